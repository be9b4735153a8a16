"""Faults as a host sees them: the unchanged pytrinamic over TCP, the pty and CAN (socketcand).

Each host waits at most :data:`HOST_TIMEOUT` for a reply, so a lost reply costs a test that
long, never more.  pytrinamic's own CAN host logic (``CanTmclInterface``) is used unchanged; it
only gets a python-can socketcand bus instead of a kernel SocketCAN one (there is none here).
pytrinamic's TCP interface (``socket_serial_tmcl``) waits for a reply forever unless its socket
has a timeout: a host that can lose replies must set one (docs/faults.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from typing import Any

import can
import pytest
from pytrinamic.connections.can_tmcl_interface import CanTmclInterface
from pytrinamic.connections.serial_tmcl_interface import SerialTmclInterface
from pytrinamic.connections.socket_tmcl_interface import SocketTmclInterface
from pytrinamic.tmcl import TMCLReplyChecksumError, TMCLReplyStatusError

from tmcl_server.embed import SimulatorThread
from tmcl_spec.commands import Status
from tmcl_spec.parameters import AP

#: How long a host waits for a reply before it gives up.
HOST_TIMEOUT = 0.25
#: What each pytrinamic interface raises when no reply came in time.
NO_REPLY = {"tcp": TimeoutError, "pty": RuntimeError, "can": ConnectionError}
TRANSPORTS = tuple(NO_REPLY)


@pytest.fixture
def sim(tmcl_sim_factory: Callable[..., SimulatorThread], tmp_path) -> SimulatorThread:
    return tmcl_sim_factory(tcp=["127.0.0.1:0"], pty=[str(tmp_path / "ttyTMCL0")],
                            socketcand=["127.0.0.1:0"])


def connect(sim: SimulatorThread, transport: str) -> Any:
    """A pytrinamic host on one of the simulator's endpoints."""
    if transport == "tcp":
        iface = SocketTmclInterface(sim.tcp)
        iface._socket.settimeout(HOST_TIMEOUT)  # otherwise a lost reply blocks it forever
        return iface
    if transport == "pty":
        return SerialTmclInterface(sim.pty, timeout_s=HOST_TIMEOUT)
    host, port = sim.endpoints["socketcand"][0].rsplit(":", 1)
    iface = CanTmclInterface("can0", 1_000_000, 2, 1, HOST_TIMEOUT)
    iface._connection = can.Bus(interface="socketcand", host=host, port=int(port), channel="can0",
                                can_filters=[{"can_id": 2, "can_mask": 0x7FF, "extended": False}])
    return iface


@pytest.fixture
def host(sim: SimulatorThread, request: pytest.FixtureRequest) -> Iterator[Any]:
    iface = connect(sim, request.param)
    iface.transport = request.param
    yield iface
    iface.close()


def with_retries(call: Callable[[], Any], errors: type[Exception], attempts: int = 3) -> tuple[Any, int]:
    """What a careful host does: try again after a timeout.  Returns (result, failed attempts)."""
    for failed in range(attempts):
        try:
            return call(), failed
        except errors:
            continue
    raise AssertionError(f"no reply in {attempts} attempts")


# -- the four things every host must survive, on every transport -----------------------------


@pytest.mark.parametrize("host", TRANSPORTS, indirect=True)
def test_a_lost_reply_is_a_timeout_and_a_retry_succeeds(sim: SimulatorThread, host: Any) -> None:
    host.set_axis_parameter(AP.MAX_SPEED, 0, 12345)
    with sim.fault("noreply", opcode="GAP", count=1) as fault:
        with pytest.raises(NO_REPLY[host.transport]):
            host.get_axis_parameter(AP.MAX_SPEED, 0)
        value, failed = with_retries(lambda: host.get_axis_parameter(AP.MAX_SPEED, 0),
                                     NO_REPLY[host.transport])
        assert (value, failed, fault.fired) == (12345, 0, 1)
    # a dropped request: the retry is what gets the command executed at all
    with sim.fault("drop", opcode="SAP", count=1):
        _, failed = with_retries(lambda: host.set_axis_parameter(AP.MAX_SPEED, 0, 2222),
                                 NO_REPLY[host.transport])
    assert failed == 1 and host.get_axis_parameter(AP.MAX_SPEED, 0) == 2222


@pytest.mark.parametrize("host", TRANSPORTS, indirect=True)
def test_a_bad_checksum_is_a_checksum_error_or_on_can_a_lost_frame(sim: SimulatorThread,
                                                                    host: Any) -> None:
    with sim.fault("checksum", opcode="GAP", count=1):
        expected = NO_REPLY["can"] if host.transport == "can" else TMCLReplyChecksumError
        with pytest.raises(expected):  # CAN: the frame fails its CRC and nobody receives it
            host.get_axis_parameter(AP.ACTUAL_POSITION, 0)
    assert host.get_axis_parameter(AP.ACTUAL_POSITION, 0) == 0  # the link is in step again


@pytest.mark.parametrize("host", TRANSPORTS, indirect=True)
def test_another_status_is_a_status_exception(sim: SimulatorThread, host: Any) -> None:
    with sim.fault("status", opcode="SAP", status="INVALID_VALUE"), \
            pytest.raises(TMCLReplyStatusError) as caught:
        host.set_axis_parameter(AP.MAX_SPEED, 0, 1000)
    assert caught.value.status_code == Status.INVALID_VALUE
    assert host.get_axis_parameter(AP.MAX_SPEED, 0) == 1000  # the module did execute it


@pytest.mark.parametrize("host", TRANSPORTS, indirect=True)
def test_a_reply_from_another_address_and_a_late_one(sim: SimulatorThread, host: Any) -> None:
    with sim.fault("wrong_address", address=7):
        assert host.send(6, AP.MAX_SPEED, 0, 0).module_address == 7  # pytrinamic takes it
    with sim.fault("delay", ms=60):
        start = time.perf_counter()
        host.get_axis_parameter(AP.ACTUAL_POSITION, 0)
        assert time.perf_counter() - start >= 0.06


# -- what the byte streams can do to a reply (TCP here; the pty behaves alike) ------------------


@pytest.fixture
def tcp(sim: SimulatorThread) -> Iterator[Any]:
    iface = connect(sim, "tcp")
    yield iface
    iface.close()


def test_a_torn_reply_is_reassembled_if_the_pauses_fit_the_timeout(sim: SimulatorThread, tcp: Any) -> None:
    with sim.fault("tear", pieces=3, pause_ms=40):
        start = time.perf_counter()
        assert tcp.get_axis_parameter(AP.MAX_SPEED, 0) == 51200
        assert time.perf_counter() - start >= 0.08
    with sim.fault("tear", pieces=2, pause_ms=400), pytest.raises(TimeoutError):
        tcp.get_axis_parameter(AP.MAX_SPEED, 0)


def test_garbage_before_a_reply_and_a_duplicate_put_the_host_out_of_step(sim: SimulatorThread,
                                                                         tcp: Any) -> None:
    with sim.fault("garbage", data="aabbcc", count=1), pytest.raises(TMCLReplyChecksumError):
        tcp.get_axis_parameter(AP.MAX_SPEED, 0)
    # the reply's last three bytes are still on the way: the next reply is read out of step
    with pytest.raises(TMCLReplyChecksumError):
        tcp.get_axis_parameter(AP.ACTUAL_POSITION, 0)
    tcp._socket.recv(64)  # what a host must do after an error: flush its input
    with sim.fault("duplicate", opcode="GAP", count=1):
        assert tcp.get_axis_parameter(AP.MAX_SPEED, 0) == 51200
    assert tcp.get_axis_parameter(AP.ACTUAL_POSITION, 0) == 51200  # the copy, not the position


def test_a_module_reset_keeps_its_eeprom_and_forgets_its_ram(sim: SimulatorThread, tcp: Any) -> None:
    tcp.set_axis_parameter(AP.MAX_SPEED, 0, 1234)
    tcp.store_axis_parameter(AP.MAX_SPEED, 0)  # STAP: in the EEPROM
    tcp.set_axis_parameter(AP.MAX_ACCELERATION, 0, 4321)  # RAM only
    tcp.set_global_parameter(0, 2, 99)  # a user variable, RAM only
    with sim.fault("reset", opcode="GAP", count=1), pytest.raises(TimeoutError):
        tcp.get_axis_parameter(AP.MAX_SPEED, 0)  # the module restarts instead of answering
    assert tcp.get_axis_parameter(AP.MAX_SPEED, 0) == 1234
    assert tcp.get_axis_parameter(AP.MAX_ACCELERATION, 0) != 4321
    assert tcp.get_global_parameter(0, 2) == 0
    tcp.set_axis_parameter(AP.MAX_ACCELERATION, 0, 4321)
    sim.power_cycle()  # the same from Python, at once
    assert tcp.get_axis_parameter(AP.MAX_ACCELERATION, 0) != 4321
    assert tcp.get_axis_parameter(AP.MAX_SPEED, 0) == 1234


@pytest.mark.tmcl_sim(faults=["status:opcode=GAP,type=4,status=3"])
def test_faults_from_the_start_by_a_pytest_marker(tmcl_sim: SimulatorThread) -> None:
    sim = tmcl_sim
    iface = connect(sim, "tcp")
    try:
        with pytest.raises(TMCLReplyStatusError):
            iface.get_axis_parameter(AP.MAX_SPEED, 0)
        assert iface.get_axis_parameter(AP.ACTUAL_POSITION, 0) == 0
        assert [f["spec"] for f in sim.faults()] == ["status:opcode=GAP,type=4,status=3"]
        sim.clear_faults()
        assert iface.get_axis_parameter(AP.MAX_SPEED, 0) == 51200
    finally:
        iface.close()


def test_the_readme_example_runs(tmp_path) -> None:
    """README, "Testing your host against faults": its pytest example passes as written."""
    import subprocess
    import sys
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    section = readme[readme.index("## Testing your host against faults"):]
    example = section.split("```python\n", 1)[1].split("```", 1)[0]
    (tmp_path / "test_example.py").write_text(example)
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             "-p", "no:xdist", str(tmp_path / "test_example.py")],
                            capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 passed" in result.stdout
