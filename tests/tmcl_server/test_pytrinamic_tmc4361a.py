"""pytrinamic, unchanged, against the TMC4361A: the TMCM-6212 on ``--axis-core tmc4361a``, and
``--module-type landungsbruecke-tmc4361a`` through pytrinamic's own ``Landungsbruecke`` and
``TMC4361_eval`` classes, over TCP and over a real pty, on the virtual clock.

Move times are checked the way a host sees them: polling the position and whether the motor
moves (STATUS VEL_STATE, exact even below the 1 pps VACTUAL shows; AP 3 on the TMCM-6212) a
few µs before and after the instant the datasheet's formula gives (the formulas are
tests/axes/test_tmc4361a.py's): still moving before, at rest on the target after.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest
from pytrinamic.evalboards import TMC4361_eval
from pytrinamic.ic import TMC4361
from pytrinamic.modules import TMCM6212, Landungsbruecke
from pytrinamic.tmcl import TMCLReplyStatusError

from tests.axes.test_tmc4361a import _s_time, _sixpoint_time
from tests.helpers.pytrinamic_link import connect
from tmcl_server.embed import SimulatorThread

REG = TMC4361.REG
NS = 1_000_000_000
#: How close to the formula a host polling the position sees the move end (s): the landing
#: margin (a few clocks of 62.5 ns) and, for S-ramps, half a bow quantum (32 clocks).
MARGIN_S = 5e-6


@pytest.fixture(params=["tcp", "pty"])
def path(request: pytest.FixtureRequest) -> str:
    return request.param


def _simulator(tmp_path, **options) -> SimulatorThread:  # type: ignore[no-untyped-def]
    return SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"],
                           pty=[str(tmp_path / "ttyTMCL0")], **options)


def now(sim: SimulatorThread) -> float:
    """The simulated time, in seconds."""
    return sim.call(lambda: sim.simulation.now_ns) / NS


def expect_end(sim: SimulatorThread, state: Callable[[], tuple[int, int]], target: int,
               seconds: float, start: float | None = None) -> None:
    """The move started at ``start`` (default: now) ends ``seconds`` later (within MARGIN_S):
    ``state()`` is (position, velocity)."""
    start = now(sim) if start is None else start
    sim.advance(start + seconds - MARGIN_S - now(sim))
    assert state()[1] != 0, "at rest too early"
    sim.advance(2 * MARGIN_S)
    assert state() == (target, 0), "not there yet"


#: STATUS VEL_STATE_F (bits 4..3): 0 at rest.
VEL_STATE = 0b11 << 3


def registers_state(board: TMC4361_eval) -> Callable[[], tuple[int, int]]:
    return lambda: (board.read_register(REG.XACTUAL, signed=True),
                    board.read_register(REG.STATUS) & VEL_STATE)


def parameters_state(motor, board: TMC4361_eval | None = None  # type: ignore[no-untyped-def]
                     ) -> Callable[[], tuple[int, int]]:
    """AP 1, and AP 3 (TMCM-6212) or the eval board's STATUS VEL_STATE."""
    if board is None:
        return lambda: (motor.get_actual_position(), motor.get_actual_velocity())
    return lambda: (motor.get_actual_position(), board.read_register(REG.STATUS) & VEL_STATE)


# == the TMCM-6212 on TMC4361A cores ==============================================================


@pytest.fixture
def tmcm(tmp_path, path: str) -> Iterator[tuple[SimulatorThread, TMCM6212, object]]:  # type: ignore[no-untyped-def]
    with _simulator(tmp_path, axis_core="tmc4361a") as sim:
        connection = connect(sim, path)
        yield sim, TMCM6212(connection), connection
        connection.close()


def test_tmcm6212_cruises_at_two_million_pps(tmcm: tuple) -> None:
    sim, module, iface = tmcm
    motor = module.motors[0]
    for ap, value in ((motor.AP.MaxVelocity, 2_000_000), (motor.AP.MaxAcceleration, 4_000_000),
                      (motor.AP.MaxDeceleration, 4_000_000)):
        motor.set_axis_parameter(ap, value)
    motor.move_to(6_000_000)
    sim.advance(1.0)
    assert motor.get_actual_velocity() == 2_000_000  # GAP 3
    assert motor.get_axis_parameter(motor.AP.MeasuredSpeed) == 2_000_000  # AP 29
    assert iface.read_mc(REG.VMAX) == 2_000_000 << 8  # 148 (pytrinamic's read_mc)


def test_tmcm6212_decelerates_with_ap17_and_ends_on_the_formula(tmcm: tuple) -> None:
    sim, module, _ = tmcm
    motor = module.motors[0]
    d, v, a, dec = 2_000_000, 1_000_000, 2_000_000, 400_000
    for ap, value in ((motor.AP.MaxVelocity, v), (motor.AP.MaxAcceleration, a),
                      (motor.AP.MaxDeceleration, dec), (motor.AP.StopVelocity, 0)):
        motor.set_axis_parameter(ap, value)
    start = now(sim)
    motor.move_to(d)
    total = d / v + v / (2 * a) + v / (2 * dec)  # 2 + 0.25 + 1.25 s
    sim.advance(total - 1.0)
    braking = motor.get_actual_velocity()  # 1 s before the end: 1 s of AP 17 left
    sim.advance(0.5)
    assert braking == pytest.approx(dec * 1.0, abs=4)  # not AP 5's 2 000 000 pps²
    assert braking - motor.get_actual_velocity() == pytest.approx(dec * 0.5, abs=4)
    expect_end(sim, parameters_state(motor), d, total, start)


def test_tmcm6212_147_reads_tmc4361a_registers(tmcm: tuple) -> None:
    _, module, iface = tmcm
    assert iface.send(147, REG.VERSION_NO, 0, 0).value == 2  # 147: READ_MC on the TMCM-6212
    iface.send(146, REG.XACTUAL, 1, 123_456)
    assert module.motors[1].get_actual_position() == 123_456


# == the Landungsbruecke with a TMC4361A-EVAL =====================================================


@pytest.fixture
def eval_setup(tmp_path, path: str) -> Iterator[tuple[SimulatorThread, object]]:  # type: ignore[no-untyped-def]
    with _simulator(tmp_path, module_type="landungsbruecke-tmc4361a") as sim:
        connection = connect(sim, path)
        yield sim, connection
        connection.close()


def test_board_detection(eval_setup: tuple[SimulatorThread, object]) -> None:
    _, iface = eval_setup
    assert iface.get_version_string() == "0012V311"
    lb = Landungsbruecke(iface)
    assert lb.detect_board_ids() == (11, 0)  # TMC4361A on channel 1, no driver board
    assert lb.get_board_names() == ("TMC4361A", "None")
    assert iface.get_global_parameter(Landungsbruecke.GP.BoardAssignment, 0) == 0x0600_020B
    assert lb.id_eeprom_mc.read_id_info() == {"description": "TMC4361A-EVAL", "id": 11,
                                              "hw_major": 1, "hw_minor": 3}
    assert lb.id_eeprom_drv.read_id_info() is None
    with pytest.raises(TMCLReplyStatusError) as refused:
        iface.send(13, 0, 0, 0)  # RFS: not an evaluation-firmware command
    assert refused.value.reply.status == 2


def test_register_access_by_tmc4361_names(eval_setup: tuple[SimulatorThread, object]) -> None:
    _, iface = eval_setup
    board = TMC4361_eval(iface)
    assert board.read_register(REG.VERSION_NO) == 2
    assert board.read_register(REG.CLK_FREQ) == 16_000_000
    assert board.read_register(REG.RAMPMODE) == 1  # the firmware's reset values
    assert board.read_register(REG.AMAX) == 20_000 << 2
    board.write_register(REG.XTARGET, -5)
    assert board.read_register(REG.XTARGET, signed=True) == -5
    # a write-only register reads back from the firmware's cache, as on the board
    assert board.read_register(REG.ENC_POS_DEV_TOL) == 0xFFFF_FFFF
    board.write_register(REG.ENC_POS_DEV_TOL, 1234)
    assert board.read_register(REG.ENC_POS_DEV_TOL) == 1234


def test_axis_parameters_of_the_eval_class(eval_setup: tuple[SimulatorThread, object]) -> None:
    _, iface = eval_setup
    board = TMC4361_eval(iface)
    motor = board.motors[0]
    ap = motor.AP
    plain = (ap.TargetPosition, ap.ActualPosition, ap.TargetVelocity, ap.MaxVelocity,
             ap.MaxAcceleration, ap.AStart, ap.MaxDeceleration, ap.DFinal, ap.BOW1, ap.BOW2,
             ap.BOW3, ap.BOW4, ap.VirtualStopLeft, ap.VirtualStopRight)
    for number in plain:
        motor.set_axis_parameter(number, 1000 + number)
        assert motor.get_axis_parameter(number) == 1000 + number, number
    # the firmware's own scalings: VSTART/VBREAK/VSTOP registers hold value / 256, DSTOP
    # value / 4, STDBY_DELAY value * 160 000
    for number, register in ((ap.StartVelocity, REG.VSTART), (ap.VBreak, REG.VBREAK),
                             (ap.StopVelocity, REG.VSTOP)):
        motor.set_axis_parameter(number, 700 * 256)
        assert board.read_register(register) == 700
        assert motor.get_axis_parameter(number) == 700 * 256
    motor.set_axis_parameter(ap.DSTOP, 4000)
    assert board.read_register(REG.DSTOP) == 1000 and motor.get_axis_parameter(ap.DSTOP) == 4000
    motor.set_axis_parameter(ap.PowerDownDelay, 2)
    assert motor.get_axis_parameter(ap.PowerDownDelay) == 320_000
    motor.set_axis_parameter(ap.RampType, 1)
    assert motor.get_axis_parameter(ap.RampType) == 1 and board.read_register(REG.RAMPMODE) == 2
    assert motor.get_axis_parameter(ap.ActualVelocity) == 0
    assert motor.get_axis_parameter(ap.PositionReachedFlag) == 0  # XACTUAL 1001, XTARGET 1000
    with pytest.raises(TMCLReplyStatusError) as refused:
        motor.set_axis_parameter(ap.MaxAcceleration, 1 << 22)
    assert refused.value.reply.status == 4
    with pytest.raises(TMCLReplyStatusError) as refused:
        motor.get_axis_parameter(6)  # not served by the evaluation firmware
    assert refused.value.reply.status == 2


SIXPOINT = dict(d=300_000, vstart=500, vbreak=20_000, vmax=60_000, vstop=1_000, astart=40_000,
                amax=20_000, dmax=30_000, dfinal=50_000)
S_RAMP = dict(d=400_000, vmax=100_000, amax=100_000, dmax=80_000,
              bows=(400_000, 300_000, 250_000, 350_000))


def _sixpoint_seconds() -> float:
    c = SIXPOINT
    return _sixpoint_time(c["d"], c["vstart"], c["vbreak"], c["vmax"], c["vstop"], c["astart"],
                          c["amax"], c["dmax"], c["dfinal"])


def test_sixpoint_move_by_registers(eval_setup: tuple[SimulatorThread, object]) -> None:
    sim, iface = eval_setup
    board = TMC4361_eval(iface)
    c = SIXPOINT
    for register, value in ((REG.VSTART, c["vstart"] << 8), (REG.VBREAK, c["vbreak"] << 8),
                            (REG.VSTOP, c["vstop"] << 8), (REG.ASTART, c["astart"] << 2),
                            (REG.AMAX, c["amax"] << 2), (REG.DMAX, c["dmax"] << 2),
                            (REG.DFINAL, c["dfinal"] << 2), (REG.VMAX, c["vmax"] << 8),
                            (REG.RAMPMODE, 0b101)):
        board.write_register(register, value)
    board.write_register(REG.XTARGET, c["d"])
    expect_end(sim, registers_state(board), c["d"], _sixpoint_seconds())
    assert board.read_register(REG.VACTUAL) == 0


def test_sixpoint_move_by_axis_parameters(eval_setup: tuple[SimulatorThread, object]) -> None:
    sim, iface = eval_setup
    board = TMC4361_eval(iface)
    motor = board.motors[0]
    ap, c = motor.AP, SIXPOINT
    for number, value in ((ap.RampType, 0), (ap.StartVelocity, c["vstart"] * 65536),
                          (ap.VBreak, c["vbreak"] * 65536), (ap.StopVelocity, c["vstop"] * 65536),
                          (ap.AStart, c["astart"]), (ap.MaxAcceleration, c["amax"]),
                          (ap.MaxDeceleration, c["dmax"]), (ap.DFinal, c["dfinal"])):
        motor.set_axis_parameter(number, value)
    motor.move_to(c["d"], c["vmax"])  # AP 4, then MVP
    expect_end(sim, parameters_state(motor, board), c["d"], _sixpoint_seconds())
    assert motor.get_axis_parameter(ap.PositionReachedFlag) == 1


def test_s_shaped_move_by_registers(eval_setup: tuple[SimulatorThread, object]) -> None:
    sim, iface = eval_setup
    board = TMC4361_eval(iface)
    c = S_RAMP
    for register, value in ((REG.AMAX, c["amax"] << 2), (REG.DMAX, c["dmax"] << 2),
                            (REG.BOW1, c["bows"][0]), (REG.BOW2, c["bows"][1]),
                            (REG.BOW3, c["bows"][2]), (REG.BOW4, c["bows"][3]),
                            (REG.VMAX, c["vmax"] << 8), (REG.RAMPMODE, 0b110)):
        board.write_register(register, value)
    board.write_register(REG.XTARGET, c["d"])
    expect_end(sim, registers_state(board), c["d"],
               _s_time(c["d"], c["vmax"], c["amax"], c["dmax"], c["bows"]))


def test_s_shaped_move_by_axis_parameters(eval_setup: tuple[SimulatorThread, object]) -> None:
    sim, iface = eval_setup
    board = TMC4361_eval(iface)
    motor = board.motors[0]
    ap, c = motor.AP, S_RAMP
    for number, value in ((ap.RampType, 1), (ap.MaxAcceleration, c["amax"]),
                          (ap.MaxDeceleration, c["dmax"]), (ap.BOW1, c["bows"][0]),
                          (ap.BOW2, c["bows"][1]), (ap.BOW3, c["bows"][2]),
                          (ap.BOW4, c["bows"][3]), (ap.MaxVelocity, c["vmax"])):
        motor.set_axis_parameter(number, value)
    motor.move_to(c["d"])
    expect_end(sim, parameters_state(motor, board), c["d"],
               _s_time(c["d"], c["vmax"], c["amax"], c["dmax"], c["bows"]))
    motor.rotate(-50_000)  # ROR: velocity mode, the S-profile stays
    sim.advance(3)
    assert motor.get_actual_velocity() == -50_000
    motor.stop()
    sim.advance(3)
    assert motor.get_actual_velocity() == 0
