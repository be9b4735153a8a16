"""The TMCM-6212 firmware layer over the emulated TMC4361A (``--axis-core tmc4361a``).

What the TMC4361A core adds to the TMC4210's: the manual's whole speed and acceleration
ranges, the six-point ramp of Table 14 (AP 15-21, AP 17 apart from AP 5), S-ramps chosen
through command 146, the manual's internal units in unit mode 0, and 32-bit register access.
Move times are held against the datasheet formulas of tests/axes/test_tmc4361a.py.  The
generic behaviour (switches, stall, encoder, reference search) runs on both cores in
tests/axes/test_axis_firmware.py and tests/axes/test_reference_search.py.
"""

from __future__ import annotations

import pytest

from axes.chips.tmc4361a import TMC4361A, Event, Reg
from axes.chips.tmc4361a.firmware import TMC4361AAxis
from axes.interface import AxisEventKind
from axes.world import AxisWorld, Switch
from tests.axes.test_axis_firmware import CORES, Harness
from tests.axes.test_tmc4361a import _s_time, _sixpoint_time
from tmcl_spec.parameters import AP
from tmcl_spec.tmcm6212 import MAX_ACCELERATION_PPS2, MAX_VELOCITY_PPS

NS = 1_000_000_000
CLOCK = 16_000_000
#: One chip clock, in ns: the ramp is updated every clock.
CLOCK_NS = NS / CLOCK


def harness() -> Harness:
    return Harness(axis_class=TMC4361AAxis)


def move(h: Harness, target: int, **parameters: int) -> float:
    """Set axis parameters (AP_NAME=value), move, and return the move time in seconds."""
    for name, value in parameters.items():
        h.sap(getattr(AP, name.upper()), value)
    start = h.now
    h.axis.move_to(target)
    event = h.until(AxisEventKind.TARGET_REACHED, timeout_s=600)
    assert h.gap(AP.ACTUAL_POSITION) == target
    return (event.time_ns - start) / NS


# == speed and acceleration ======================================================================


def test_cruise_at_two_million_pps_reads_back_on_ap3_and_ap29() -> None:
    h = harness()
    h.sap(AP.MAX_SPEED, 2_000_000)
    h.sap(AP.MAX_ACCELERATION, 4_000_000)
    h.sap(AP.MAX_DECELERATION, 4_000_000)
    h.axis.move_to(8_000_000)
    h.advance(1.0)
    assert h.gap(AP.ACTUAL_SPEED) == 2_000_000
    assert h.gap(AP.MEASURED_SPEED) == 2_000_000
    assert h.axis.register_access(Reg.VMAX) == 2_000_000 << 8  # the chip's own unit


def test_deceleration_follows_ap17_apart_from_ap5_and_the_move_time_matches() -> None:
    h = harness()
    d, v, a, dec = 3_000_000, 1_000_000, 2_000_000, 250_000
    elapsed = move(h, d, max_speed=v, max_acceleration=a, max_deceleration=dec, vstop=0)
    expected = d / v + v / (2 * a) + v / (2 * dec)  # trapezoid: 0.25 s up, 2 s down
    # the ramp is updated every clock; the move ends within the landing margin past the
    # formula: at most 1 + AMAX/DMAX clocks of VMAX travel (docs/tmc4361a.md), + 1 rounding
    assert 0 <= elapsed - expected <= (2 + a / dec) * CLOCK_NS / NS
    # the speed on the way down falls by AP 17 per second, not AP 5
    replay = harness()
    for number, value in ((AP.MAX_SPEED, v), (AP.MAX_ACCELERATION, a),
                          (AP.MAX_DECELERATION, dec), (AP.VSTOP, 0)):
        replay.sap(number, value)
    replay.axis.move_to(d)
    replay.advance(expected - 1.0)  # one second before the end: 1 s of braking left
    assert replay.gap(AP.ACTUAL_SPEED) == pytest.approx(dec * 1.0, abs=2)


def test_ap17_changed_in_flight_takes_effect_and_mst_brakes_with_ap5() -> None:
    h = harness()
    for number, value in ((AP.MAX_SPEED, 400_000), (AP.MAX_ACCELERATION, 800_000),
                          (AP.MAX_DECELERATION, 100_000), (AP.VSTOP, 0)):
        h.sap(number, value)
    h.axis.move_to(10_000_000)
    h.advance(1.0)
    h.sap(AP.MAX_DECELERATION, 400_000)
    arrived = move(h, 10_000_000)
    # 0.5 s up, cruise, 1 s down at 400 000 pps² (4 s at the old 100 000)
    assert arrived + 1.0 == pytest.approx(10_000_000 / 400_000 + 0.25 + 0.5, abs=1e-6)
    h.axis.move_to(0)
    h.advance(2.0)
    h.axis.stop()  # MST: velocity mode, decelerating with AP 5 (800 000 pps²)
    h.advance(0.25)
    assert h.gap(AP.ACTUAL_SPEED) == pytest.approx(-200_000, abs=2)
    h.advance(0.3)
    assert h.gap(AP.ACTUAL_SPEED) == 0


def test_the_manuals_full_speed_and_acceleration_ranges() -> None:
    """The chip positions at most at f/4 (datasheet §6.7.2, Table 18: 4 000 000 pps at
    16 MHz), so the manual's AP 4 range (7 999 774 pps) is taken up to there (issue 34, item
    7: beyond it a value was read back that no move ran); it rotates at up to f/2, so a
    rotation runs at the full range."""
    h = harness()
    with pytest.raises(ValueError):
        h.sap(AP.MAX_SPEED, MAX_VELOCITY_PPS)
    h.sap(AP.MAX_SPEED, CLOCK // 4)
    h.sap(AP.MAX_ACCELERATION, MAX_ACCELERATION_PPS2)
    h.sap(AP.MAX_DECELERATION, MAX_ACCELERATION_PPS2)
    h.axis.move_to(2_000_000_000)
    h.advance(0.5)
    # beyond the real-unit range (4 194 303 pps²) the chip runs on direct values: 4096 LSB of
    # f²/2^37 = 7 629 394.5 pps², 0.0015 % off the parameter
    assert h.gap(AP.ACTUAL_SPEED) == pytest.approx(MAX_ACCELERATION_PPS2 * 0.5, rel=2e-5)
    assert h.axis.register_access(Reg.GENERAL_CONF) & 0b10
    h.advance(1.0)
    assert h.gap(AP.MAX_SPEED) == CLOCK // 4
    assert h.gap(AP.ACTUAL_SPEED) == CLOCK // 4
    assert h.axis.register_access(Reg.VMAX) == (CLOCK // 4) << 8
    h.axis.rotate(-MAX_VELOCITY_PPS)
    h.advance(3.0)
    assert h.gap(AP.ACTUAL_SPEED) == -MAX_VELOCITY_PPS


@pytest.mark.parametrize("clock", [16_000_000, 10_000_000])
def test_the_datasheets_speed_ceiling_in_each_mode(clock: int) -> None:
    """|VMAX| <= f/4 in positioning, <= f/2 in velocity mode (datasheet §6.7.2): beyond them
    the real chip makes wrong step pulses or positions wrongly, so the firmware refuses a
    positioning speed beyond f/4 (issue 34, item 7: it used to take it and run slower) and
    runs a rotation at up to f/2, AP 2 keeping the value the host wrote."""
    h = Harness(axis_class=lambda index, parameters, world=None: TMC4361AAxis(
        index, parameters, world=world, clock_hz=clock))
    h.sap(AP.MAX_ACCELERATION, MAX_ACCELERATION_PPS2)
    h.sap(AP.MAX_DECELERATION, MAX_ACCELERATION_PPS2)
    h.sap(AP.MAX_SPEED, 1_000_000)
    h.axis.move_to(1_000_000_000)
    h.advance(0.5)
    assert h.gap(AP.ACTUAL_SPEED) == 1_000_000
    with pytest.raises(ValueError, match="f/4"):  # the module's status 4
        h.sap(AP.MAX_SPEED, clock // 4 + 1)
    h.sap(AP.MAX_SPEED, clock // 4)  # on the fly
    h.advance(1.5)
    assert (h.gap(AP.ACTUAL_SPEED), h.gap(AP.MAX_SPEED)) == (clock // 4, clock // 4)
    h.axis.rotate(7_000_000)
    h.advance(1.5)
    assert (h.gap(AP.ACTUAL_SPEED), h.gap(AP.TARGET_SPEED)) == (min(7_000_000, clock // 2),
                                                                 7_000_000)


# == the six-point ramp of Table 14 ==============================================================


@pytest.mark.parametrize("case", [
    # d, VSTART, V1, VMAX, VSTOP, A1, AP 5, AP 17, D1
    (1_200_000, 500, 50_000, 200_000, 1_000, 100_000, 60_000, 80_000, 120_000),
    (1_000_000, 5_000, 100_000, 400_000, 8_000, 400_000, 250_000, 300_000, 500_000),
])
def test_table_14_sixpoint_ramp_move_time(case: tuple) -> None:
    d, vstart, v1, vmax, vstop, a1, amax, dmax, d1 = case
    h = harness()
    elapsed = move(h, d, vstart=vstart, v1=v1, max_speed=vmax, vstop=vstop, a1=a1,
                   max_acceleration=amax, max_deceleration=dmax, d1=d1)
    expected = _sixpoint_time(d, vstart, v1, vmax, vstop, a1, amax, dmax, d1)
    assert 0 <= elapsed - expected <= 4 * CLOCK_NS / NS


def test_v1_zero_turns_the_first_phase_off_and_ap21_waits_at_a_reversal() -> None:
    h = harness()
    elapsed = move(h, 512_000, max_speed=51_200, max_acceleration=51_200,
                   max_deceleration=51_200, a1=1000, d1=1000, v1=0, vstop=0)
    assert elapsed == pytest.approx(11.0, abs=1e-6)  # A1/D1 unused: the manual's trapezoid
    h.sap(AP.RAMP_WAIT, 31_250)  # 31 250 x 32 µs = 1 s standstill at a direction reversal
    h.axis.rotate(51_200)
    h.advance(2.0)
    h.axis.rotate(-51_200)  # 1 s down to 0, 1 s waiting, then up again
    h.advance(1.5)
    assert h.gap(AP.ACTUAL_SPEED) == 0
    h.advance(1.0)
    assert h.gap(AP.ACTUAL_SPEED) == pytest.approx(-25_600, abs=2)
    assert AxisEventKind.CURRENT_CHANGED not in h.kinds()  # the wait is no standstill


def test_s_ramps_through_command_146_survive_the_next_move() -> None:
    h = harness()
    d, vmax, amax, dmax, bows = 712_000, 200_000, 100_000, 80_000, (400_000, 300_000, 250_000,
                                                                    350_000)
    rampmode = h.axis.register_access(Reg.RAMPMODE)
    h.axis.register_access(Reg.RAMPMODE, (rampmode & ~0b11) | 0b10)  # S-shaped profile
    for reg, bow in zip((Reg.BOW1, Reg.BOW2, Reg.BOW3, Reg.BOW4), bows, strict=True):
        h.axis.register_access(reg, bow)
    elapsed = move(h, d, max_speed=vmax, max_acceleration=amax, max_deceleration=dmax, vstop=0)
    assert h.axis.register_access(Reg.RAMPMODE) == 0b110  # positioning, still S-shaped
    # within half a bow quantum (32 clocks) of the datasheet's segment kinematics
    assert abs(elapsed - _s_time(d, vmax, amax, dmax, bows)) <= 64 * CLOCK_NS / NS
    h.axis.rotate(100_000)
    h.advance(2)
    assert h.gap(AP.ACTUAL_SPEED) == 100_000
    assert h.axis.register_access(Reg.RAMPMODE) == 0b010  # velocity mode, S-shaped


# == units ======================================================================================


def test_unit_mode_0_uses_the_manuals_internal_units() -> None:
    """Velocity unit f/2^24 pps (0.954 pps at 16 MHz), acceleration unit f²/2^41 pps²."""
    h = harness()
    h.sap(AP.UNIT_MODE, 0)
    h.sap(AP.MAX_ACCELERATION, 8590)  # 8590 x 116.415 = 1 000 004 pps²
    h.axis.rotate(1_048_576)  # 2^20 units = 1 000 000 pps
    h.advance(0.5)
    assert h.axis.register_access(Reg.VACTUAL) == pytest.approx(500_002, abs=2)
    h.advance(1.0)
    assert h.axis.register_access(Reg.VACTUAL) == 1_000_000
    assert h.gap(AP.ACTUAL_SPEED) == 1_048_576
    assert h.gap(AP.MEASURED_SPEED) == 1_048_576


# == commands 146/147 ============================================================================


def test_register_access_is_32_bit_data_and_writes_bypass_the_firmware() -> None:
    h = harness()
    assert h.axis.register_access(Reg.VERSION_NO) == 2
    assert h.axis.register_access(Reg.CLK_FREQ) == CLOCK
    h.axis.register_access(Reg.XACTUAL, -123_456)
    assert h.gap(AP.ACTUAL_POSITION) == -123_456
    assert h.axis.register_access(Reg.XACTUAL) == -123_456  # no status byte in the answer
    h.axis.register_access(Reg.VMAX, 10_000 << 8)  # velocity mode after power-up: it runs
    h.advance(1)
    assert h.gap(AP.ACTUAL_SPEED) == 10_000


# == stop switches: a direction is blocked only while its switch is active (issue 24, item 1) ====


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize(("polarity", "speed"), [(AP.RIGHT_POLARITY, 20_000),
                                                 (AP.LEFT_POLARITY, -20_000)])
def test_a_polarity_toggled_at_standstill_leaves_no_direction_blocked(
        core: str, polarity: int, speed: int) -> None:
    """``SAP 24, 0, 1; SAP 24, 0, 0`` with no switch in the world: the inverted input reads
    the switch active for a moment, the chip latches its stop event (datasheet §8.1.2: at
    standstill too) and kept that direction locked, so ``ROR 0, 20000`` never moved.  The
    firmware clears the stale event before a motion command; both cores now move."""
    h = Harness(axis_class=CORES[core])
    h.sap(polarity, 1)
    assert h.gap(AP.RIGHT_SWITCH if speed > 0 else AP.LEFT_SWITCH) == 1
    h.sap(polarity, 0)
    h.axis.rotate(speed)
    h.advance(0.5)
    assert h.gap(AP.ACTUAL_SPEED) == pytest.approx(speed, abs=5)
    assert h.gap(AP.ACTUAL_POSITION) * speed > 0


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize(("standing_on", "speed"), [("left", 20_000), ("right", -20_000)])
def test_swapping_switches_back_while_standing_on_one_leaves_the_other_side_free(
        core: str, standing_on: str, speed: int) -> None:
    """AP 14 toggled 1 -> 0 while the motor stands on a switch: for a moment the switch was
    the other side's, whose event stayed latched.  Moving away from the real switch works;
    moving into it stays blocked while it is active."""
    side = "below" if standing_on == "left" else "above"
    h = Harness(AxisWorld(switches={standing_on: Switch.place(0, side=side)}), CORES[core])
    h.sap(AP.SWAP_SWITCHES, 1)
    h.sap(AP.SWAP_SWITCHES, 0)
    h.axis.rotate(-speed)  # into the switch it stands on: blocked
    h.advance(0.5)
    assert (h.gap(AP.ACTUAL_SPEED), h.gap(AP.ACTUAL_POSITION)) == (0, 0)
    h.axis.rotate(speed)  # away from it
    h.advance(0.5)
    assert h.gap(AP.ACTUAL_SPEED) == pytest.approx(speed, abs=5)
    assert h.gap(AP.ACTUAL_POSITION) * speed > 0


@pytest.mark.parametrize("core", CORES)
def test_a_switch_released_at_standstill_frees_its_direction_for_mvp(core: str) -> None:
    """A switch the world closes and opens again (here: puts under the motor and takes away)
    while the motor stands still: an MVP toward that side moves and arrives."""
    h = Harness(axis_class=CORES[core])
    h.axis.set_switch("right", Switch.place(0, side="above"))
    assert h.gap(AP.RIGHT_SWITCH) == 1
    h.axis.set_switch("right", Switch.place(50_000, side="above"))
    assert h.gap(AP.RIGHT_SWITCH) == 0
    h.axis.move_to(10_000)
    h.until(AxisEventKind.TARGET_REACHED, timeout_s=5)
    assert h.gap(AP.ACTUAL_POSITION) == 10_000


# == a target inside the braking distance (issue 24, item 2) =====================================


@pytest.mark.parametrize("s_ramp", [False, True])
def test_a_new_target_inside_the_braking_distance_is_reached_with_vstop(s_ramp: bool) -> None:
    """AP 20 at its factory value (10 pps): an MVP to a target closer than the braking
    distance used to end in a VSTOP crawl away from it for ever (87 936 steps past after
    20 s, AP 8 = 0).  The move passes the target, turns (datasheet §6.6) and arrives."""
    h = harness()
    assert h.gap(AP.VSTOP) == 10
    if s_ramp:
        rampmode = h.axis.register_access(Reg.RAMPMODE)
        h.axis.register_access(Reg.RAMPMODE, (rampmode & ~0b11) | 0b10)
        for reg in (Reg.BOW1, Reg.BOW2, Reg.BOW3, Reg.BOW4):
            h.axis.register_access(reg, 400_000)  # BOW2 = BOW4: the U-turn passes through 0
    for number, value in ((AP.MAX_SPEED, 100_000), (AP.MAX_ACCELERATION, 51_200),
                          (AP.MAX_DECELERATION, 51_200)):
        h.sap(number, value)
    h.axis.move_to(10_000_000)
    h.advance(3.0)
    assert h.gap(AP.ACTUAL_SPEED) == 100_000
    target = h.gap(AP.ACTUAL_POSITION) + 10_000
    h.axis.move_to(target)
    h.until(AxisEventKind.TARGET_REACHED, timeout_s=20)
    assert (h.gap(AP.ACTUAL_POSITION), h.gap(AP.POSITION_REACHED), h.gap(AP.ACTUAL_SPEED)) == (
        target, 1, 0)
    h.advance(1.0)
    assert h.gap(AP.ACTUAL_POSITION) == target


# == remembered runs through the firmware (issue 23, item 4) =====================================


@pytest.mark.parametrize("s_ramp", [False, True])
def test_remembered_runs_change_nothing_a_host_sees(s_ramp: bool,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    """The manual's program (MVP ±512000) on one axis and a rotation reversed every 7 s on
    another, through the firmware and its look-ahead: with the chip replaying runs it has
    seen, every event comes at the same instant and every reading is the same as with a
    chip that works each run out."""
    replays = 0
    replay = TMC4361A._replay

    def counted(chip: TMC4361A, *args) -> None:  # type: ignore[no-untyped-def]
        nonlocal replays
        replays += 1
        replay(chip, *args)

    monkeypatch.setattr(TMC4361A, "_replay", counted)

    def session(recall: bool) -> list[tuple]:
        monkeypatch.setattr(TMC4361A, "recall", recall)
        mover, rotor = harness(), harness()
        for h in (mover, rotor):
            if s_ramp:
                rampmode = h.axis.register_access(Reg.RAMPMODE)
                h.axis.register_access(Reg.RAMPMODE, (rampmode & ~0b11) | 0b10)
                for reg in (Reg.BOW1, Reg.BOW2, Reg.BOW3, Reg.BOW4):
                    h.axis.register_access(reg, 400_000)
            h.sap(AP.MAX_SPEED, 200_000)
            h.sap(AP.MAX_ACCELERATION, 100_000)
        seen: list[tuple] = []
        target, speed = 512_000, 80_000
        mover.axis.move_to(target)
        rotor.axis.rotate(speed)
        for _ in range(40):
            event = mover.until(AxisEventKind.TARGET_REACHED, timeout_s=60)
            rotor.advance_to(event.time_ns)
            if event.time_ns // (7 * NS) != (event.time_ns - 1) // (7 * NS) or len(seen) % 3 == 0:
                speed = -speed
                rotor.axis.rotate(speed)
            seen.append((event.time_ns, mover.gap(AP.ACTUAL_POSITION), rotor.gap(AP.ACTUAL_POSITION),
                         rotor.gap(AP.ACTUAL_SPEED), rotor.axis.register_access(Reg.EVENTS)))
            target = -target
            mover.axis.move_to(target)
        return seen

    assert session(True) == session(False)
    assert replays > 40  # the moves (and the rotation's reversals) were replayed


def test_stop_events_are_cleared_at_standstill_as_the_tmc4361_firmware_does() -> None:
    """TMCL-LITE-1111 (Trinamic's TMCL firmware for the TMC4361 modules) reads and clears a
    STOPL/STOPR/VSTOPL/VSTOPR event in every main-loop pass while VACTUAL = 0: a host that
    reads EVENTS (command 147) after a switch came and went at standstill finds none.  While
    the motor moves the event stays, and locks its direction until the motor stands."""
    h = harness()
    h.sap(AP.RIGHT_POLARITY, 1)
    h.sap(AP.RIGHT_POLARITY, 0)
    assert not h.axis.register_access(Reg.EVENTS) & Event.STOPR
    h.axis.rotate(20_000)
    h.advance(0.5)
    h.axis.set_switch("left", Switch.place(h.gap(AP.ACTUAL_POSITION), side="below"))
    h.axis.set_switch("left", None)  # the left switch came and went while moving right
    assert h.axis.register_access(Reg.EVENTS) & Event.STOPL  # moving: kept
    h.axis.rotate(-20_000)  # down to 0 (the event locks the left side), then left
    h.advance(1.0)
    assert h.gap(AP.ACTUAL_SPEED) == -20_000


def test_the_tmc4361_modules_write_vmax_unclamped() -> None:
    """The speed ceiling is the TMCM-6212 core's choice; TMCL-LITE-1111 writes VMAX = pps << 8
    whatever it is, so a module with the TMC4361 modules' numbering positions as fast as it
    is told (the chip model does not emulate what goes wrong above f/4)."""
    from tmcl_server.clock import VirtualClock
    from tmcl_server.module import TMCLModule
    from tmcl_server.protocol import Request
    from tmcl_server.simulation import Simulation
    from tmcl_spec.commands import Opcode

    module = TMCLModule(kind="tmcm-1111")
    sim = Simulation([module], VirtualClock())
    for number, value in ((AP.MAX_SPEED, 6_000_000), (AP.MAX_ACCELERATION, 4_000_000),
                          (AP.MAX_DECELERATION, 4_000_000)):
        module.execute(Request(1, Opcode.SAP, number, 0, value))
    module.execute(Request(1, Opcode.MVP, 0, 0, 2_000_000_000))
    sim.replan()
    sim.advance(2.0)
    assert module.execute(Request(1, Opcode.GAP, AP.ACTUAL_SPEED, 0, 0)).value == 6_000_000


def test_a_positioning_speed_beyond_f_over_4_is_refused_not_silently_capped() -> None:
    """Issue 34, item 7: the core positions at up to f/4 (4 Mpps at 16 MHz, datasheet §6.7.2);
    AP 4 (and AP 195, the search's last move) beyond it used to be accepted and read back
    while the moves ran at 4 Mpps.  The module refuses it (status 4); rotations keep f/2."""
    from tmcl_server.module import TMCLModule
    from tmcl_server.protocol import Request
    from tmcl_spec.commands import Opcode, Status

    module = TMCLModule(kind="tmcm-6212", chip_core="tmc4361a")
    for number in (4, 195):
        refused = module.execute(Request(1, Opcode.SAP, number, 0, 4_000_001))
        assert refused.status == Status.INVALID_VALUE, number
        assert module.execute(Request(1, Opcode.GAP, number, 0, 0)).value != 4_000_001
        assert module.execute(Request(1, Opcode.SAP, number, 0, 4_000_000)).status == Status.OK
    module.execute(Request(1, Opcode.SAP, 5, 0, 7_000_000))
    assert module.execute(Request(1, Opcode.ROR, 0, 0, 7_999_774)).status == Status.OK
    module.advance_to(3_000_000_000)
    assert module.execute(Request(1, Opcode.GAP, 3, 0, 0)).value == 7_999_774
