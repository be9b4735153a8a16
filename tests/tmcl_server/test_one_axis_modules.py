"""The one-axis modules (TMCM-1140, 1141, 1160, 1161 on a TMC429, TMCM-1111 on a TMC4361)
against pytrinamic's own classes for them, unchanged, over TCP, the pty and CAN.

CAN is a python-can ``virtual`` bus the simulator joins (``--can virtual:NAME``), reached
through pytrinamic's ``CanTmclInterface`` (the base of its SocketCAN/PCAN/SLCAN interfaces)
over python-can's in-process ``virtual`` interface; pytrinamic's own ``slcan_tmcl`` on the
project's SLCAN pty runs once as well.  Every parameter a class names is read, and written
where the table allows it; moves through the class's motor API reach their targets.  Where a
class uses a name its own parameter table lacks (docs/modules.md, "pytrinamic's classes"),
the test shows pytrinamic raising AttributeError before anything is sent, and the rest of
that feature working.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import can
import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.connections.can_tmcl_interface import CanTmclInterface
from pytrinamic.modules import TMCM1111, TMCM1140, TMCM1141, TMCM1160, TMCM1161
from pytrinamic.tmcl import TMCLReplyStatusError

from tests.helpers.pytrinamic_classes import check_identity_and_parameters, names
from tmcl_server.embed import SimulatorThread
from tmcl_spec.commands import Status
from tmcl_spec.modules import module_type

PYTRINAMIC: dict[str, Any] = {"tmcm-1140": TMCM1140, "tmcm-1141": TMCM1141,
                              "tmcm-1160": TMCM1160, "tmcm-1161": TMCM1161,
                              "tmcm-1111": TMCM1111}
VERSIONS = {"tmcm-1140": "1140V127", "tmcm-1141": "1141V119", "tmcm-1160": "1160V147",
            "tmcm-1161": "1161V124", "tmcm-1111": "1111V105"}
PATHS = ("tcp", "pty", "can")
#: Every module over every path it has (the TMCM-1141 and 1161 have no CAN interface).
KIND_PATHS = [(kind, path) for kind in PYTRINAMIC for path in PATHS
              if path != "can" or module_type(kind).has_can]
#: A speed and a move for each unit convention: TMC429 register units, or pps.
SPEED = {"tmcm-1111": 51200}
TMC429_SPEED = 1500


class VirtualCanTmclInterface(CanTmclInterface):
    """pytrinamic's CAN interface on python-can's in-process ``virtual`` bus (its SocketCAN
    interface with ``interface="virtual"``: the same frames, filter and framing)."""

    def __init__(self, channel: str, host_id: int = 2, module_id: int = 1,
                 timeout_s: float = 5) -> None:
        CanTmclInterface.__init__(self, channel, 1_000_000, host_id, module_id, timeout_s)
        self._connection = can.Bus(interface="virtual", channel=channel)
        self._connection.set_filters([{"can_id": host_id, "can_mask": 0x7F}])

    def __enter__(self) -> VirtualCanTmclInterface:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class Rig:
    """One simulated module with every endpoint, and the way to reach it by ``path``."""

    def __init__(self, tmp_path: Path, kind: str) -> None:
        self.kind = kind
        self.channel = f"tmcl-sim-{uuid.uuid4()}"
        self.sim = SimulatorThread(clock="virtual", module_type=kind, tcp=["127.0.0.1:0"],
                                   pty=[str(tmp_path / "ttyTMCL0")],
                                   can=[f"virtual:{self.channel}"])

    def connect(self, path: str) -> Any:
        if path == "tcp":
            return ConnectionManager(f"--interface socket_serial_tmcl --port {self.sim.tcp}").connect()
        if path == "pty":
            return ConnectionManager(
                f"--interface serial_tmcl --port {self.sim.pty} --data-rate 115200").connect()
        return VirtualCanTmclInterface(self.channel)


@pytest.fixture
def rig(tmp_path: Path, kind: str) -> Iterator[Rig]:
    rig = Rig(tmp_path, kind)
    with rig.sim:
        yield rig


# == identity and parameters ===================================================================


@pytest.mark.parametrize(("kind", "path"), KIND_PATHS)
def test_version_and_every_parameter_the_class_lists(rig: Rig, kind: str, path: str) -> None:
    profile = module_type(kind)
    with rig.connect(path) as iface:
        module = PYTRINAMIC[kind](iface)
        assert module.name == profile.name
        assert profile.number_of_axes == 1
        check_identity_and_parameters(iface, module, profile, VERSIONS[kind])
        with pytest.raises(TMCLReplyStatusError) as error:
            iface.get_axis_parameter(189, 0)  # no module of these has a row 189
        assert error.value.reply.status == Status.WRONG_TYPE


# == moves through the motor API ==============================================================


@pytest.mark.parametrize(("kind", "path"), KIND_PATHS)
def test_moves_through_the_motor_api_reach_their_targets(rig: Rig, kind: str, path: str) -> None:
    with rig.connect(path) as iface:
        module = PYTRINAMIC[kind](iface)
        motor = module.motors[0]
        speed = SPEED.get(kind, TMC429_SPEED)
        if hasattr(motor.AP, "MaxVelocity"):
            module.move_to(0, 12_345, velocity=speed)  # SAP 4, then MVP ABS
            assert motor.linear_ramp.max_velocity == speed
        else:  # the TMCM1111 class calls AP 4 MaxPositioningSpeed: move_to's velocity fails
            with pytest.raises(AttributeError):
                module.move_to(0, 12_345, velocity=speed)
            module.move_to(0, 12_345)
        assert not motor.get_position_reached()
        for _ in range(200):
            if motor.get_position_reached():
                break
            rig.sim.advance(0.05)
        assert motor.actual_position == motor.target_position == 12_345
        motor.move_by(-2_345)
        assert rig.sim.advance_until(lambda: rig.sim.module().axis(0).get_parameter(8) == 1,
                                     timeout=10)
        assert motor.actual_position == 10_000
        motor.rotate(-speed)
        rig.sim.advance(3.0)
        assert motor.actual_velocity == -speed and motor.actual_position < 10_000
        motor.stop()
        rig.sim.advance(3.0)
        assert motor.actual_velocity == 0
        motor.actual_position = 0  # SAP 1
        assert motor.actual_position == 0 and motor.get_position_reached()


# == pytrinamic's feature classes =============================================================


@pytest.mark.parametrize("kind", PYTRINAMIC)
def test_the_feature_classes_work_where_the_class_has_their_names(rig: Rig, kind: str) -> None:
    with rig.connect("tcp") as iface:
        motor = PYTRINAMIC[kind](iface).motors[0]
        ap = motor.AP
        drive = motor.drive_settings
        drive.max_current = 100  # AP 6
        drive.standby_current = 20  # AP 7
        drive.boost_current = 10  # AP 200
        drive.microstep_resolution = 6  # AP 140: 64 microsteps
        assert (drive.max_current, drive.standby_current, drive.boost_current,
                drive.microstep_resolution) == (100, 20, 10, 6)
        assert "'max_current': 100" in str(drive)
        if hasattr(ap, "ReferenceSwitchTolerance"):  # TMCM1140/1141 only
            drive.reference_switch_tolerance = 77
            assert drive.reference_switch_tolerance == 77
        ramp = motor.linear_ramp
        ramp.max_acceleration = 1000  # AP 5
        assert ramp.max_acceleration == 1000
        assert ramp.enabled is None  # no class names an EnableRamp parameter
        if hasattr(ap, "MaxVelocity"):
            ramp.max_velocity = 1234
            assert ramp.max_velocity == 1234 and "'max_velocity': 1234" in str(ramp)
        else:
            with pytest.raises(AttributeError):
                ramp.max_velocity = 1234
        sg = motor.stallguard2
        sg.filter, sg.threshold = 1, -5  # AP 173, 174
        assert (sg.filter, sg.threshold) == (1, -5) and 0 <= sg.load_value <= 1023  # AP 206
        if hasattr(ap, "SmartEnergyStallVelocity"):
            sg.stop_velocity = 200  # AP 181
            assert sg.stop_velocity == 200 and "threshold" in str(sg)
        else:  # TMCM1160/1161 spell the smartEnergy names in lower camel case
            with pytest.raises(AttributeError):
                sg.stop_velocity = 200
            with pytest.raises(AttributeError):
                str(sg)
        cool = motor.coolstep
        cool.current_minimum, cool.current_down_step, cool.current_up_step = 1, 2, 3
        assert (cool.current_minimum, cool.current_down_step, cool.current_up_step) == (1, 2, 3)
        for name, attribute, value in (("SmartEnergyHysteresis", "hysteresis", 4),
                                       ("SmartEnergyHysteresisStart", "hysteresis_start", 5),
                                       ("SmartEnergyThresholdSpeed", "threshold_speed", 600),
                                       ("SmartEnergySlowRunCurrent", "slow_run_current", 7)):
            if hasattr(ap, name):
                setattr(cool, attribute, value)
                assert getattr(cool, attribute) == value, name
            else:
                with pytest.raises(AttributeError):
                    setattr(cool, attribute, value)
        if hasattr(ap, "StatusFlags"):  # only the TMCM1111 class names AP 207/208 so
            assert motor.get_status_flags() == motor.get_axis_parameter(208)
            assert motor.get_error_flags() == 0
        else:
            with pytest.raises(AttributeError):
                motor.get_status_flags()


# == I/O =====================================================================================


@pytest.mark.parametrize("kind", PYTRINAMIC)
def test_the_io_ports_the_class_names_and_the_supply(rig: Rig, kind: str) -> None:
    profile = module_type(kind)
    io = names(PYTRINAMIC[kind].IO)
    module = rig.sim.module()
    with rig.connect("pty") as iface:
        outputs = [n for name, n in io.items() if name.startswith("OUT")]
        assert len(outputs) == profile.outputs
        for port in outputs:
            iface.set_digital_output(port)
            assert iface.get_digital_output(port) == 1
            iface.clear_digital_output(port)
            assert iface.get_digital_output(port) == 0
        inputs = {name: n for name, n in io.items() if name.startswith("IN")}
        assert len(inputs) == profile.digital_inputs
        for line, (name, port) in enumerate(sorted(inputs.items())):
            # the world numbers the lines (IN0..IN3), GIO the ports: the TMCM-1141's IN3 is
            # port 4 (issue 34, item 9), as its class says
            rig.sim.call(module.set_digital_input, line, True)
            assert iface.get_digital_input(port) == 1, name
            rig.sim.call(module.set_analog_input, line, 1000)  # below half of 4095: 0
            assert iface.get_digital_input(port) == 0 and iface.get_analog_input(port) == 1000
        if profile.input_ports is not None:  # a port that is no line answers status 3
            gap = min(set(range(max(profile.input_ports))) - set(profile.input_ports))
            with pytest.raises(TMCLReplyStatusError):
                iface.get_digital_input(gap)
        if profile.supply_voltage_channel is None:
            with pytest.raises(TMCLReplyStatusError):
                iface.get_analog_input(8)
        else:  # Odemis and the TMCL-IDE read the supply on GIO 8, 1 in 0.1 V
            assert iface.get_analog_input(8) == round(10 * profile.nominal_supply_voltage)


# == CAN =====================================================================================


@pytest.mark.parametrize("kind", [k for k in PYTRINAMIC if not module_type(k).has_can])
def test_modules_without_can_stay_silent_on_the_bus(rig: Rig, kind: str) -> None:
    with VirtualCanTmclInterface(rig.channel, timeout_s=0.2) as iface, pytest.raises(ConnectionError):
        iface.get_version_string()
    with rig.connect("tcp") as iface, pytest.raises(TMCLReplyStatusError):
        iface.get_global_parameter(69, 0)  # no CAN bit rate either


def test_pytrinamic_slcan_tmcl_drives_a_tmcm_1140(tmp_path: Path) -> None:
    """pytrinamic's own CAN interface, unchanged, through the virtual SLCAN adapter."""
    link = tmp_path / "ttySLCAN0"
    with SimulatorThread(clock="virtual", module_type="tmcm-1140", slcan=[str(link)]) as sim:
        port = sim.endpoints["slcan"][0]
        connection = ConnectionManager(f"--interface slcan_tmcl --port {port} --data-rate 1000000")
        with connection.connect() as iface:
            module = TMCM1140(iface)
            assert iface.get_version_string() == "1140V127"
            module.move_to(0, -4_000, velocity=TMC429_SPEED)
            assert sim.advance_until(lambda: sim.module().axis(0).get_parameter(8) == 1,
                                     timeout=10)
            assert module.motors[0].actual_position == -4_000
            assert module.motors[0].get_axis_parameter(209, signed=True) == -4_000  # sensOstep
