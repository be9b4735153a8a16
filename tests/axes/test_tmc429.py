"""The emulated TMC429: three motors on one chip, its global registers, switch layouts, interrupts.

Motion is checked as for the TMC4210 (the motor core is the same code): each of three motors
moving at once on one chip must land on the same positions and velocities, and arrive at the
same ticks, as its own tick-by-tick ``ReferenceChip``.  The driver chain and the TMC262 are
in ``test_tmc429_chain.py`` and ``test_tmc262.py``.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from axes.chips.tmc42x.registers import AXIS_REGISTERS, MASK24, Irq, RampMode, Reg, datagram, signed
from axes.chips.tmc42x.tmc429 import (
    EN_REFR,
    EN_SD,
    INV_REF,
    MOT1R,
    POR_CHAIN_WORDS,
    POR_SINE_TABLE,
    REFMUX,
    SDO_INT,
    TMC429,
    TYPE_VERSION,
    StaleTwin,
    TMC429Motor,
    motor_address,
)
from axes.chips.tmc42x.units import (
    choose_pulse_div,
    choose_ramp_div,
    velocity_register,
)
from axes.core import Stop
from tests.axes.reference_tmc4210 import ReferenceChip
from tests.helpers.tmc42x import apply_change, configure, run_alongside

IDLE_STATUS = 0x15  # no INT, no CDGW, no switch, all three motors at target


def status(chip: TMC429) -> int:
    return chip.spi(datagram(Reg.TYPE_VERSION, read=True)) >> 24


def step_dir_chip(**kwargs) -> TMC429:
    chip = TMC429(**kwargs)
    chip.write(Reg.IF_CONFIGURATION, EN_SD)
    return chip


# == register file =============================================================================


def test_power_on_values_and_idle_status() -> None:
    chip = TMC429()
    assert chip.spi(0x73000000) == IDLE_STATUS << 24 | TYPE_VERSION  # JDX %1001: $429101
    assert chip.read(Reg.SMGP) == 0x000F00  # CLK2_DIV = 15, LSMD = 0 (SPI mode, one driver)
    assert chip.read(Reg.IF_CONFIGURATION) == 0  # en_sd = 0: SPI driver chain
    for motor in range(3):
        for reg in AXIS_REGISTERS:
            expected = 0x8000 if reg == Reg.PMUL_PDIV else 0  # PMUL bit 15 reads 1
            assert chip.read(motor_address(motor, reg)) == expected, (motor, reg.name)
    # RAM: the driver-chain configuration and the sine table, two 6-bit words per address
    assert chip.read(0x40) == POR_CHAIN_WORDS[1] << 8 | POR_CHAIN_WORDS[0]
    assert chip.read(0x40 + 17) == POR_CHAIN_WORDS[35] << 8 | POR_CHAIN_WORDS[34]
    assert chip.read(0x60) == POR_SINE_TABLE[1] << 8 | POR_SINE_TABLE[0]
    assert POR_SINE_TABLE[:8] == (0, 2, 3, 5, 6, 8, 9, 11) and POR_SINE_TABLE[-5:] == (63,) * 5


def test_address_map_and_digest_examples() -> None:
    chip = TMC429()
    assert motor_address(1, Reg.X_ACTUAL) << 1 | 1 == 0x23  # motor 2 X_ACTUAL read, first byte
    assert Reg.SMGP << 1 == 0x7E
    assert chip.spi(0x1A000123) == IDLE_STATUS << 24  # a write answers status + 24 zero bits
    assert chip.spi(0x1B000000) == IDLE_STATUS << 24 | 0x000123  # motor 1 DX_REF_TOLERANCE
    assert chip.spi(0xFE002321) == IDLE_STATUS << 24  # RAM words 126 and 127
    assert chip.spi(0xFF000000) & MASK24 == 0x2321
    assert chip.ram[126:] == [0b100001, 0b100011]
    with pytest.raises(ValueError):
        motor_address(3, Reg.X_TARGET)


@pytest.mark.parametrize(("reg", "written", "read_back"), [
    (Reg.V_MAX, 0xFFF, 0x7FF),
    (Reg.V_TARGET, 0xFFFF9C, 0xF9C),
    (Reg.A_THRESHOLD, 0xFFFFFF, 0x7777FF),  # IS_AGTAT, IS_ALEAT, IS_V0, 11-bit threshold
    (Reg.PMUL_PDIV, 0x007A0F, 0xFA0F),
    (Reg.DIVIDERS, 0xFFFFFF, 0xFF07),
    (Reg.USTEP_COUNT, 0x1FF, 0xFF),  # R/W: writes set the sequencer pointer
    (Reg.DX_REF_TOLERANCE, 0xFFFFFF, 0xFFF),
])
@pytest.mark.parametrize("motor", [0, 1, 2])
def test_axis_register_widths(motor: int, reg: Reg, written: int, read_back: int) -> None:
    chip = TMC429()
    chip.write(motor_address(motor, reg), written)
    assert chip.read(motor_address(motor, reg)) == read_back


@pytest.mark.parametrize(("reg", "written", "read_back"), [
    (Reg.IF_CONFIGURATION, 0xFFFFFF, 0x1FF),
    (Reg.SMGP, 0xFFFFFF, 0x31FFFF),
    (Reg.POS_COMP, 0xFFFFFF, 0xFFFFFF),
    (Reg.COVER_DATAGRAM, 0xABCDEF, 0xABCDEF),
])
def test_global_register_widths(reg: Reg, written: int, read_back: int) -> None:
    chip = step_dir_chip()  # no chain: a cover datagram stays waiting
    chip.write(reg, written)
    assert chip.read(reg) == read_back


def test_read_only_and_unused_global_registers() -> None:
    chip = TMC429()
    for address in (Reg.TYPE_VERSION, Reg.REFERENCE_SWITCHES, 0x37, 0x3A, 0x3D):
        chip.write(address, 0x123456)
    assert chip.read(Reg.TYPE_VERSION) == TYPE_VERSION
    assert chip.read(Reg.REFERENCE_SWITCHES) == 0
    assert chip.read(0x37) == chip.read(0x3A) == 0


_axis_write = st.tuples(st.sampled_from(list(AXIS_REGISTERS)), st.integers(0, MASK24))


@settings(max_examples=60, deadline=None)
@given(motor=st.integers(0, 2), writes=st.lists(_axis_write, min_size=1, max_size=12))
def test_writes_to_one_motor_never_touch_another(motor: int, writes: list[tuple[Reg, int]]) -> None:
    chip = TMC429()
    for other in range(3):  # distinct contents everywhere first
        chip.write(motor_address(other, Reg.X_TARGET), 1000 + other)
        chip.write(motor_address(other, Reg.V_MAX), 10 + other)
    before = {(m, r): chip.read(motor_address(m, r)) for m in range(3) for r in AXIS_REGISTERS if m != motor}
    for reg, value in writes:
        chip.write(motor_address(motor, reg), value)
    after = {(m, r): chip.read(motor_address(m, r)) for m in range(3) for r in AXIS_REGISTERS if m != motor}
    assert after == before
    assert chip.motor(motor).writes == len(writes) + 2


def test_status_byte_layout() -> None:
    chip = TMC429()
    chip.write(motor_address(1, Reg.X_TARGET), 7)  # motor 2 not at target: xEQt2 (bit 2) clear
    assert status(chip) == IDLE_STATUS & ~0x04
    chip.motor(2).set_pins(True, False)  # motor 3's left switch: RS3 (bit 5)
    assert status(chip) == (IDLE_STATUS & ~0x04) | 0x20
    chip.write(Reg.IF_CONFIGURATION, INV_REF)  # every input inverted: RS1, RS2 active, RS3 not
    assert status(chip) == (IDLE_STATUS & ~0x04) | 0x02 | 0x08
    chip.write(motor_address(2, Reg.INTERRUPT), 1 << (8 + Irq.STOP_LEFT_LOW))
    chip.motor(2).set_pins(False, False)  # inverted: released -> active, a rising edge
    assert chip.read(motor_address(2, Reg.INTERRUPT)) == 0x1000  # only the mask
    chip.motor(2).set_pins(True, False)  # active -> inactive: stop_left_low
    assert chip.read(motor_address(2, Reg.INTERRUPT)) == 0x1000 | 1 << Irq.STOP_LEFT_LOW
    assert status(chip) >> 7 == 1  # INT: the OR over all motors' enabled flags
    assert not chip.nint


def test_sdo_int_leaves_the_answers_alone_on_the_qfn32() -> None:
    chip = TMC429()
    chip.write(Reg.IF_CONFIGURATION, SDO_INT)
    assert chip.spi(datagram(Reg.TYPE_VERSION, read=True)) == IDLE_STATUS << 24 | TYPE_VERSION
    assert chip.nint  # the separate nINT pin: high (inactive)


# == switches ==================================================================================


def _all_pressed(refmux: bool, mot1r: bool, en_refr: bool, en_sd: bool = False) -> TMC429:
    chip = TMC429()
    chip.write(Reg.IF_CONFIGURATION, (EN_REFR if en_refr else 0) | (EN_SD if en_sd else 0))
    chip.write(Reg.SMGP, (REFMUX if refmux else 0) | (MOT1R if mot1r else 0))
    for motor in chip.motors:
        motor.set_pins(True, True)
    return chip


@pytest.mark.parametrize(("refmux", "mot1r", "en_refr", "en_sd", "switches"), [
    (False, False, False, False, 0b10_10_10),  # left only (power-on layout)
    (False, True, False, False, 0b00_10_11),  # two-one-zero: REF3 is motor 1's right switch
    (False, False, True, False, 0b11_11_11),  # REFR1..3 enabled (QFN32)
    (True, False, False, False, 0b11_11_11),  # six switches through the 74HC157
    (True, True, False, False, 0b11_11_11),  # with refmux, mot1r is ignored
    (True, False, False, True, 0b10_10_10),  # refmux needs nSCS_S: not in Step/Dir mode
    (False, True, False, True, 0b00_10_11),  # mot1r works in Step/Dir mode too
])
def test_reference_switch_layouts(refmux: bool, mot1r: bool, en_refr: bool, en_sd: bool,
                                  switches: int) -> None:
    chip = _all_pressed(refmux, mot1r, en_refr, en_sd)
    assert chip.read(Reg.REFERENCE_SWITCHES) == switches
    rs = (switches >> 1 & 1) << 1 | (switches >> 3 & 1) << 3 | (switches >> 5 & 1) << 5
    assert status(chip) == IDLE_STATUS | rs


def test_a_right_switch_stops_only_where_the_layout_wires_it() -> None:
    for mot1r, stops in ((False, False), (True, True)):
        chip = step_dir_chip()
        chip.write(Reg.SMGP, MOT1R if mot1r else 0)
        motor = chip.motor(0)
        configure(motor, v_max=1000, a_max=100, pulse_div=0, ramp_div=0, mode=RampMode.VELOCITY)
        motor.write(Reg.V_TARGET, 500)
        motor.run(20_000)
        motor.set_pins(False, True)
        assert (motor.v == 0) == stops
        assert chip.motor(2).left_active is False  # REF3 is not motor 3's in either case


def test_inv_ref_on_one_write_acts_on_every_motor() -> None:
    chip = step_dir_chip()
    for motor in chip.motors:
        configure(motor, v_max=1000, a_max=100, pulse_div=0, ramp_div=0, mode=RampMode.VELOCITY)
        motor.write(Reg.V_TARGET, -500 & 0xFFF)
        motor.write(Reg.INTERRUPT, 1 << (8 + Irq.STOP))
    chip.advance(20_000)
    chip.write(Reg.IF_CONFIGURATION, EN_SD | INV_REF)  # open switches now read active
    assert [m.v for m in chip.motors] == [0, 0, 0]
    assert [m.int_flags for m in chip.motors] == [1 << Irq.STOP] * 3


def test_latch_on_motor_ones_right_switch_in_the_two_one_zero_layout() -> None:
    chip = step_dir_chip()
    chip.write(Reg.SMGP, MOT1R)
    motor = chip.motor(0)
    configure(motor, v_max=1000, a_max=100, pulse_div=0, ramp_div=0, mode=RampMode.VELOCITY)
    motor.write(Reg.REF_CONF_RAMP_MODE, RampMode.VELOCITY | 1 << 11 | 1 << 9)  # ref_RnL, no stop
    motor.write(Reg.X_LATCHED, 0)  # arm
    motor.write(Reg.V_TARGET, 500)
    motor.run(30_000)
    position = motor.x_actual
    chip.motor(2).set_pins(True, True)  # motor 3's switches: not wired in this layout
    assert motor.read(Reg.REF_CONF_RAMP_MODE) >> 16 & 1  # still armed
    motor.set_pins(False, True)  # motor 1's right switch (REF3)
    assert motor.read(Reg.X_LATCHED) == position and motor.v > 0
    assert not motor.read(Reg.REF_CONF_RAMP_MODE) >> 16 & 1


def test_time_conversions_are_the_chips() -> None:
    motor = TMC429(clock_hz=32_000_000).motor(2)
    assert motor.ticks_at(1_000_000_000) == 1_000_000  # clk32 at 32 MHz: 1 MHz
    assert motor.ns_at(3) == 3000


# == interrupts, position compare, power-down ==================================================


def test_interrupt_flags_are_per_motor_and_int_is_their_or() -> None:
    chip = step_dir_chip()
    for motor in chip.motors:
        configure(motor, v_max=1000, a_max=500, pulse_div=0, ramp_div=0)
        motor.write(Reg.INTERRUPT, 1 << (8 + Irq.POS_END))
    chip.motor(1).write(Reg.X_TARGET, 300)
    chip.advance(1_000_000)
    assert [m.read(Reg.INTERRUPT) & 0xFF for m in chip.motors] == [0, 1, 0]
    assert status(chip) >> 7 == 1
    chip.motor(1).write(Reg.INTERRUPT, 0x0101)  # write 1 to clear
    assert status(chip) == IDLE_STATUS


def test_position_compare_follows_the_selected_motor() -> None:
    chip = step_dir_chip()
    for motor in chip.motors:
        configure(motor, v_max=1000, a_max=500, pulse_div=0, ramp_div=0)
        motor.write(Reg.X_TARGET, 500)
    chip.write(Reg.POS_COMP, 250)
    chip.write(Reg.IF_CONFIGURATION, EN_SD | 2 << 6)  # pos_comp_sel = motor 3
    chip.write(Reg.POS_COMP_INT, 0x100)
    chip.motor(0).run(10**6)
    assert chip.read(Reg.POS_COMP_INT) == 0x100  # motor 1 passed 250: not selected
    chip.motor(2).run(10**6)
    assert chip.read(Reg.POS_COMP_INT) == 0x101
    assert status(chip) >> 7 == 1
    chip.write(Reg.POS_COMP_INT, 0x101)  # write 1 to clear
    assert chip.read(Reg.POS_COMP_INT) == 0x100
    chip.write(Reg.IF_CONFIGURATION, EN_SD | 3 << 6)  # %11: off
    chip.motor(1).run(10**6)
    assert chip.read(Reg.POS_COMP_INT) == 0x100


def test_power_down_freezes_every_motor_until_the_next_frame() -> None:
    chip = step_dir_chip()
    for motor in chip.motors:
        configure(motor, v_max=1000, a_max=1000, pulse_div=0, ramp_div=0)
        motor.write(Reg.X_TARGET, 100_000)
    chip.advance(1000)
    chip.write(Reg.POWER_DOWN, 0)
    frozen = [m.x_actual for m in chip.motors]
    chip.advance(50_000)
    assert [m.x_actual for m in chip.motors] == frozen
    status(chip)  # any frame wakes the chip
    chip.advance(60_000)
    assert all(m.x_actual > x for m, x in zip(chip.motors, frozen, strict=True))


# == Step/Dir and the chain: which motors' steps reach a motor =================================


def test_steps_reach_the_motors_in_the_chain_or_all_in_step_dir_mode() -> None:
    for if_config, smgp, moved in ((0, 0x000F00, [True, False, False]),
                                   (0, 0x000F02, [True, True, True]),
                                   (EN_SD, 0x000F00, [True, True, True])):
        chip = TMC429()
        chip.write(Reg.IF_CONFIGURATION, if_config)
        chip.write(Reg.SMGP, smgp)
        for motor in chip.motors:
            configure(motor, v_max=1000, a_max=500, pulse_div=0, ramp_div=0)
            motor.write(Reg.X_TARGET, 321)
        chip.advance(10**6)
        assert [m.x_actual for m in chip.motors] == [321] * 3
        assert [m.motor_position == 321 for m in chip.motors] == moved


# == one axis per motor: independence, clone and adopt =========================================


def test_motors_keep_their_own_time() -> None:
    chip = step_dir_chip()
    for motor in chip.motors:
        configure(motor, v_max=1000, a_max=500, pulse_div=0, ramp_div=0)
        motor.write(Reg.X_TARGET, 5000)
    assert chip.motor(0).run(10**7) is Stop.ARRIVED
    assert (chip.motor(1).t, chip.motor(1).x_actual) == (0, 0)
    assert chip.motor(1).run(10**7) is Stop.ARRIVED
    assert chip.motor(1).t == chip.motor(0).t  # same law, same arrival tick


def test_lookahead_clone_and_adopt() -> None:
    chip = step_dir_chip()
    for motor in chip.motors:
        configure(motor, v_max=1000, a_max=500, pulse_div=0, ramp_div=0)
        motor.write(Reg.X_TARGET, 5000)
    live = chip.motor(1)
    twin = live.clone()
    assert twin.run(10**7) is Stop.ARRIVED
    assert (live.t, live.x_actual, chip.motor(0).t) == (0, 0, 0)  # nothing moved in the chip
    chip.motor(0).write(Reg.X_TARGET, 7)  # another motor's registers: no matter
    driver_before = live.driver
    adopted = live.adopt(twin)
    assert adopted is live is chip.motor(1) and live.chip is chip and live.driver is driver_before
    assert live.t == twin.t
    assert chip.read(motor_address(1, Reg.X_ACTUAL)) == 5000
    assert status(chip) & 0x0C == 0x04  # RS2 clear, xEQt2 set, seen through the live chip

    stale = adopted.clone()
    chip.write(Reg.SMGP, MOT1R)  # a global write after the clone
    with pytest.raises(StaleTwin):
        adopted.adopt(stale)
    stale = adopted.clone()
    adopted.write(Reg.X_TARGET, 0)  # this motor's registers after the clone
    with pytest.raises(StaleTwin):
        adopted.adopt(stale)
    with pytest.raises(StaleTwin):
        chip.motor(0).adopt(adopted.clone())  # another motor's twin
    old = adopted.clone()
    adopted.run(adopted.t + 1000)
    with pytest.raises(StaleTwin):
        adopted.adopt(old)  # behind the live motor: adopting would go back in time


# == motion against the tick-by-tick reference, three motors at once ===========================


def _reference_for(motor: TMC429Motor) -> ReferenceChip:
    return ReferenceChip(v_min=motor.v_min, v_max=motor.v_max, a_max=motor.a_max, pmul=motor.pmul,
                         pdiv=motor.pdiv, pulse_div=motor.pulse_div, ramp_div=motor.ramp_div,
                         mode=motor.mode)


def _run_all(chip: TMC429, refs: list[ReferenceChip], until: int, order: list[int],
             arrivals: list[list[int]]) -> None:
    for index in order:
        run_alongside(chip.motor(index), refs[index], until, arrivals[index],
                      f"motor {index} at tick {until}")
    xeq = status(chip) & 0x15
    assert xeq == sum((r.x_actual == r.x_target) << 2 * i for i, r in enumerate(refs))


_motor_setup = st.tuples(st.integers(0, 3), st.integers(-1, 4), st.integers(1, 2047),
                         st.integers(1, 2047), st.integers(-20000, 20000))
_change = st.one_of(
    st.tuples(st.just("x_target"), st.integers(-20000, 20000)),
    st.tuples(st.just("v_max"), st.integers(0, 2047)),
    st.tuples(st.just("a_max"), st.integers(1, 2047)),
    st.tuples(st.just("v_target"), st.integers(-2047, 2047)),
    st.tuples(st.just("mode"), st.sampled_from([RampMode.RAMP, RampMode.SOFT, RampMode.VELOCITY])),
    st.tuples(st.just("global"), st.integers(0, MASK24)),  # SMGP / IF_CONFIGURATION noise
)


def _three_motor_case(setups: list[tuple[int, int, int, int, int]],
                      changes: list[tuple[int, int, tuple[str, int]]], order: list[int]) -> None:
    chip = TMC429()
    chip.write(Reg.SMGP, 2)  # LSMD = 2: every motor in the (SPI) chain
    refs = []
    for motor, (pulse_div, span, a_max, v_max, target) in zip(chip.motors, setups, strict=True):
        configure(motor, v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=max(0, pulse_div + span))
        ref = _reference_for(motor)
        motor.write(Reg.X_TARGET, target & MASK24)
        ref.x_target = target & MASK24
        refs.append(ref)
    arrivals: list[list[int]] = [[], [], []]
    t = 0
    for gap, index, (what, value) in changes:
        t += gap
        _run_all(chip, refs, t, order, arrivals)
        motor, ref = chip.motor(index), refs[index]
        if what == "global":  # global writes that must not disturb motion (no switches wired)
            chip.write(Reg.SMGP, value & 0x0FFFFF | 2)  # refmux/mot1r off, chain kept
            chip.write(Reg.IF_CONFIGURATION, value >> 8 & 0x1DE)  # not inv_ref, not en_sd
        else:
            apply_change(motor, ref, what, value)
    _run_all(chip, refs, t + 150_000, order, arrivals)
    assert arrivals == [ref.arrivals for ref in refs]
    assert [m.motor_position for m in chip.motors] == [signed(r.x_actual, 24) for r in refs]


_three = dict(setups=st.lists(_motor_setup, min_size=3, max_size=3),
              changes=st.lists(st.tuples(st.integers(1, 40000), st.integers(0, 2), _change), max_size=5),
              order=st.permutations([0, 1, 2]))


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_three)
def test_three_motors_match_the_tick_by_tick_reference(setups, changes, order) -> None:
    _three_motor_case(setups, changes, order)


@pytest.mark.soak
@pytest.mark.timeout(3600)
@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_three)
def test_three_motors_match_the_tick_by_tick_reference_soak(setups, changes, order) -> None:
    _three_motor_case(setups, changes, order)


# == random moves: exactly on target, never past it ============================================


class Fence:
    """A board that marks the first step past the target, or the first step away from it."""

    def __init__(self) -> None:
        self.target = 0

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        return False, False, False

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        if (self.target - motor_position) * direction > 0:
            return self.target + direction
        return motor_position + direction


#: (speed pps, acceleration pps²), the acceleration reaching the speed within 10 ms .. 100 s (far
#: outside, the firmware's clamped A_MAX makes ramps of 10**5 single ramp ticks: slow to compute).
_move_setup = st.integers(50, 400_000).flatmap(
    lambda speed: st.tuples(st.just(speed), st.integers(max(100, speed // 100), min(5_000_000, speed * 100))))


def _moves_case(setups: list[tuple[int, int]], targets: list[list[int]]) -> None:
    """Registers as the firmware layer derives them from a speed (pps) and acceleration (pps²)."""
    fences = [Fence(), Fence(), Fence()]
    chip = step_dir_chip(boards=fences)
    for motor, (speed, acceleration) in zip(chip.motors, setups, strict=True):
        pulse_div = choose_pulse_div(speed, chip.clock_hz)
        ramp_div, a_max = choose_ramp_div(acceleration, pulse_div, chip.clock_hz)
        v_max = max(1, velocity_register(speed, pulse_div, chip.clock_hz))
        configure(motor, v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=ramp_div)
    for index, motor in enumerate(chip.motors):
        for target in targets[index]:
            fences[index].target = target
            motor.write(Reg.X_TARGET, target & MASK24)
            while motor.x_actual != target & MASK24 or not motor.at_rest():
                stop = motor.run(motor.t + 10**9)
                assert stop is not Stop.MARK, f"motor {index}: past or away from {target}"
            assert motor.motor_position == target


_moves = dict(setups=st.lists(_move_setup, min_size=3, max_size=3),
              targets=st.lists(st.lists(st.integers(-300_000, 300_000), min_size=1, max_size=3),
                               min_size=3, max_size=3))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# 977 pps at 430 pps² overshot by one step before units.stop_speed covered late braking:
@example(setups=[(50, 100), (50, 100), (977, 430)], targets=[[0], [0], [1259]])
@given(**_moves)
def test_random_moves_land_on_target_without_overshoot(setups, targets) -> None:
    _moves_case(setups, targets)


@pytest.mark.soak
@pytest.mark.timeout(3600)
@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_moves)
def test_random_moves_land_on_target_without_overshoot_soak(setups, targets) -> None:
    _moves_case(setups, targets)


# == long moves: braking along the curve, three motors =========================================


_long_setup = st.tuples(st.integers(0, 4), st.integers(-3, 5), st.integers(200, 2047),
                        st.integers(1, 2047), st.floats(-0.5, 0.5))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(setups=[(4, 4, 1678, 880, 0.3), (3, 5, 2047, 600, -0.3), (0, -3, 2047, 2047, 0.2)],
         retarget=0.5)  # braking from V_MAX over hundreds of ramp ticks; a pulse every 8 ticks
@given(setups=st.lists(_long_setup, min_size=3, max_size=3), retarget=st.floats(0.1, 0.9))
def test_long_moves_of_three_motors_match_the_reference(setups, retarget: float) -> None:
    """Each motor of one TMC429 brakes from V_MAX along the curve over thousands of ramp
    ticks (the batched braking, remembered or not), one of them re-targeted in flight: every
    motor is the reference's at every checkpoint and arrives at its tick."""
    chip = step_dir_chip()
    refs, horizons = [], []
    for motor, (pulse_div, span, v_max, a_max, reach) in zip(chip.motors, setups, strict=True):
        ramp_div = min(13, max(0, pulse_div + span))
        configure(motor, v_max=v_max, a_max=a_max, pulse_div=pulse_div, ramp_div=ramp_div)
        ref = _reference_for(motor)
        horizon = 100_000 << min(pulse_div, ramp_div)
        target = round(reach * v_max * (horizon >> pulse_div) / 2048) & MASK24
        motor.write(Reg.X_TARGET, target)
        ref.x_target = target
        refs.append(ref)
        horizons.append(horizon)
    arrivals: list[list[int]] = [[], [], []]
    for step in range(1, 9):
        for index, (motor, ref) in enumerate(zip(chip.motors, refs, strict=True)):
            until = horizons[index] * step // 8
            ref.run_until(until)
            while motor.t < until:
                if motor.run(until) is Stop.ARRIVED:
                    arrivals[index].append(motor.t)
            assert (motor.x_actual, motor.v, motor.v_target) == (
                ref.x_actual, ref.v, ref.v_target), f"motor {index} at tick {until}"
            if index == 1 and step == max(1, round(retarget * 8)):
                target = (motor.x_target - 5000) & MASK24
                motor.write(Reg.X_TARGET, target)
                ref.x_target = target
    assert arrivals == [ref.arrivals for ref in refs]


def _chip_state(chip: TMC429) -> tuple[dict, list[dict]]:
    """Everything a frame can change: the chip's own state and each motor's."""
    top = {k: v for k, v in vars(chip).items() if k not in ("motors", "_origin_chip")}
    motors = [{k: v for k, v in vars(m).items() if k not in ("chip", "driver", "board")}
              for m in chip.motors]
    return top, motors


_any_frame = st.one_of(
    st.builds(lambda address, data: datagram(address, data, read=True), st.integers(0, 0x7F),
              st.integers(0, MASK24)),  # reads, the firmware's spi_data path
    st.builds(datagram, st.sampled_from([*range(0x30, 0x40), 0x0, 0x16, 0x2B, 0x45]),
              st.integers(0, MASK24)),  # global writes (the cover datagram, power-down, ...)
)


@settings(max_examples=80, deadline=None)
@given(frames=st.lists(st.tuples(_any_frame, st.integers(0, 300)), min_size=1, max_size=12),
       step_dir=st.booleans())
def test_spi_data_answers_the_data_bits_of_spi_and_acts_the_same(
        frames: list[tuple[int, int]], step_dir: bool) -> None:
    """The firmware's reads (spi_data) skip the status byte: the same answer's data bits and the
    same chip afterwards, for any frame (the cover datagram and its echo, power-down, RAM)."""
    chips = [step_dir_chip() if step_dir else TMC429() for _ in range(2)]
    for chip in chips:
        chip.write(Reg.SMGP, 2)
        for motor in chip.motors:
            configure(motor, v_max=900, a_max=30, pulse_div=0, ramp_div=2)
            motor.write(Reg.X_TARGET, 4000)
            motor.write(Reg.INTERRUPT, 0xFF00)
    t = 0
    for frame, ticks in frames:
        t += ticks
        for chip in chips:
            chip.advance(t)
        assert chips[1].motor(frame >> 29 & 1).spi_data(frame) == chips[0].spi(frame) & MASK24
        assert _chip_state(chips[1]) == _chip_state(chips[0])
