"""The stallGuard2 / coolStep arithmetic (axes/stallguard.py) on its own."""

from __future__ import annotations

from axes import stallguard
from axes.stallguard import FULL_STEP, CoolStep
from tmcl_spec.parameters import AP
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS


def params(**changes: int) -> dict[int, int]:
    values = {n: spec.default for n, spec in AXIS_PARAMETERS.items()}
    values.update({AP.MAX_CURRENT: 255, AP.SMARTENERGY_HYSTERESIS_START: 2,
                   AP.SMARTENERGY_HYSTERESIS: 1})  # thresholds 64 and (2+1+1)*32 = 128
    values.update({getattr(AP, name): value for name, value in changes.items()})
    return values


def test_reading_is_clamped_to_the_scale():
    assert stallguard.reading(500, 0) == 500
    assert stallguard.reading(500, 63) == 1023
    assert stallguard.reading(500, -64) == 0


def test_minimum_scale_is_half_or_a_quarter():
    assert stallguard.minimum_scale(31, quarter=False) == 15
    assert stallguard.minimum_scale(31, quarter=True) == 7
    assert stallguard.minimum_scale(0, quarter=True) == 0


def test_down_steps_count_readings_across_updates():
    cool, p = CoolStep(), params(SMARTENERGY_CURRENT_DOWN_STEP=1)  # one step per 8 readings
    cool.feed(p, 0, 900, True)
    assert cool.scale == 31
    cool.feed(p, 5 * FULL_STEP + 100, 900, True)  # 5 readings: not yet
    assert cool.scale == 31
    cool.feed(p, 8 * FULL_STEP, 900, True)  # 8 in all (the 100 units were kept)
    assert cool.scale == 30


def test_filtered_mode_measures_every_fourth_full_step():
    cool, p = CoolStep(), params(STALLGUARD_FILTER=1, SMARTENERGY_CURRENT_DOWN_STEP=3)
    cool.feed(p, 0, 900, True)
    cool.feed(p, -7 * FULL_STEP, 900, True)  # backwards counts the same: one measurement
    assert cool.scale == 30
    cool.feed(p, -8 * FULL_STEP, 900, True)
    assert cool.scale == 29


def test_between_the_thresholds_nothing_changes_and_below_it_rises():
    cool, p = CoolStep(), params(SMARTENERGY_CURRENT_DOWN_STEP=3, SMARTENERGY_CURRENT_UP_STEP=2)
    cool.feed(p, 0, 900, True)
    cool.feed(p, 10 * FULL_STEP, 900, True)
    assert cool.scale == 21
    cool.feed(p, 20 * FULL_STEP, 100, True)  # 64 <= 100 < 128: hold
    assert cool.scale == 21
    cool.feed(p, 21 * FULL_STEP, 10, True)  # below 64: +4 per reading
    assert cool.scale == 25
    cool.feed(p, 21 * FULL_STEP, 10, False)  # switched off: not regulating, full current
    assert cool.scale is None


def test_the_switch_follows_ap_182_and_ap_22_as_the_stepRocker_firmware_does():
    p = params(SMARTENERGY_THRESHOLD_SPEED=1000, COOLSTEP_THRESHOLD_SPEED=5000)
    assert not stallguard.switched_on(p, 999) and stallguard.switched_on(p, 1000)
    assert stallguard.switched_on(p, 4999) and not stallguard.switched_on(p, 5000)
    assert stallguard.switched_on(params(), 0)  # AP 182 = 0: on even at rest (SysControl.c 85)
    assert not stallguard.switched_on(params(SMARTENERGY_HYSTERESIS_START=0), 1000)
