"""The TMCM-1110, TMCM-3110 and TMCM-6110 against host software written for them, unchanged.

pytrinamic's ``TMCM1110``/``TMCM3110``/``TMCM6110`` classes over the module's USB port (pty) and
TCP; TMCM-Lib, which implements the TMCM-3110 and identifies a module with command 136 type 1
before its usual start-up; a TMCL program on the TMCM-6110 whose interrupt vectors follow the
module's eight inputs.  docs/modules.md says what each profile takes from where.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from pytrinamic.modules import TMCM1110, TMCM3110, TMCM6110
from pytrinamic.tmcl import TMCLReplyStatusError

from interpreter.assembler import assemble
from tests.helpers.pytrinamic_classes import check_identity_and_parameters, names
from tests.helpers.pytrinamic_link import connect
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCLModule
from tmcl_server.protocol import Request
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.modules import module_type
from tmcl_spec.parameters import AP

PYTRINAMIC = {"tmcm-1110": TMCM1110, "tmcm-3110": TMCM3110, "tmcm-6110": TMCM6110}
VERSIONS = {"tmcm-1110": "1110V109", "tmcm-3110": "3110V114", "tmcm-6110": "6110V146"}
MODULES = sorted(PYTRINAMIC)


def simulator(tmp_path: Path, kind: str, **options) -> SimulatorThread:
    return SimulatorThread(clock="virtual", module_type=kind, tcp=["127.0.0.1:0"],
                           pty=[str(tmp_path / "ttyTMCL0")], **options)


@pytest.fixture(params=MODULES)
def kind(request) -> str:
    return request.param


@pytest.fixture
def sim(tmp_path, kind):
    with simulator(tmp_path, kind) as sim:
        yield sim


# == identity and parameters ===================================================================


@pytest.mark.parametrize("path", ["pty", "tcp"])
def test_version_and_every_parameter_the_pytrinamic_class_names(sim, kind, path) -> None:
    with connect(sim, path) as iface:
        module = PYTRINAMIC[kind](iface)
        profile = module_type(kind)
        check_identity_and_parameters(iface, module, profile, VERSIONS[kind])
        with pytest.raises(TMCLReplyStatusError) as error:
            iface.get_axis_parameter(AP.UNIT_MODE, 0)  # the TMCM-6212's, not these modules'
        assert error.value.reply.status == Status.WRONG_TYPE


@pytest.mark.parametrize("path", ["pty", "tcp"])
def test_moves_on_every_axis_polled_to_the_target_and_registers_per_motor(sim, kind, path) -> None:
    with connect(sim, path) as iface:
        module = PYTRINAMIC[kind](iface)
        targets = [(-1) ** n * 12_345 * (n + 1) for n in range(len(module.motors))]
        for motor, target in zip(module.motors, targets, strict=True):
            motor.move_to(target, velocity=1500)  # AP 4 in the TMC429's units
        for _ in range(100):
            if all(motor.get_position_reached() for motor in module.motors):
                break
            sim.advance(0.1)
        assert [motor.actual_position for motor in module.motors] == targets
        assert [motor.get_axis_parameter(AP.MAX_SPEED) for motor in module.motors] == [1500] * len(targets)
        # commands 146/147: the TMC429 itself; a write to one motor's register only
        assert iface.send(Opcode.READ_MC, 0x39, 0, 0).value & 0xFFFFFF == 0x429101
        last = len(module.motors) - 1
        iface.send(Opcode.WRITE_MC, 0x02, last, 345)  # V_MIN of the last axis's motor
        v_min = [iface.send(Opcode.READ_MC, 0x02, n, 0).value & 0x7FF for n in range(last + 1)]
        assert v_min[last] == 345 and all(v != 345 for v in v_min[:last])


WORLD = """
[[axis]]
index = {axis}
left = {{ position = -20000 }}
right = {{ position = 30000 }}
"""


@pytest.mark.parametrize("kind", ["tmcm-3110", "tmcm-6110"])
def test_reference_search_against_a_world_file(tmp_path, kind) -> None:
    axis = 2
    world = tmp_path / "world.toml"
    world.write_text(WORLD.format(axis=axis))
    with simulator(tmp_path, kind, world=str(world)) as sim, connect(sim, "tcp") as iface:
        motor = PYTRINAMIC[kind](iface).motors[axis]
        motor.set_axis_parameter(AP.RFS_MODE, 2)  # right switch, then left: the zero
        motor.set_axis_parameter(AP.RFS_SPEED, 700)
        iface.reference_search(0, axis)
        for _ in range(200):
            sim.advance(0.1)
            if iface.reference_search(2, axis) == 0:
                break
        assert iface.reference_search(2, axis) == 0
        assert motor.actual_position == 0
        assert motor.get_axis_parameter(AP.SWITCH_DISTANCE) == pytest.approx(50_000, abs=2)
        assert sim.module().axis(axis).status().mechanical_position == pytest.approx(-20_000, abs=2)


def test_inputs_outputs_and_the_supply_voltage(sim, kind) -> None:
    profile = module_type(kind)
    module: TMCLModule = sim.module()
    with connect(sim, "tcp") as iface:
        io = PYTRINAMIC[kind].IO
        outputs = [number for name, number in names(io).items() if name.startswith("OUT")]
        for port in outputs:
            iface.set_digital_output(port)
            assert iface.get_digital_output(port) == 1
            iface.clear_digital_output(port)
        inputs = [number for name, number in names(io).items() if name.startswith(("IN", "AIN"))]
        assert sorted(inputs) == list(range(profile.digital_inputs))
        sim.call(module.set_digital_input, inputs[-1], True)
        sim.call(module.set_analog_input, 0, 1000)  # below half of 4095: digital 0
        assert [iface.get_digital_input(port) for port in inputs] == [0] * (len(inputs) - 1) + [1]
        assert iface.get_analog_input(0) == 1000
        if profile.supply_voltage_channel is not None:
            assert iface.get_analog_input(names(io).get("VIN", 8)) == 240  # 24.0 V
        with pytest.raises(TMCLReplyStatusError):
            iface.get_digital_input(profile.digital_inputs)


def test_supply_voltage_on_gio_8_1_as_odemis_reads_it_at_start_up(sim, kind) -> None:
    """Odemis' TMCL driver reads GIO 8, 1 on every TMC429 module before anything else and
    refuses a module that does not answer it (docs/modules.md: the TMCM-1110 too)."""
    module: TMCLModule = sim.module()
    with connect(sim, "pty") as iface:
        assert iface.send(Opcode.GIO, 8, 1, 0).value == 240  # 24.0 V in 0.1 V
        sim.call(module.set_supply_voltage, 0.0)  # USB power only: recent firmware reads 0
        assert iface.get_analog_input(8) == 0
        with pytest.raises(TMCLReplyStatusError) as error:
            iface.send(Opcode.GIO, 9, 1, 0)
        assert error.value.reply.status == Status.WRONG_TYPE


def test_ap_9_is_the_reference_switch_the_left_one(tmp_path, kind) -> None:
    """AP 9 ("reference switch status" in pytrinamic and the TMCL-IDE's include) reads the
    left switch, as AP 11 does: these modules have two reference switches per axis and no
    home input (docs/modules.md)."""
    axis = module_type(kind).number_of_axes - 1
    world = tmp_path / "world.toml"
    world.write_text(f"[[axis]]\nindex = {axis}\nleft = {{ position = -100 }}\n"
                     f"home = {{ position = 5000, width = 400 }}\n")
    with simulator(tmp_path, kind, world=str(world)) as sim, connect(sim, "tcp") as iface:
        motor = PYTRINAMIC[kind](iface).motors[axis]
        reference = names(motor.AP)["ReferenceSwitchStatus"]
        assert (motor.get_axis_parameter(reference), motor.get_axis_parameter(AP.LEFT_SWITCH)) == (0, 0)
        iface.send(Opcode.SAP, AP.LEFT_DISABLE, axis, 1)  # drive into it, do not stop
        iface.send(Opcode.MVP, 0, axis, -1000)
        sim.advance(2.0)
        assert motor.actual_position == -1000
        assert (motor.get_axis_parameter(reference), motor.get_axis_parameter(AP.LEFT_SWITCH)) == (1, 1)
        iface.send(Opcode.MVP, 0, axis, 5000)  # the world's home cam: not an input here
        sim.advance(2.0)
        assert motor.actual_position == 5000
        assert motor.get_axis_parameter(reference) == 0


def test_a_blocked_motor_stalls_through_the_tmc262_at_a_tuned_threshold(tmp_path, kind) -> None:
    """The TMC262 model reads the same law: a blocked zone reads 0 at AP 174 = 24, the
    partial load before it does not (docs/motion.md, "stallGuard2 and coolStep")."""
    world = tmp_path / "world.toml"
    world.write_text("[[axis]]\nindex = 0\n"
                     "[[axis.load_zone]]\nfrom = 2000\nto = 5000\nload = 100\n"
                     "[[axis.load_zone]]\nfrom = 8000\nto = 900000\nblocked = true\n")
    with simulator(tmp_path, kind, world=str(world)) as sim, connect(sim, "tcp") as iface:
        motor = PYTRINAMIC[kind](iface).motors[0]
        motor.set_axis_parameter(AP.STALLGUARD_THRESHOLD, 24)
        motor.set_axis_parameter(AP.STOP_ON_STALL, 100)  # TMC429 units
        iface.rotate(0, 1500)
        sim.advance(2.0)
        assert motor.get_axis_parameter(AP.ACTUAL_SPEED) == 0
        # the firmware's pass stops it (TMCL-LITE-1110 SysControl.c lines 106-114): one axis
        # every 11 ms, so at most one period of axis 0's passes into the zone (1500 units at
        # PULSE_DIV 2: 91,553 pps)
        period_s = 0.011 * module_type(kind).number_of_axes
        assert 8000 <= motor.actual_position <= 8000 + 2 * 256 + 91_553 * period_s
        assert motor.get_axis_parameter(AP.ERROR_FLAGS) == 1
        assert motor.get_axis_parameter(AP.LOAD) == 0


def test_user_variables_and_parameters_are_stored_across_a_restart(tmp_path, kind) -> None:
    state = str(tmp_path / "state")
    with simulator(tmp_path, kind, state_dir=state) as sim, connect(sim, "pty") as iface:
        iface.set_global_parameter(7, 2, -4242)
        iface.store_global_parameter(7, 2)
        iface.set_global_parameter(8, 2, 99)  # not stored
        iface.set_axis_parameter(AP.MAX_ACCELERATION, 0, 1234)
        iface.store_axis_parameter(AP.MAX_ACCELERATION, 0)
    with simulator(tmp_path, kind, state_dir=state) as sim, connect(sim, "tcp") as iface:
        assert iface.get_global_parameter(7, 2, signed=True) == -4242
        assert iface.get_global_parameter(8, 2) == 0
        assert iface.get_axis_parameter(AP.MAX_ACCELERATION, 0) == 1234


# == TMCM-Lib: a host written for the TMCM-3110 ===============================================


def test_tmcm_lib_finds_its_tmcm_3110_and_runs_its_start_up(tmp_path) -> None:
    tmcm_lib = pytest.importorskip("tmcm_lib")
    with simulator(tmp_path, "tmcm-3110") as sim:
        port = tmcm_lib.Port(sim.pty, 115200)
        assert tmcm_lib.Module.identify(port) == (3110, (1, 14))  # command 136 type 1
        module = tmcm_lib.Module.construct(port)  # version check, parameter reads, pull-ups
        assert type(module).__name__ == "Module" and module.model_number == 3110
        assert module.supply_voltage == 24_000  # mV, from GIO 8, 1 in 0.1 V
        assert module.motor_count == 3 and module.coordinate_count == 20
        motor = module.motors[1]
        assert motor.microstep_resolution == 256
        motor.velocity_moving = motor.velocity_maximum / 4  # sets AP 154 and AP 4
        motor.acceleration_moving = motor.acceleration_maximum / 4  # AP 153 and AP 5
        motor.move_to(25_600, wait_while_moving=False)
        for _ in range(100):
            sim.advance(0.1)
            if not motor.moving:
                break
        assert motor.position == 25_600
        assert module.switch_limit_activity  # GP 79 = 0 read at start-up: active high


# == interrupts follow the module's inputs =====================================================


def test_a_program_on_the_tmcm_6110_gets_the_interrupt_of_input_7() -> None:
    module = TMCLModule(kind="tmcm-6110")

    def command(opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        reply = module.execute(Request(1, opcode, type_, motor, value))
        assert reply.status in (Status.OK, Status.LOADED), reply
        return reply.value

    program = assemble("""
        VECT 46, Input7
        EI 46
        EI 255
    Idle:
        JA Idle
    Input7:
        GGP 46, 2
        CALC ADD, 1
        AGP 46, 2
        RETI
    """).instructions
    command(Opcode.ENTER_DOWNLOAD_MODE)
    for instruction in program:
        command(*instruction)
    command(Opcode.EXIT_DOWNLOAD_MODE)
    command(Opcode.SGP, 46, 3, 3)  # input 7: both edges (a TMCM-6212 has no row 46)
    command(Opcode.RUN_APPLICATION)
    for t, level in ((10, True), (20, False), (30, True)):
        module.advance_to(t * 1_000_000)
        module.set_digital_input(7, level)
    module.advance_to(40_000_000)
    assert command(Opcode.GGP, 46, 2) == 3


# == profile details at the module ============================================================


def test_end_switch_polarity_pull_ups_and_analogue_channels_of_the_tmcm_3110() -> None:
    module = TMCLModule(kind="tmcm-3110")

    def send(opcode: int, type_: int = 0, motor: int = 0, value: int = 0):
        return module.execute(Request(1, opcode, type_, motor, value))

    module.set_switch(1, "left", 0, side="above")  # axis 1 stands on its left switch
    assert send(Opcode.GAP, AP.LEFT_SWITCH, 1).value == 1
    assert send(Opcode.SGP, 79, 0, 1).status == Status.OK  # GP 79: the limit switches inverted
    assert [send(Opcode.GAP, AP.LEFT_SWITCH, n).value for n in range(3)] == [1, 0, 1]
    assert [send(Opcode.GAP, AP.RIGHT_SWITCH, n).value for n in range(3)] == [1, 1, 1]
    assert send(Opcode.SIO, 0, 0, 0).status == Status.OK and module.pullups == [0]  # pull-ups off
    assert send(Opcode.SIO, 1, 0, 0).status == Status.WRONG_TYPE  # one pull-up switch only
    module.set_analog_input(4, 3000)
    assert send(Opcode.GIO, 4, 1).value == 3000 and send(Opcode.GIO, 4, 0).value == 1
    assert send(Opcode.GIO, 1, 1).status == Status.WRONG_TYPE  # IN1 is digital only
    with pytest.raises(ValueError):
        module.set_analog_input(0, 4096)  # a 12-bit ADC


def test_positions_are_the_tmc429s_24_bit_registers() -> None:
    """Issue 34, item 5: AP 0 and AP 1 are X_TARGET and X_ACTUAL sign-extended from 24 bits
    (TMCL-LITE-1110 Commands.c ``Read429Int``): a rotation counts on past 8,388,607 at
    -8,388,608, the manual's range +-8,388,607 bounds SAP 0/1 and MVP ABS, and a relative move
    across the wrap takes the short way and arrives."""
    module = TMCLModule(kind="tmcm-1110")

    def send(opcode: int, type_: int, value: int) -> tuple[int, int]:
        reply = module.execute(Request(1, opcode, type_, 0, value))
        return reply.status, reply.value

    assert send(Opcode.SAP, AP.ACTUAL_POSITION, 2**23)[0] == Status.INVALID_VALUE
    assert send(Opcode.MVP, 0, -(2**23))[0] == Status.INVALID_VALUE
    assert send(Opcode.SAP, AP.ACTUAL_POSITION, 2**23 - 5000)[0] == Status.OK
    send(Opcode.ROR, 0, 200)  # about 12,000 steps a second
    module.advance_to(module.now_ns + 1_000_000_000)
    position = send(Opcode.GAP, AP.ACTUAL_POSITION, 0)[1]
    assert -(2**23) <= position < -(2**23) + 10_000  # past the top: counting on from the bottom
    send(Opcode.MST, 0, 0)
    module.advance_to(module.now_ns + 1_000_000_000)
    here = send(Opcode.GAP, AP.ACTUAL_POSITION, 0)[1]
    assert send(Opcode.MVP, 1, -20_000) == (Status.OK, -20_000)  # back across the wrap
    module.advance_to(module.now_ns + 5_000_000_000)
    assert send(Opcode.GAP, AP.TARGET_POSITION, 0)[1] == here - 20_000 + 2**24
    assert send(Opcode.GAP, AP.ACTUAL_POSITION, 0)[1] == here - 20_000 + 2**24
    assert send(Opcode.GAP, AP.POSITION_REACHED, 0)[1] == 1


def test_ror_beyond_2047_writes_the_12_bit_v_target_as_the_firmware_does() -> None:
    """Issue 34, item 6: TMCL-LITE-1110 writes ROR's value into the 12-bit V_TARGET
    (``Write429Short``): 3000 is -1096 there, so the motor runs left at 1096 and AP 2 reads
    -1096; ROL 3000 writes -3000, +1096: right.  SAP 2 keeps the manual's range."""
    module = TMCLModule(kind="tmcm-1110")

    def send(opcode: int, type_: int, value: int) -> tuple[int, int]:
        reply = module.execute(Request(1, opcode, type_, 0, value))
        return reply.status, reply.value

    assert send(Opcode.SAP, AP.TARGET_SPEED, 3000)[0] == Status.INVALID_VALUE
    send(Opcode.ROR, 0, 3000)
    module.advance_to(module.now_ns + 2_000_000_000)
    assert send(Opcode.GAP, AP.TARGET_SPEED, 0)[1] == -1096
    assert send(Opcode.GAP, AP.ACTUAL_SPEED, 0)[1] == -1096
    send(Opcode.ROL, 0, 3000)
    module.advance_to(module.now_ns + 2_000_000_000)
    assert send(Opcode.GAP, AP.ACTUAL_SPEED, 0)[1] == 1096


@pytest.mark.parametrize("kind", ["tmcm-3110", "tmcm-1110"])
def test_the_encoder_prescaler_takes_what_published_programs_write(kind: str) -> None:
    """Issue 34, item 12: four published FLIR programs for the TMCM-3110 write SAP 210, m,
    4674113; the range was 0..65535 (inferred), the module takes it."""
    module = TMCLModule(kind=kind)
    for motor in range(module.type.number_of_axes):
        reply = module.execute(Request(1, Opcode.SAP, AP.ENCODER_RESOLUTION, motor, 4674113))
        assert reply.status == Status.OK
        assert module.execute(Request(1, Opcode.GAP, AP.ENCODER_RESOLUTION, motor, 0)).value == 4674113
    module.execute(Request(1, Opcode.MVP, 0, 0, 1000))
    module.advance_to(module.now_ns + 1_000_000_000)
    assert module.execute(Request(1, Opcode.GAP, AP.ENCODER_POSITION, 0, 0)).status == Status.OK
