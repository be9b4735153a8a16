"""The emulated TMC4210: register file, status byte, side effects, switches, and motion.

Motion is checked against ``tests.axes.reference_tmc4210.ReferenceChip``, a literal one-clk32-tick-at-a-time
transcription of the digest's model: the event-driven engine must land on the same position
and velocity at every instant, and stop at the same tick.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from axes.chips.tmc42x import fast_ramps
from axes.chips.tmc42x.tmc4210 import (
    EN_SD,
    MASK24,
    MOT1R,
    TMC4210,
    TYPE_VERSION,
    Irq,
    RampMode,
    Reg,
    Stop,
    datagram,
    signed,
)
from tests.axes.reference_tmc4210 import ReferenceChip
from tests.helpers.tmc42x import apply_change, configure, run_alongside

IDLE_STATUS = 0x15


def status(chip: TMC4210) -> int:
    return chip.spi(datagram(Reg.TYPE_VERSION, read=True)) >> 24


# == register file =============================================================================


def test_the_register_map_is_the_families_axis_and_global_registers() -> None:
    """One table for the family: the sixteen axis registers IDX 0..15, then the global ones
    at %011 JDX (the TMC4210's addresses, the TMC429's motor 0)."""
    addresses = [member.value for member in Reg]
    assert addresses[:16] == list(range(16))
    assert all(address >> 4 == 0b011 for address in addresses[16:])


def test_power_on_values_and_idle_status() -> None:
    chip = TMC4210()
    assert chip.spi(0x73000000) == IDLE_STATUS << 24 | TYPE_VERSION  # datasheet + real part
    assert chip.read(Reg.SMGP) == 0x000F00  # STPDIV = 15, everything else 0
    for reg in (Reg.X_TARGET, Reg.X_ACTUAL, Reg.V_MIN, Reg.V_MAX, Reg.V_TARGET, Reg.V_ACTUAL,
                Reg.A_MAX, Reg.A_ACTUAL, Reg.INTERRUPT, Reg.DIVIDERS, Reg.IF_CONFIGURATION):
        assert chip.read(reg) == 0, reg.name
    assert chip.read(Reg.PMUL_PDIV) == 0x8000  # PMUL bit 15 is hard-wired to 1


def test_digest_worked_datagrams() -> None:
    chip = TMC4210()
    assert chip.spi(0x1A000123) == IDLE_STATUS << 24  # a write answers status + 24 zero bits
    assert chip.spi(0x1B000000) == IDLE_STATUS << 24 | 0x000123
    assert chip.spi(0xFE002321) == IDLE_STATUS << 24  # RAM pair 63
    assert chip.spi(0xFF000000) & MASK24 == 0x2321


@pytest.mark.parametrize(("reg", "written", "read_back"), [
    (Reg.V_MAX, 0xFFF, 0x7FF),  # 11 bits
    (Reg.V_MIN, 0xFFFFFF, 0x7FF),
    (Reg.A_MAX, 0x1800, 0x000),
    (Reg.V_TARGET, 0xFFFF9C, 0xF9C),  # -100, zero-extended 12 bits
    (Reg.DX_REF_TOLERANCE, 0xFFFFFF, 0xFFF),
    (Reg.X_TARGET, 0xFFFFFF, 0xFFFFFF),
    (Reg.PMUL_PDIV, 0x007A0F, 0xFA0F),  # bit 15 forced
    (Reg.DIVIDERS, 0xFFFFFF, 0xFF07),
    (Reg.USTEP_COUNT, 0x1FF, 0xFF),
    (Reg.IF_CONFIGURATION, 0xFFFFFD, 0x1FD),  # sdo_int (bit 1) would turn reads off
    (Reg.SMGP, 0xFFFFFF, 0x31FFFF),
    (Reg.A_THRESHOLD, 0xFFFFFF, 0x777FFF),
])
def test_field_widths(reg: Reg, written: int, read_back: int) -> None:
    chip = TMC4210()
    chip.write(reg, written)
    assert chip.read(reg) == read_back


def test_read_only_registers_and_hidden_axes() -> None:
    chip = TMC4210()
    chip.write(Reg.TYPE_VERSION, 0)
    chip.write(Reg.A_ACTUAL, 0x123)
    assert chip.read(Reg.TYPE_VERSION) == TYPE_VERSION
    assert chip.read(Reg.A_ACTUAL) == 0
    chip.write(0x10, 0x1234)  # hidden axis 2 X_TARGET
    assert chip.read(0x10) == 0
    chip.write(Reg.V_ACTUAL, 5)  # ignored outside hold mode
    assert chip.read(Reg.V_ACTUAL) == 0
    chip.write(Reg.REF_CONF_RAMP_MODE, RampMode.HOLD)
    chip.write(Reg.V_ACTUAL, 0xFFF)
    assert chip.read(Reg.V_ACTUAL) == 0xFFF  # -1, zero-extended


def test_interrupt_register_sets_mask_and_clears_flags_in_one_write() -> None:
    chip = TMC4210()
    chip.write(Reg.INTERRUPT, 0xFF00)
    chip.int_flags = 0x05
    assert chip.spi(0) >> 31 == 1  # INT in every status byte
    chip.write(Reg.INTERRUPT, 0xFF01)  # clear pos_end only
    assert chip.read(Reg.INTERRUPT) == 0xFF04
    chip.write(Reg.INTERRUPT, 0x0000)  # clearing a mask bit forces its flag to 0
    assert chip.read(Reg.INTERRUPT) == 0
    assert status(chip) == IDLE_STATUS


def test_latch_arming_and_firing_on_a_reference_edge() -> None:
    chip = TMC4210()
    chip.write(Reg.X_LATCHED, 0x42)
    assert chip.read(Reg.REF_CONF_RAMP_MODE) >> 16 & 1  # lp set, value unchanged
    assert chip.read(Reg.X_LATCHED) == 0
    chip.write(Reg.X_ACTUAL, 1234)
    chip.set_pins(True, False, False)  # at rest: edges do not latch
    assert chip.read(Reg.X_LATCHED) == 0
    chip.write(Reg.REF_CONF_RAMP_MODE, RampMode.HOLD | 1 << 8)  # no stop on the left switch
    chip.write(Reg.V_ACTUAL, -10)
    chip.set_pins(False, False, False)
    assert chip.read(Reg.X_LATCHED) == 1234
    assert not chip.read(Reg.REF_CONF_RAMP_MODE) >> 16 & 1


def test_status_bits_follow_pins_inversion_and_mot1r() -> None:
    chip = TMC4210()
    chip.set_pins(True, True, True)
    assert status(chip) == IDLE_STATUS | 0x02 | 0x08 | 0x20  # R_L, GP_IN, R_R (mot1r = 0)
    chip.write(Reg.SMGP, MOT1R)
    assert status(chip) == IDLE_STATUS | 0x02 | 0x08  # REF_R now belongs to the axis
    assert chip.read(Reg.REFERENCE_SWITCHES) == 0b001011
    chip.write(Reg.IF_CONFIGURATION, 1)  # inv_ref
    assert status(chip) == IDLE_STATUS
    chip.write(Reg.X_TARGET, 5)
    assert status(chip) == IDLE_STATUS & ~1  # xEQt1 follows X_ACTUAL == X_TARGET


def test_switch_edge_interrupts_and_sdo_int() -> None:
    chip = TMC4210()
    chip.write(Reg.SMGP, MOT1R)
    chip.write(Reg.INTERRUPT, 0xF000)  # the four edge masks
    chip.set_pins(True, True, False)
    assert chip.read(Reg.INTERRUPT) & 0xFF == 1 << Irq.STOP_LEFT_HIGH | 1 << Irq.STOP_RIGHT_HIGH
    chip.set_pins(False, True, False)
    assert chip.read(Reg.INTERRUPT) & 1 << Irq.STOP_LEFT_LOW
    chip.write(Reg.IF_CONFIGURATION, 2)  # sdo_int: SDO carries nINT, reads are lost
    assert chip.spi(datagram(Reg.X_ACTUAL, read=True)) == 0
    chip.write(Reg.INTERRUPT, 0xF0FF)
    assert chip.spi(datagram(Reg.X_ACTUAL, read=True)) == 0xFFFF_FFFF


def test_power_down_freezes_motion_until_the_next_frame() -> None:
    chip = _configured(v_max=1000, a_max=1000, pulse_div=0, ramp_div=0)
    chip.write(Reg.X_TARGET, 100000)
    chip.run(1000)
    chip.write(Reg.POWER_DOWN, 0)
    frozen = chip.x_actual
    chip.run(50000)
    assert chip.x_actual == frozen
    chip.spi(datagram(Reg.X_ACTUAL, read=True))  # wakes it
    chip.run(60000)
    assert chip.x_actual > frozen


_frames = st.one_of(
    st.integers(0, 0xFFFF_FFFF),  # anything: writes, RAM, global registers, power-down, sdo_int
    st.builds(lambda idx, data: datagram(idx, data, read=True), st.integers(0, 0x0F),
              st.integers(0, MASK24)),  # axis register reads, the driver's fast path
    st.sampled_from([datagram(Reg.DATAGRAM_LOW, 1), datagram(Reg.POWER_DOWN, 0),
                     datagram(Reg.IF_CONFIGURATION, 2), datagram(Reg.IF_CONFIGURATION, EN_SD)]),
)


@settings(max_examples=80, deadline=None)
@given(frames=st.lists(st.tuples(_frames, st.integers(0, 300)), min_size=1, max_size=12),
       pins=st.tuples(st.booleans(), st.booleans(), st.booleans()))
def test_spi_data_answers_the_data_bits_of_spi_and_acts_the_same(
        frames: list[tuple[int, int]], pins: tuple[bool, bool, bool]) -> None:
    """The driver's reads (spi_data) skip the status byte: the same answer's data bits, and the
    same chip afterwards, for any frame (cdgw, power-down and sdo_int included)."""
    chip = _configured(v_max=900, a_max=30, pulse_div=0, ramp_div=2)
    chip.write(Reg.X_TARGET, 4000)
    chip.write(Reg.INTERRUPT, 0xFF00)
    chip.set_pins(*pins)
    twin = chip.clone()
    t = 0
    for frame, ticks in frames:
        t += ticks
        chip.run(t)
        twin.run(t)
        assert twin.spi_data(frame) == chip.spi(frame) & MASK24
        assert vars(twin) == vars(chip)


# == motion against the tick-by-tick reference =================================================


def _configured(*, v_max: int, a_max: int, pulse_div: int, ramp_div: int, v_min: int | None = None,
                mode: RampMode = RampMode.RAMP) -> TMC4210:
    chip = TMC4210()
    chip.write(Reg.IF_CONFIGURATION, EN_SD)
    configure(chip, v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=ramp_div, v_min=v_min,
              mode=mode)
    return chip


def _reference_for(chip: TMC4210) -> ReferenceChip:
    return ReferenceChip(v_min=chip.v_min, v_max=chip.v_max, a_max=chip.a_max, pmul=chip.pmul,
                         pdiv=chip.pdiv, pulse_div=chip.pulse_div, ramp_div=chip.ramp_div,
                         mode=chip.mode)


def _run_both(chip: TMC4210, ref: ReferenceChip, until: int, arrivals: list[int]) -> None:
    run_alongside(chip, ref, until, arrivals, f"at clk32 tick {until}")


change = st.one_of(
    st.tuples(st.just("x_target"), st.integers(-20000, 20000)),
    st.tuples(st.just("v_max"), st.integers(0, 2047)),
    st.tuples(st.just("v_min"), st.integers(0, 2047)),  # V_MIN > V_MAX too
    st.tuples(st.just("a_max"), st.integers(1, 2047)),
    st.tuples(st.just("v_target"), st.integers(-2047, 2047)),
    st.tuples(st.just("mode"), st.sampled_from([RampMode.RAMP, RampMode.SOFT, RampMode.VELOCITY])),
)


def _replay_changes(chip, ref, changes: list[tuple[int, tuple[str, int]]], conf: int = 0) -> None:
    """Apply each change to the engine and the reference after its gap of clocks, run both
    150,000 clocks past the last one, and compare the instants the target was reached.
    ``conf``: the REF_CONF bits kept when the ramp mode is written."""
    arrivals: list[int] = []
    t = 0
    for gap, (what, value) in changes:
        t += gap
        _run_both(chip, ref, t, arrivals)
        apply_change(chip, ref, what, value, conf)
    _run_both(chip, ref, t + 150_000, arrivals)
    assert arrivals == ref.arrivals


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(pulse_div=0, span=3, a_max=165, v_max=18, first_target=18,  # a reversal's zero crossing
         changes=[(8, ("mode", RampMode.VELOCITY)), (2242, ("v_target", -18))])
@example(pulse_div=0, span=1, a_max=2, v_max=3, first_target=1,  # V_TARGET after an arrival
         changes=[(1196, ("mode", RampMode.VELOCITY))])
@given(pulse_div=st.integers(0, 3), span=st.integers(-1, 4), a_max=st.integers(1, 2047),
       v_max=st.integers(1, 2047), first_target=st.integers(-20000, 20000),
       changes=st.lists(st.tuples(st.integers(1, 60000), change), max_size=4))
def test_engine_matches_the_tick_by_tick_reference(pulse_div: int, span: int, a_max: int,
                                                   v_max: int, first_target: int,
                                                   changes: list[tuple[int, tuple[str, int]]]) -> None:
    ramp_div = max(0, pulse_div + span)
    chip = _configured(v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=ramp_div)
    ref = _reference_for(chip)
    chip.write(Reg.X_TARGET, first_target & MASK24)
    ref.x_target = first_target & MASK24
    _replay_changes(chip, ref, changes)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(pulse_div=0, span=0, a_max=3, v_max=900, left=False, right=True, soft=True,
         tolerance=0, disable=0, first_target=-3000,  # reversed against a soft stop
         changes=[(3000, ("x_target", 20000)), (20000, ("x_target", -20000))])
@example(pulse_div=0, span=0, a_max=0, v_max=354, left=False, right=True, soft=False,
         tolerance=3, disable=0, first_target=-9843,  # overshoot, back towards a blocking switch
         changes=[(1, ("a_max", 210))])
@example(pulse_div=0, span=3, a_max=1, v_max=1000, left=False, right=False, soft=False,
         tolerance=0, disable=0, first_target=0,  # V_MIN above V_MAX: cruise to the target
         changes=[(8, ("v_min", 1001)), (8, ("x_target", 9000))])
@example(pulse_div=0, span=0, a_max=0, v_max=500, left=True, right=False, soft=False,
         tolerance=0, disable=0, first_target=0,  # no acceleration: nothing ever moves
         changes=[(10, ("mode", RampMode.VELOCITY)), (10, ("v_target", -500))])
@given(pulse_div=st.integers(0, 3), span=st.integers(-2, 4), a_max=st.integers(0, 40),
       v_max=st.integers(0, 2047), left=st.booleans(), right=st.booleans(), soft=st.booleans(),
       tolerance=st.sampled_from([0, 3, 300, 4095]), disable=st.integers(0, 3),
       first_target=st.integers(-20000, 20000),
       changes=st.lists(st.tuples(st.integers(1, 60000), change), max_size=4))
def test_engine_matches_the_reference_with_switches_and_slow_ramps(
        pulse_div: int, span: int, a_max: int, v_max: int, left: bool, right: bool, soft: bool,
        tolerance: int, disable: int, first_target: int,
        changes: list[tuple[int, tuple[str, int]]]) -> None:
    """Stop switches that stay active (ahead of the motor or behind it, hard or soft, inside
    or outside the tolerance window, disabled), small or no acceleration, moves reversed in
    flight: the closed forms agree with the tick-by-tick reference."""
    ramp_div = max(0, pulse_div + span)
    chip = _configured(v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=ramp_div)
    chip.write(Reg.SMGP, MOT1R)  # wire the right switch
    chip.write(Reg.DX_REF_TOLERANCE, tolerance)
    conf = soft << 10 | disable << 8
    chip.write(Reg.REF_CONF_RAMP_MODE, conf | chip.mode)
    chip.set_pins(left, right, False)
    ref = _reference_for(chip)
    ref.left, ref.right, ref.soft_stop, ref.tolerance = left, right, soft, tolerance
    ref.disable_left, ref.disable_right = bool(disable & 1), bool(disable & 2)
    chip.write(Reg.X_TARGET, first_target & MASK24)
    ref.x_target = first_target & MASK24
    _replay_changes(chip, ref, changes, conf)


def test_24_bit_wrap_goes_the_short_way() -> None:
    chip = _configured(v_max=2047, a_max=2047, pulse_div=0, ramp_div=0)
    chip.write(Reg.REF_CONF_RAMP_MODE, RampMode.VELOCITY)
    chip.write(Reg.X_ACTUAL, 8_388_000)
    chip.write(Reg.X_TARGET, 8_388_000)
    chip.write(Reg.REF_CONF_RAMP_MODE, RampMode.RAMP)
    chip.write(Reg.X_TARGET, -8_388_000 & MASK24)  # +1216 steps through the wrap
    while chip.run(chip.t + 1_000_000) is not Stop.ARRIVED:
        pass
    assert chip.x_actual == -8_388_000 & MASK24
    assert chip.motor_position == 1216


def test_hard_and_soft_switch_stops_and_the_tolerance_window() -> None:
    chip = _configured(v_max=1000, a_max=100, pulse_div=0, ramp_div=0, mode=RampMode.VELOCITY)
    chip.write(Reg.INTERRUPT, 1 << (8 + Irq.STOP))
    chip.write(Reg.V_TARGET, -500 & 0xFFF)
    chip.run(50_000)
    chip.set_pins(True, False, False)  # hard stop: at once
    assert chip.v == 0 and chip.read(Reg.INTERRUPT) & 1 << Irq.STOP
    chip.run(100_000)
    assert chip.v == 0  # the level keeps it stopped ...
    chip.write(Reg.V_TARGET, 500)
    chip.run(101_000)
    assert chip.v > 0  # ... in that direction only

    soft = _configured(v_max=1000, a_max=100, pulse_div=0, ramp_div=0, mode=RampMode.VELOCITY)
    soft.write(Reg.REF_CONF_RAMP_MODE, RampMode.VELOCITY | 1 << 10)
    soft.write(Reg.V_TARGET, -500 & 0xFFF)
    soft.run(50_000)
    v_before = soft.v
    soft.set_pins(True, False, False)
    soft.run(50_001)
    assert 0 > soft.v > v_before  # ramps down with A_MAX
    soft.run(60_000)
    assert soft.v == 0

    window = _configured(v_max=1000, a_max=100, pulse_div=0, ramp_div=0, mode=RampMode.VELOCITY)
    window.write(Reg.DX_REF_TOLERANCE, 4000)
    window.write(Reg.V_TARGET, -500 & 0xFFF)
    window.run(10_000)
    window.set_pins(True, False, False)
    assert window.v < 0  # |X_ACTUAL| < tolerance: no stop
    assert abs(signed(window.x_actual, 24)) < 4000


@pytest.mark.parametrize("target", [1, 77, 5000, 123_457])
def test_run_never_passes_its_end_tick(target: int) -> None:
    """Stopping one clk32 tick short of the arrival leaves the motor still moving."""
    chip = _configured(v_max=1678, a_max=220, pulse_div=3, ramp_div=8)
    chip.write(Reg.X_TARGET, target)
    while chip.run(chip.t + 10**9) is not Stop.ARRIVED:
        pass
    arrival = chip.t
    for end in range(arrival - 40, arrival):
        twin = _configured(v_max=1678, a_max=220, pulse_div=3, ramp_div=8)
        twin.write(Reg.X_TARGET, target)
        assert twin.run(end) is None or twin.t <= end
        assert twin.t == end and twin.v != 0


engine_states = st.fixed_dictionaries({
    "v_min": st.sampled_from([0, 1, 2, 30, 700, 2047]),
    "v_max": st.sampled_from([0, 1, 2, 3, 300, 2047]),
    "a_max": st.sampled_from([0, 1, 2, 3, 17, 400, 2047]),
    "pmul": st.integers(128, 255), "pdiv": st.integers(0, 13),
    "pulse_div": st.integers(0, 8), "ramp_div": st.integers(0, 7),
    "mode": st.sampled_from([RampMode.RAMP, RampMode.SOFT, RampMode.VELOCITY]),
    "x_actual": st.sampled_from([0, 5, -5, 2000, -2000]),
    "x_target": st.one_of(st.sampled_from([0, 5, 300, -300]), st.integers(-20000, 20000),
                          st.integers((1 << 23) - 40, (1 << 23) + 40)),
    "v": st.one_of(st.just(0), st.integers(-2047 * 256, 2047 * 256)),
    "v_target": st.integers(-2047, 2047),
    "tolerance": st.sampled_from([0, 3, 300]), "soft": st.booleans(),
    "disable": st.integers(0, 3), "left": st.booleans(), "right": st.booleans(),
})


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(state={"v_min": 61, "v_max": 2047, "a_max": 2, "pmul": 166, "pdiv": 2, "pulse_div": 3,
                "ramp_div": 0, "mode": RampMode.VELOCITY, "x_actual": 2000, "x_target": 0,
                "v": 510464, "v_target": 1020, "tolerance": 3, "soft": True, "disable": 0,
                "left": True, "right": True}, checkpoints=[60_000])  # a soft stop at the switch
@example(state={"v_min": 2, "v_max": 2, "a_max": 3, "pmul": 248, "pdiv": 2, "pulse_div": 8,
                "ramp_div": 0, "mode": RampMode.RAMP, "x_actual": -5, "x_target": -5,
                "v": 274497, "v_target": 0, "tolerance": 300, "soft": False, "disable": 3,
                "left": False, "right": False}, checkpoints=[60_000])  # at the target, too fast to stop there
@example(state={"v_min": 2, "v_max": 300, "a_max": 3, "pmul": 236, "pdiv": 4, "pulse_div": 6,
                "ramp_div": 0, "mode": RampMode.RAMP, "x_actual": 5, "x_target": (1 << 23) + 4,
                "v": -401664, "v_target": 0, "tolerance": 0, "soft": False, "disable": 0,
                "left": False, "right": False}, checkpoints=[60_000])  # away from a target 2**23 - 1 off
@given(state=engine_states, checkpoints=st.lists(st.integers(1, 60_000), min_size=1, max_size=3))
def test_engine_matches_the_reference_from_register_level_states(
        state: dict, checkpoints: list[int]) -> None:
    """Any speed (above V_MAX too), any dividers, curve and target (half the 24-bit range
    off too), switches held: the batched ramps (soft stops at a switch, flat stretches of
    the curve, braking at or away from the target) land where the reference does."""
    chip = TMC4210()
    chip.steps_out = True
    for name in ("v_min", "v_max", "a_max", "pmul", "pdiv", "pulse_div", "ramp_div", "mode",
                 "v", "v_target"):
        setattr(chip, name, state[name])
    chip.ramp_next = 1 << chip.ramp_div
    chip.x_actual = state["x_actual"] & MASK24
    chip.x_target = state["x_target"] & MASK24
    chip.dx_ref_tolerance = state["tolerance"]
    chip.ref_conf = state["soft"] << 10 | state["disable"] << 8
    chip.right_wired = True
    chip.ref_l, chip.ref_r = state["left"], state["right"]
    ref = ReferenceChip(v_min=chip.v_min, v_max=chip.v_max, a_max=chip.a_max, pmul=chip.pmul,
                        pdiv=chip.pdiv, pulse_div=chip.pulse_div, ramp_div=chip.ramp_div,
                        mode=chip.mode)
    ref.x_actual, ref.x_target, ref.v, ref.v_target = (chip.x_actual, chip.x_target, chip.v,
                                                       chip.v_target)
    ref.left, ref.right, ref.soft_stop, ref.tolerance = (state["left"], state["right"],
                                                         state["soft"], state["tolerance"])
    ref.disable_left, ref.disable_right = bool(state["disable"] & 1), bool(state["disable"] & 2)
    for until in sorted(checkpoints):
        while ref.t < until:
            ref.tick()
        while chip.t < until:
            chip.run(until)
        assert (chip.x_actual, chip.v, chip.v_target) == (ref.x_actual, ref.v, ref.v_target), (
        f"at clk32 tick {until}")


# == long moves, dividers, marks and switches mid-ramp (the batched braking) ===================


class _Strip:
    """A board for the engine and the reference alike: a left stop switch active at and below
    ``left``, a right one at and above ``right`` (None: none), and ``marks`` where nothing
    changes (as the firmware's deviation and rolling-target marks): the engine must stop its
    batches there and go on exactly as if it had not."""

    def __init__(self, left: int | None, right: int | None, marks: list[int]) -> None:
        self.left, self.right = left, right
        edges = [] if left is None else [left, left + 1]
        edges += [] if right is None else [right, right - 1]
        self.marks = sorted(set(marks + edges))

    def levels(self, position: int) -> tuple[bool, bool]:
        return (self.left is not None and position <= self.left,
                self.right is not None and position >= self.right)

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        return (*self.levels(motor_position), False)

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        ahead = [m for m in self.marks if (m - motor_position) * direction > 0]
        return min(ahead, key=lambda m: (m - motor_position) * direction) if ahead else None


#: Event ticks (ramp or pulse ticks) the reference runs per example: about a second.
_REFERENCE_EVENTS = 150_000


def _long_case(pulse_div: int, ramp_div: int, v_max: int, a_max: int, v_min: int | None,
               mode: RampMode, reach: float, changes: list[tuple[float, tuple[str, int]]],
               board: _Strip | None = None, pos_comp: int | None = None, soft: bool = False,
               checkpoints: int = 6) -> tuple[TMC4210, ReferenceChip]:
    """A move of ``reach`` times what V_MAX covers in the reference's time budget, with
    ``changes`` applied at fractions of that time, both models compared at checkpoints."""
    horizon = _REFERENCE_EVENTS << min(ramp_div, pulse_div)
    chip = TMC4210(board=board)
    chip.write(Reg.IF_CONFIGURATION, EN_SD)
    chip.write(Reg.SMGP, MOT1R)  # wire the right switch
    configure(chip, v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=ramp_div, v_min=v_min,
              mode=soft << 10 | mode)
    chip.write(Reg.INTERRUPT, 1 << (8 + Irq.REF_MISS))  # X_ACTUAL 0 is a position of interest
    if pos_comp is not None:
        chip.write(Reg.POS_COMP, pos_comp & MASK24)
        chip.write(Reg.POS_COMP_INT, 1 << 8)
    ref = _reference_for(chip)
    ref.soft_stop = soft
    if board is not None:
        ref.switches = board.levels
        ref.left, ref.right = board.levels(0)
    distance = round(reach * v_max * (horizon >> pulse_div) / 2048)
    chip.write(Reg.X_TARGET, distance & MASK24)
    ref.x_target = distance & MASK24
    stops = sorted({*(round(f * horizon) for f, _ in changes),
                    *(horizon * (i + 1) // checkpoints for i in range(checkpoints))})
    pending = sorted(changes, key=lambda change: change[0])
    arrivals: list[int] = []
    for until in stops:
        if until <= 0:
            continue
        while ref.t < until:
            ref.run_until(until)
        while chip.t < until:
            if chip.run(until) is Stop.ARRIVED:
                arrivals.append(chip.t)
        assert (chip.x_actual, chip.v, chip.motor_position, chip.v_target) == (
            ref.x_actual, ref.v, ref.position, ref.v_target), f"at clk32 tick {until}"
        while pending and round(pending[0][0] * horizon) <= until:
            _, (what, value) = pending.pop(0)
            if what == "x_target":
                chip.write(Reg.X_TARGET, value & MASK24)
                ref.x_target = value & MASK24
            else:
                chip.write(getattr(Reg, what.upper()), value)
                setattr(ref, what, value)
    assert arrivals == ref.arrivals
    return chip, ref


_long_change = st.tuples(st.floats(0.02, 0.95), st.one_of(
    st.tuples(st.just("x_target"), st.integers(-300_000, 300_000)),
    st.tuples(st.just("v_max"), st.integers(0, 2047)),
    st.tuples(st.just("v_min"), st.integers(0, 300)),
    st.tuples(st.just("a_max"), st.integers(0, 2047)),
))
_long = {
    "pulse_div": st.integers(0, 4), "span": st.integers(-4, 5), "v_max": st.integers(1, 2047),
    "a_max": st.one_of(st.integers(1, 2047), st.sampled_from([0, 1, 2, 3])),
    "v_min": st.one_of(st.none(), st.integers(0, 60)),
    "mode": st.sampled_from([RampMode.RAMP, RampMode.RAMP, RampMode.SOFT]),
    "reach": st.floats(-0.6, 0.6), "changes": st.lists(_long_change, max_size=3),
}


def _long_moves(pulse_div: int, span: int, v_max: int, a_max: int, v_min: int | None,
                mode: RampMode, reach: float, changes: list[tuple[float, tuple[str, int]]]) -> None:
    ramp_div = min(13, max(0, pulse_div + span))
    _long_case(pulse_div, ramp_div, v_max, a_max, v_min, mode, reach, changes)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(pulse_div=3, span=5, v_max=1678, a_max=220, v_min=None, mode=RampMode.RAMP, reach=0.45,
         changes=[])  # the manual's example move's registers, braking from V_MAX
@example(pulse_div=0, span=-4, v_max=2047, a_max=2047, v_min=None, mode=RampMode.RAMP,
         reach=-0.5, changes=[(0.3, ("x_target", 1000))])  # a pulse every 16 ramp ticks
@example(pulse_div=4, span=5, v_max=900, a_max=3, v_min=0, mode=RampMode.SOFT, reach=0.3,
         changes=[(0.5, ("v_min", 200))])  # slow acceleration, V_MIN raised mid-ramp
@example(pulse_div=2, span=3, v_max=2047, a_max=600, v_min=None, mode=RampMode.RAMP, reach=0.6,
         changes=[(0.4, ("a_max", 0)), (0.6, ("a_max", 600))])  # A_MAX 0 in flight
@given(**_long)
def test_long_moves_match_the_reference(pulse_div: int, span: int, v_max: int, a_max: int,
                                        v_min: int | None, mode: RampMode, reach: float,
                                        changes: list[tuple[float, tuple[str, int]]]) -> None:
    """Moves over tens of thousands of ramp ticks, with any dividers (a pulse every few ramp
    ticks, or many pulses per ramp tick), V_MIN, no acceleration, the target, V_MAX, V_MIN or
    A_MAX changed in flight: the batched braking lands on every step at the reference's tick."""
    _long_moves(pulse_div, span, v_max, a_max, v_min, mode, reach, changes)


@pytest.mark.soak
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_long)
def test_long_moves_match_the_reference_soak(pulse_div: int, span: int, v_max: int, a_max: int,
                                             v_min: int | None, mode: RampMode, reach: float,
                                             changes: list[tuple[float, tuple[str, int]]]) -> None:
    _long_moves(pulse_div, span, v_max, a_max, v_min, mode, reach, changes)


_marks = {
    "pulse_div": st.integers(0, 3), "span": st.integers(-2, 5), "v_max": st.integers(200, 2047),
    "a_max": st.integers(1, 2047), "reach": st.floats(-0.6, 0.6),
    "left": st.one_of(st.none(), st.integers(-150_000, 0)),
    "right": st.one_of(st.none(), st.integers(1, 150_000)),
    "marks": st.lists(st.integers(-150_000, 150_000), max_size=12),
    "soft": st.booleans(), "pos_comp": st.one_of(st.none(), st.integers(-150_000, 150_000)),
    "changes": st.lists(_long_change, max_size=2),
}


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(pulse_div=3, span=5, v_max=1678, a_max=220, reach=0.45, left=None, right=None,
         marks=[20_000, 40_000, 50_000, 52_000, 52_001, 53_000], soft=False, pos_comp=54_000,
         changes=[])  # marks all through the braking
@example(pulse_div=1, span=3, v_max=2000, a_max=300, reach=0.5, left=None, right=60_000,
         marks=[], soft=False, pos_comp=None, changes=[])  # a hard stop at a switch mid-ramp
@example(pulse_div=1, span=3, v_max=2000, a_max=300, reach=-0.5, left=-60_000, right=None,
         marks=[], soft=True, pos_comp=None, changes=[])  # a soft stop at a switch mid-ramp
@given(**_marks)
def test_marks_and_switches_mid_ramp_match_the_reference(
        pulse_div: int, span: int, v_max: int, a_max: int, reach: float, left: int | None,
        right: int | None, marks: list[int], soft: bool, pos_comp: int | None,
        changes: list[tuple[float, tuple[str, int]]]) -> None:
    """Positions that interrupt a batch (board marks, the position compare register, X_ACTUAL
    0 with REF_MISS armed) and stop switches that the motor reaches mid-ramp, hard or soft:
    the motion is the reference's, step for step."""
    ramp_div = min(13, max(0, pulse_div + span))
    _long_case(pulse_div, ramp_div, v_max, a_max, None, RampMode.RAMP, reach, changes,
               board=_Strip(left, right, marks), pos_comp=pos_comp, soft=soft)


def test_a_repeated_move_brakes_as_the_first_and_as_the_reference() -> None:
    """The engine remembers braking runs (a program repeats its moves): the second of two
    identical moves takes the remembered run, the first computes it; both are the
    reference's, and forgetting changes nothing."""
    fast_ramps._DESCENTS.clear()
    runs = [_long_case(3, 8, 1678, 220, None, RampMode.RAMP, 0.45, [])[0] for _ in range(2)]
    assert fast_ramps._DESCENTS, "the braking was remembered"
    fast_ramps._DESCENTS.clear()
    runs.append(_long_case(3, 8, 1678, 220, None, RampMode.RAMP, 0.45, [])[0])
    assert len({(c.t, c.x_actual, c.acc, c.v) for c in runs}) == 1


_braking_states = {
    "pulse_div": st.integers(0, 6), "span": st.integers(-4, 5),
    "a_max": st.one_of(st.integers(1, 2047), st.integers(1, 40)),
    "pmul": st.integers(128, 255), "pdiv": st.integers(0, 13),
    "v_min": st.one_of(st.integers(0, 40), st.integers(0, 2047)), "v_max": st.integers(1, 2047),
    "mode": st.sampled_from([RampMode.RAMP, RampMode.SOFT]),
    "distance": st.one_of(st.integers(1, 3000), st.integers(1, 600_000)),
    "acc": st.integers(0, 2047), "lag": st.floats(0, 1), "direction": st.sampled_from([1, -1]),
    "room": st.floats(0, 1), "max_ticks": st.integers(1, 2000),
}


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_braking_states)
def test_braking_batches_are_the_reference_ramp_ticks(
        pulse_div: int, span: int, a_max: int, pmul: int, pdiv: int, v_min: int, v_max: int,
        mode: RampMode, distance: int, acc: int, lag: float, direction: int, room: float,
        max_ticks: int) -> None:
    """The braking batch on its own (``MotorEngine._descend``), from any speed at or a little
    above the curve, any distance, accumulator and dividers, a position of interest anywhere
    up to the target and any tick budget: its ticks are the reference's, tick for tick, and
    none of them reaches the position of interest."""
    ramp_div = min(13, max(0, pulse_div + span))
    chip = TMC4210()
    for name, value in (("v_min", v_min), ("v_max", v_max), ("a_max", a_max), ("pmul", pmul),
                        ("pdiv", pdiv), ("pulse_div", pulse_div), ("ramp_div", ramp_div),
                        ("mode", mode), ("acc", acc)):
        setattr(chip, name, value)
    chip.x_target = distance * direction & MASK24
    curve = min(max(chip._curve(distance), v_min), v_max) << 8
    w = curve + int(lag * (a_max << 4)) - 1 if lag else curve
    if w < curve:
        w = curve
    # a speed the chip can hold: its velocity is 12-bit signed, |v| <= 2047 (a larger one
    # would need more than one pulse a clock, which neither the chip nor the reference gives)
    w = min(w, (2047 << 8) | 255)
    chip.ramp_next = 5 << ramp_div  # not at a multiple of a long pulse period
    chip.t = chip.ramp_next - 1
    chip.v = w * direction
    steps_to_interest = max(1, round(room * distance))
    plan = chip._pulse_plan(chip.ramp_next)
    fast_ramps._DESCENTS.clear()
    fast_ramps._CUT_DESCENTS.clear()
    down = chip._descend(w, distance, acc, steps_to_interest, max_ticks, plan)
    # remembered, whether it ended or was cut by max_ticks: the same again; a shorter cut is
    # not the remembered one, but what it computes afresh
    assert chip._descend(w, distance, acc, steps_to_interest, max_ticks, plan) == down
    if down is not None and down[0] >= fast_ramps.CUT_DESCENT_MIN_TICKS:
        assert fast_ramps._DESCENTS or fast_ramps._CUT_DESCENTS, "not remembered"
    if down is not None and down[0] > 1:
        shorter = chip._descend(w, distance, acc, steps_to_interest, down[0] - 1, plan)
        fast_ramps._DESCENTS.clear()
        fast_ramps._CUT_DESCENTS.clear()
        assert shorter == chip._descend(w, distance, acc, steps_to_interest, down[0] - 1, plan)
        assert shorter is not None and shorter[0] == down[0] - 1
    ref = _reference_for(chip)
    ref.x_target, ref.v, ref.acc, ref.t = chip.x_target, chip.v, acc, chip.t
    if down is None:  # not one tick: the first one reaches the position of interest
        ref.run_until(chip.ramp_next + (1 << ramp_div) - 1)
        assert abs(signed(ref.x_actual, 24)) >= steps_to_interest
        return
    ticks, w_after, acc_after, steps, a_step, mag, _ = down
    w_before = w_after - a_step
    assert 1 <= ticks <= max_ticks and steps < steps_to_interest
    ref.run_until(chip.ramp_next - 1 + ((ticks - 1) << ramp_div))
    v_before = ref.v
    ref.run_until(chip.ramp_next - 1 + (ticks << ramp_div))
    assert (ref.x_actual, ref.v, ref.acc, ref.v_target) == (
        steps * direction & MASK24, w_after * direction, acc_after, mag * direction)
    assert v_before == w_before * direction


@settings(max_examples=20, deadline=None)
@given(pulse_div=st.integers(0, 5), ramp_div=st.integers(0, 7), target=st.integers(-3000, 3000),
       ends=st.lists(st.integers(1, 20_000), min_size=1, max_size=4))
def test_the_references_idle_tick_skipping_is_its_tick_by_tick_run(
        pulse_div: int, ramp_div: int, target: int, ends: list[int]) -> None:
    """``ReferenceChip.run_until`` (which the long-move tests use) visits only ramp and pulse
    ticks: the same as calling ``tick`` for every clk32 tick."""
    refs = [ReferenceChip(v_min=5, v_max=900, a_max=300, pmul=200, pdiv=3, pulse_div=pulse_div,
                          ramp_div=ramp_div) for _ in range(2)]
    for ref in refs:
        ref.x_target = target & MASK24
    for end in sorted(ends):
        while refs[0].t < end:
            refs[0].tick()
        refs[1].run_until(end)
        assert [vars(r) for r in refs[:1]] == [vars(refs[1])]
