"""Third-party TMCL host libraries against the simulator, as their users would run them.

docs/compatibility.md lists the clients and what works; each test here is one line of that
table.  The libraries are used unchanged, over the pty (the module's USB port) or over TCP
through pyserial's ``socket://`` URL.  Where a library has a bug of its own, the test pins
the library's behaviour so that the table stays true; the simulator's reply is checked too.
"""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
import serial

from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

pyTMCL = pytest.importorskip("pyTMCL")  # the library's own spelling


@pytest.fixture
def sim(tmp_path: Path):
    with SimulatorThread(clock="virtual", pty=[str(tmp_path / "ttyTMCL0")],
                         tcp=["127.0.0.1:0"]) as sim:
        yield sim


@pytest.fixture(params=["pty", "tcp"])
def port(request, sim):
    """A pyserial port to the module: its USB port (pty), or TCP through ``socket://``."""
    if request.param == "pty":
        handle = serial.Serial(sim.pty, 115200, timeout=2.0)
    else:
        handle = serial.serial_for_url(f"socket://{sim.tcp}", timeout=2.0)
    yield handle
    handle.close()


# -- pyTMCL 1.0.10 (PyPI "pytmcl") ----------------------------------------------------------------

def test_pytmcl_moves_reads_and_writes(sim, port):
    motor = pyTMCL.connect(port).get_module(1).get_motor(2)
    motor.axis.max_positioning_speed = 100_000
    assert motor.axis.max_positioning_speed == 100_000
    assert motor.move_absolute(-20_000) == 100
    sim.advance(2.0)
    assert motor.axis.actual_position == -20_000  # signed values both ways
    assert motor.get_position_reached() == 1
    assert motor.rotate_right(30_000) == 100
    sim.advance(2.0)
    assert motor.axis.actual_speed > 29_000
    motor.stop()
    sim.advance(2.0)
    assert motor.axis.actual_speed == 0
    motor.move_relative(5_000)
    sim.advance(2.0)
    assert motor.get_axis_parameter(AP.ACTUAL_POSITION) == motor.axis.target_position
    assert motor.rotate_left(10_000) == 100
    sim.advance(1.0)
    assert motor.axis.actual_speed < -9_000
    motor.stop()
    assert motor.set_axis_parameter(AP.MAX_ACCELERATION, 70_000) == 70_000
    assert motor.set_user_var(3, -5) == 100
    assert motor.get_user_var(3) == -5
    assert motor.reference_search(motor.RFS_STATUS) == 100
    assert motor.get_axis_parameter(AP.SMARTENERGY_ACTUAL_CURRENT) == 16  # AP 6 = 128 at rest
    assert motor.run_command(0) == 100  # 129 type 1: run the (empty) program from address 0


def test_pytmcl_error_replies(sim, port):
    bus = pyTMCL.connect(port)
    motor = bus.get_module(1).get_motor(0)
    with pytest.raises(pyTMCL.reply.TrinamicException, match="Wrong Type"):
        motor.get_axis_parameter(154)  # pulse divisor: a TMC429 module's, not the TMCM-6212's
    with pytest.raises(pyTMCL.reply.TrinamicException, match="Invalid Value"):
        bus.get_module(1).get_motor(6).get_axis_parameter(AP.MAX_SPEED)
    # Status 9 (program memory full) is not in the library's message table: KeyError.
    assert bus.send(1, Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 6143).status == 100
    assert bus.send(1, Opcode.MST, 0, 0, 0).status == 101  # stored at the last address
    with pytest.raises(KeyError):
        bus.send(1, Opcode.MST, 0, 0, 0)
    assert bus.send(1, Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0).status == 100


# -- TMCL 1.1.1 (PyPI "tmcl", NativeDesign/python-tmcl) -------------------------------------------

def test_python_tmcl_reads_but_fails_on_its_own_checksum_and_errors(sim, port):
    tmcl = pytest.importorskip("TMCL")
    motor = tmcl.connect(port).get_motor(1)
    assert motor.axis.max_positioning_speed == 51200
    motor.axis.max_current = 100  # small values: its checksum (a sum of integers) is right
    assert motor.axis.max_current == 100
    with pytest.raises(struct.error):  # value 1000 makes its "checksum" 1010: not a byte
        motor.axis.max_positioning_speed = 1000
    with pytest.raises(NameError):  # its exception class refers to an undefined name
        motor.axis.get(154)
    # values are unpacked unsigned: a negative position reads as 2**32 - 5
    raw = RawClient(sim.tcp)
    raw.request(1, Opcode.SAP, AP.ACTUAL_POSITION, 0, -5)
    raw.close()
    assert motor.axis.actual_position == 2**32 - 5


# -- TMCM-Lib 1.0.0 (PyPI "tmcm-lib") ---------------------------------------------------------------

def test_tmcm_lib_identifies_the_module_but_supports_only_the_tmcm_3110(sim):
    tmcm_lib = pytest.importorskip("tmcm_lib")
    port = tmcm_lib.Port(sim.pty, 115200)
    assert tmcm_lib.Module.identify(port) == (6212, (1, 5))  # command 136 type 1
    with pytest.raises(NotImplementedError):  # it has a class for the TMCM-3110 only
        tmcm_lib.Module.construct(port)
    from tmcm_lib.module_3110.module import Module as Module3110

    with pytest.raises(tmcm_lib.exceptions.ModelException):
        Module3110(port)


# -- pytrinamic (Trinamic's own) beyond tests/tmcl_server/test_pytrinamic.py ----------------------

def test_pytrinamic_reads_the_supply_voltage_and_reports_unknown_commands(sim):
    from pytrinamic.connections import ConnectionManager
    from pytrinamic.tmcl import GetInfoRequestError, TMCLReplyStatusError

    with ConnectionManager(f"--interface serial_tmcl --port {sim.pty} --data-rate 115200"
                           ).connect() as iface:
        assert iface.get_analog_input(8) == 240  # 24.0 V
        assert iface.get_version_string() == "6212V105"
        with pytest.raises(GetInfoRequestError):  # command 157 is newer than firmware 1.05
            iface.get_info("FWVersion")
        iface.send(Opcode.SGP, 81, 0, 2)  # protect the program against overwriting
        with pytest.raises(TMCLReplyStatusError) as error:
            iface.send(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0)
        assert error.value.status_code == 8
        with pytest.raises(KeyError):  # pytrinamic's message table has 9 but not 8
            error.value.error_description  # noqa: B018


def test_pytrinamics_tmclinfo_fails_faithfully_and_tmcl_info_answers(sim) -> None:
    """pytrinamic's own ``tmclinfo`` asks for command 157 (GetInfo), which firmware 1.05 lacks
    (status 2, as the real module answers): it ends in a traceback.  docs/compatibility.md
    says so and names ``tmcl info`` instead, which reads the same module (issue 37, item 10)."""
    import subprocess
    import sys

    tmclinfo = Path(sys.executable).parent / "tmclinfo"
    if not tmclinfo.exists():
        pytest.skip("pytrinamic's tmclinfo is not installed")
    done = subprocess.run([str(tmclinfo), "--interface", "serial_tmcl", "--port", sim.pty],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode != 0 and "GetInfoRequestError" in done.stderr, done.stderr[-500:]
    assert "Invalid Command" in done.stderr
    done = subprocess.run([str(Path(sys.executable).parent / "tmcl"), "--serial", sim.pty, "info"],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "version                   6212V105" in done.stdout
    doc = (Path(__file__).resolve().parents[2] / "docs" / "compatibility.md").read_text()
    assert "tmclinfo" in doc and "tmcl info" in doc
