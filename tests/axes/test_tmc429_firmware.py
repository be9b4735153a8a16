"""The TMC429 core: TMCL axes three to a TMC429, each with a TMC262 on the microcontroller's SPI.

The firmware layer (axes/firmware.py) over TMC429Driver and TMC262Link: axes built in groups,
register access per motor, motion in the chip's own units landing exactly on target, and the
current, microstep, stallGuard2 and coolStep parameters acting on the TMC262 model.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from axes.chips.tmc42x.registers import RampMode, Reg
from axes.chips.tmc42x.tmc429 import EN_REFR, EN_SD, SDO_INT, TYPE_VERSION, motor_address
from axes.chips.tmc42x.tmc429_firmware import TMC429Axis
from axes.chips.tmc42x.tmc4210_firmware import TMC4210Axis
from axes.chips.tmc42x.units import (
    a_max_lower_limit,
    a_max_upper_limit,
    acceleration_rate,
    pmul_pdiv,
    step_rate,
)
from axes.cores import make_axes
from axes.interface import AxisEventKind
from axes.world import AxisWorld, LoadZone, Switch
from tmcl_spec.numbers import NS_PER_S
from tmcl_spec.parameters import AP
from tmcl_spec.tmc429_modules import AXIS_PARAMETERS_1110, AXIS_PARAMETERS_3110, AXIS_PARAMETERS_6110
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS as TMCM6212_AXIS_PARAMETERS

MASK24 = 0xFFFFFF


def six_axes() -> list[TMC429Axis]:
    return make_axes("tmc429", 6, AXIS_PARAMETERS_6110)  # type: ignore[return-value]


def run(axes, seconds: float, start_ns: int = 0) -> list:
    """Advance every axis to ``start_ns + seconds``; the events on the way."""
    end = start_ns + int(seconds * NS_PER_S)
    return [event for axis in axes for event in axis.advance_to(end)]


def sentinel(target: int, start: int = 0) -> AxisWorld:
    """A world whose home switch is active one step beyond ``target`` (seen from ``start``):
    a motor that passes the target raises a home-switch event (256 µsteps: mechanics = steps)."""
    if target >= start:
        return AxisWorld(switches={"home": Switch.place(target + 1, side="above")})
    return AxisWorld(switches={"home": Switch.place(target - 1, side="below")})


# == axes in groups, set-up, register access ===================================================


def test_six_axes_sit_on_two_chips_three_motors_each_with_a_tmc262() -> None:
    axes = six_axes()
    chips = [axis.chip.chip for axis in axes]
    assert chips[0] is chips[1] is chips[2] and chips[3] is chips[4] is chips[5]
    assert chips[0] is not chips[3]
    assert [axis.chip.index for axis in axes] == [0, 1, 2, 0, 1, 2]
    assert all(axis.chip.driver is not None and axis.motor_driver is not None for axis in axes)
    single = make_axes("tmc429", 1, AXIS_PARAMETERS_1110)[0]
    assert [m.driver is not None for m in single.chip.chip.motors] == [True, False, False]


def test_power_up_runs_the_chip_in_step_dir_and_configures_the_tmc262() -> None:
    axis = make_axes("tmc429", 3, AXIS_PARAMETERS_3110)[1]
    assert axis.register_access(Reg.IF_CONFIGURATION) & MASK24 == EN_SD | EN_REFR | SDO_INT
    driver = axis.chip.driver
    assert driver.mres == 0 and driver.microsteps == 256  # AP 140 = 8
    assert driver.cs == 255 >> 3  # AP 6, the stepRocker firmware's scale
    assert driver.toff == 5 and driver.vsense and not driver.sdoff  # bridges on, Step/Dir
    assert axis.chip.read(Reg.V_MIN) >= 1  # AP 130 = 1, raised as the chip needs
    assert axis.chip.read(Reg.DIVIDERS) >> 8 == 2 << 4 | 3  # AP 154 = 2, AP 153 = 3


def test_register_access_reads_the_type_version_and_writes_one_motor_only() -> None:
    axes = six_axes()
    assert axes[4].register_access(Reg.TYPE_VERSION) & MASK24 == TYPE_VERSION
    before = [[a.chip.read(reg) for reg in (Reg.V_MAX, Reg.X_TARGET)] for a in axes[:3]]
    axes[1].register_access(Reg.V_MAX, 1234)  # IDX 3: axis 1's own motor (SMDA 1)
    axes[1].register_access(Reg.X_TARGET, 777)
    after = [[a.chip.read(reg) for reg in (Reg.V_MAX, Reg.X_TARGET)] for a in axes[:3]]
    assert after[1] == [1234, 777]
    assert after[0] == before[0] and after[2] == before[2]
    assert axes[3].chip.read(Reg.V_MAX) == axes[0].chip.read(Reg.V_MAX)  # other chip
    # 0x10..0x2F pass to the chip as they are: axis 0 reads motor 1's register
    assert axes[0].register_access(motor_address(1, Reg.X_TARGET)) & MASK24 == 777


# == motion ====================================================================================


def test_moves_on_every_axis_land_while_the_other_motors_of_the_chip_are_commanded() -> None:
    axes = six_axes()
    targets = [40_000, -25_000, 300, -7, 123_456, 0]
    for axis, target in zip(axes, targets, strict=True):
        axis.set_world(sentinel(target))
    for step, (axis, target) in enumerate(zip(axes, targets, strict=True)):
        axis.advance_to(step * 10_000_000)
        axis.move_to(target)  # writes to one motor while its neighbours move
    events = run(axes, 10.0)
    assert [axis.get_parameter(AP.ACTUAL_POSITION) for axis in axes] == targets
    assert all(axis.get_parameter(AP.POSITION_REACHED) for axis in axes)
    assert not [e for e in events if e.kind is AxisEventKind.HOME_SWITCH]  # nobody passed
    assert len([e for e in events if e.kind is AxisEventKind.TARGET_REACHED]) == 6


def test_speeds_are_register_values_with_the_divisors_of_ap_153_and_154() -> None:
    axis = make_axes("tmc429", 3, AXIS_PARAMETERS_3110)[0]
    axis.set_parameter(AP.PULSE_DIVISOR, 4)
    axis.set_parameter(AP.RAMP_DIVISOR, 6)
    axis.rotate(1500)
    run([axis], 0.001)
    assert 0 < axis.get_parameter(AP.ACTUAL_ACCELERATION) <= 500  # ramping up (AP 5 = 500)
    assert axis.get_parameter(AP.RAMP_MODE) == RampMode.VELOCITY
    run([axis], 1.0)
    assert axis.get_parameter(AP.ACTUAL_SPEED) == 1500
    assert axis.chip.read(Reg.DIVIDERS) >> 8 == 4 << 4 | 6
    steps = axis.get_parameter(AP.ACTUAL_POSITION)
    run([axis], 3.0)
    travelled = axis.get_parameter(AP.ACTUAL_POSITION) - steps
    assert travelled == pytest.approx(2 * step_rate(1500, 4, 16_000_000), rel=1e-3)
    axis.set_parameter(AP.RAMP_MODE, 1)  # soft positioning for the next move
    axis.move_to(0)
    assert axis.get_parameter(AP.RAMP_MODE) == RampMode.SOFT
    run([axis], 30.0)
    assert axis.get_parameter(AP.ACTUAL_POSITION) == 0


@st.composite
def register_settings(draw) -> tuple[int, int, int, int]:
    """(AP 154, AP 153, AP 4, AP 5) a TMC429 positions with (the datasheet's §5.3 limits and a
    PMUL/PDIV pair), with ramps of at most a few thousand ramp ticks and moves of minutes."""
    pulse_div = draw(st.integers(0, 7))
    ramp_div = draw(st.integers(max(0, pulse_div - 1), min(13, pulse_div + 5)))
    v_max = draw(st.integers(50, 2047))
    low = max(1, a_max_lower_limit(pulse_div, ramp_div), v_max // 8)
    high = min(2047, a_max_upper_limit(pulse_div, ramp_div))
    assume(low <= high)
    a_max = draw(st.integers(low, high))
    assume(pmul_pdiv(a_max, ramp_div, pulse_div) is not None)
    return pulse_div, ramp_div, v_max, a_max


_random_moves = dict(setting=register_settings(),
                     targets=st.lists(st.integers(-20_000, 20_000), min_size=1, max_size=3))


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_random_moves)
def test_random_moves_land_on_target_without_overshoot(setting, targets) -> None:
    _random_moves_case(setting, targets)


@pytest.mark.soak
@pytest.mark.timeout(3600)
@settings(max_examples=1000, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(**_random_moves)
def test_random_moves_land_on_target_without_overshoot_soak(setting, targets) -> None:
    _random_moves_case(setting, targets)


def _random_moves_case(setting: tuple[int, int, int, int], targets: list[int]) -> None:
    """AP 154/153/4/5 as drawn, then moves to ``targets``: each lands, none passes it."""
    pulse_div, ramp_div, v_max, a_max = setting
    axis = make_axes("tmc429", 1, AXIS_PARAMETERS_1110)[0]
    for number, value in ((AP.PULSE_DIVISOR, pulse_div), (AP.RAMP_DIVISOR, ramp_div),
                          (AP.MAX_SPEED, v_max), (AP.MAX_ACCELERATION, a_max)):
        axis.set_parameter(number, value)
    now = 0
    for target in targets:
        start = axis.get_parameter(AP.ACTUAL_POSITION)
        axis.set_world(sentinel(target, start))
        axis.move_to(target)
        speed = step_rate(v_max, pulse_div, 16_000_000)
        seconds = 10 + abs(target - start) / speed + 2 * speed / acceleration_rate(
            a_max, pulse_div, ramp_div, 16_000_000)
        events = axis.advance_to(now := now + int(seconds * NS_PER_S))
        assert axis.get_parameter(AP.ACTUAL_POSITION) == target
        assert not [e for e in events if e.kind is AxisEventKind.HOME_SWITCH], "passed the target"


def test_the_tmc4210_core_no_longer_overshoots_where_v_min_missed_late_braking() -> None:
    """977 pps at 430 pps²: PULSE_DIV 8, RAMP_DIV 13, A_MAX 1891 (docs/motion.md, V_MIN)."""
    axis = TMC4210Axis(0, TMCM6212_AXIS_PARAMETERS)
    axis.set_parameter(AP.MAX_SPEED, 977)
    axis.set_parameter(AP.MAX_ACCELERATION, 430)
    for target in (1259, 1290, 2000, 0):
        start = axis.get_parameter(AP.ACTUAL_POSITION)
        axis.set_world(sentinel(target, start))
        axis.move_to(target)
        events = axis.advance_to(axis._now_ns + 20 * NS_PER_S)
        assert axis.get_parameter(AP.ACTUAL_POSITION) == target
        assert not [e for e in events if e.kind is AxisEventKind.HOME_SWITCH], target


@pytest.mark.parametrize(("core", "table"), [("tmc429", TMCM6212_AXIS_PARAMETERS),
                                              ("tmc4210", AXIS_PARAMETERS_6110)])
def test_a_table_runs_on_the_other_core(core, table) -> None:
    """--axis-core: the TMCM-6212's pps units on TMC429 axes, register units on TMC4210 axes."""
    axes = make_axes(core, 3, table)
    for axis, target in zip(axes, (5000, -3000, 51_200), strict=True):
        axis.move_to(target)
    run(axes, 5.0)
    assert [axis.get_parameter(AP.ACTUAL_POSITION) for axis in axes] == [5000, -3000, 51_200]
    axes[0].rotate(1000)
    run(axes, 1.0, 5 * NS_PER_S)
    assert axes[0].get_parameter(AP.ACTUAL_SPEED) == pytest.approx(1000, abs=20)


# == the TMC262: current, microsteps, stallGuard2, coolStep ====================================


def test_run_and_standby_current_set_the_tmc262_current_scale() -> None:
    axis = make_axes("tmc429", 1, AXIS_PARAMETERS_1110)[0]
    axis.set_parameter(AP.MAX_CURRENT, 200)
    axis.set_parameter(AP.STANDBY_CURRENT, 40)
    axis.set_parameter(AP.POWER_DOWN_DELAY, 50)  # 0.5 s
    assert axis.chip.driver.cs == 200 >> 3
    run([axis], 1.0)
    assert axis.chip.driver.cs == 40 >> 3 and axis.current == 40
    axis.rotate(300)
    assert axis.chip.driver.cs == 40 >> 3  # until the firmware's next pass sees it move
    run([axis], 1.011)
    assert axis.chip.driver.cs == 200 >> 3


def test_microstep_resolution_is_the_tmc262s_and_the_mechanics_follow() -> None:
    axis = make_axes("tmc429", 1, AXIS_PARAMETERS_1110)[0]
    axis.set_parameter(AP.MICROSTEPS, 4)  # 16 microsteps
    assert axis.chip.driver.microsteps == 16
    axis.move_to(160)  # ten full steps
    run([axis], 2.0)
    assert axis.status().mechanical_position == 160 * 16  # 1/256 microsteps of the world
    assert axis.chip.driver.mscnt == 160 * 16


def test_stallguard2_is_read_from_the_tmc262_and_stops_the_motor_on_stall() -> None:
    axis = make_axes("tmc429", 1, AXIS_PARAMETERS_1110)[0]
    axis.set_world(AxisWorld(free_load=700, load_zones=[LoadZone(20_000, 30_000, 0)]))
    assert axis.get_parameter(AP.LOAD) == 0  # nothing measured yet
    axis.set_parameter(AP.STALLGUARD_THRESHOLD, -5)
    assert axis.chip.driver.sgt == -5
    axis.move_to(10_000)
    run([axis], 2.0)
    assert axis.get_parameter(AP.LOAD) == 700 - 5 * 16  # the TMC262's SG, measured at full steps
    axis.set_parameter(AP.STOP_ON_STALL, 100)
    axis.move_to(40_000)
    events = run([axis], 5.0, 2 * NS_PER_S)
    assert [e.kind for e in events if e.kind is AxisEventKind.STALL] == [AxisEventKind.STALL]
    position = axis.get_parameter(AP.ACTUAL_POSITION)
    assert 20_000 <= position < 20_000 + 2 * 256  # within the zone's first full steps
    assert axis.get_parameter(AP.ERROR_FLAGS) == 1
    assert axis.get_parameter(AP.LOAD) == 0 and axis.get_parameter(AP.DRIVER_ERROR_FLAGS) & 1


def test_coolstep_lowers_the_tmc262_current_at_light_load_above_the_threshold_speed() -> None:
    axis = make_axes("tmc429", 1, AXIS_PARAMETERS_1110)[0]
    axis.set_world(AxisWorld(free_load=1000))
    for number, value in ((AP.SMARTENERGY_HYSTERESIS_START, 2), (AP.SMARTENERGY_HYSTERESIS, 1),
                          (AP.SMARTENERGY_CURRENT_DOWN_STEP, 3), (AP.SMARTENERGY_THRESHOLD_SPEED, 800),
                          (AP.SMARTENERGY_SLOW_RUN_CURRENT, 160)):
        axis.set_parameter(number, value)
    axis.rotate(500)  # below AP 182: coolStep off, the slow-run current (AP 183)
    run([axis], 1.0)
    assert axis.get_parameter(AP.SMARTENERGY_ACTUAL_CURRENT) == 160 >> 3
    assert axis.chip.driver.semin == 0 and axis.current == 160
    axis.rotate(1000)
    run([axis], 1.0, NS_PER_S)
    assert axis.get_parameter(AP.ACTUAL_SPEED) == 1000  # the firmware looks: AP 182 passed
    assert axis.chip.driver.semin == 2
    run([axis], 1.0, 2 * NS_PER_S)
    assert axis.get_parameter(AP.SMARTENERGY_ACTUAL_CURRENT) == 15  # half of CS 31: (31+1)/2-1
    assert axis.current == 255 * 16 // 32
    axis.set_parameter(AP.SMARTENERGY_THRESHOLD_SPEED, 1500)  # now below it: off again
    run([axis], 0.011, 3 * NS_PER_S)  # at the firmware's next pass
    assert axis.get_parameter(AP.SMARTENERGY_ACTUAL_CURRENT) == 160 >> 3
    assert axis.chip.driver.semin == 0


def test_a_move_across_the_24_bit_wrap_takes_the_shorter_way() -> None:
    """The TMC429 modules' positions are the chip's 24-bit registers (docs/modules.md, "AP 0 /
    AP 1"): 2000 steps forward across the wrap, not 16.7 million back."""
    axis = six_axes()[4]
    axis.set_parameter(AP.ACTUAL_POSITION, 2**23 - 1000)
    axis.move_to(-(2**23) + 1000)
    events = run([axis], 30)
    assert AxisEventKind.TARGET_REACHED in [event.kind for event in events]
    assert (axis.get_parameter(AP.ACTUAL_POSITION), axis.chip.motor_position) == (-(2**23) + 1000, 2000)
