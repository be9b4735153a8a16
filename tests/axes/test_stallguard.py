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
    cool.update(p, 0, 51200, 900)
    assert cool.scale == 31
    cool.update(p, 5 * FULL_STEP + 100, 51200, 900)  # 5 readings: not yet
    assert cool.scale == 31
    cool.update(p, 8 * FULL_STEP, 51200, 900)  # 8 in all (the 100 units were kept)
    assert cool.scale == 30


def test_filtered_mode_measures_every_fourth_full_step():
    cool, p = CoolStep(), params(STALLGUARD_FILTER=1, SMARTENERGY_CURRENT_DOWN_STEP=3)
    cool.update(p, 0, 51200, 900)
    cool.update(p, -7 * FULL_STEP, 51200, 900)  # backwards counts the same: one measurement
    assert cool.scale == 30
    cool.update(p, -8 * FULL_STEP, 51200, 900)
    assert cool.scale == 29


def test_between_the_thresholds_nothing_changes_and_below_it_rises():
    cool, p = CoolStep(), params(SMARTENERGY_CURRENT_DOWN_STEP=3, SMARTENERGY_CURRENT_UP_STEP=2)
    cool.update(p, 0, 1000, 900)
    cool.update(p, 10 * FULL_STEP, 1000, 900)
    assert cool.scale == 21
    cool.update(p, 20 * FULL_STEP, 1000, 100)  # 64 <= 100 < 128: hold
    assert cool.scale == 21
    cool.update(p, 21 * FULL_STEP, 1000, 10)  # below 64: +4 per reading
    assert cool.scale == 25
    cool.update(p, 21 * FULL_STEP, 0, 10)  # at rest: not regulating, full current
    assert cool.scale is None
