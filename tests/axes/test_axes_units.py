"""TMC4210 unit conversions against the worked numbers of the digest and the datasheet."""

from __future__ import annotations

import pytest

from axes.chips.tmc42x.units import (
    a_max_lower_limit,
    a_max_upper_limit,
    acceleration_rate,
    choose_pulse_div,
    choose_ramp_div,
    last_step_speed,
    max_step_rate,
    pmul_pdiv,
    step_rate,
    velocity_register,
)

F = 16_000_000


@pytest.mark.parametrize(("pulse_div", "hz_per_unit", "at_2047"), [
    (0, 244.140625, 499_755.9), (1, 122.0703, 249_877.9), (3, 30.5176, 62_469.5),
    (5, 7.6294, 15_617.4), (8, 0.9537, 1_952.2), (13, 0.0298, 61.0),
])
def test_velocity_table_at_16_mhz(pulse_div: int, hz_per_unit: float, at_2047: float) -> None:
    assert step_rate(1, pulse_div, F) == pytest.approx(hz_per_unit, rel=1e-4)
    assert max_step_rate(pulse_div, F) == pytest.approx(at_2047, abs=0.1)


@pytest.mark.parametrize(("divs", "per_unit"), [
    (0, 476_837.2), (2, 119_209.3), (6, 7_450.58), (10, 465.66), (16, 7.276), (26, 0.00711),
])
def test_acceleration_table_at_16_mhz(divs: int, per_unit: float) -> None:
    assert acceleration_rate(1, divs // 2, divs - divs // 2, F) == pytest.approx(per_unit, rel=1e-3)


def test_digest_example_ramp() -> None:
    """PD = RD = 3, V_MAX = 2047, A_MAX = 100: 62 469.5 pps, 745 058 pps², 83.8 ms, 2 618.9 steps."""
    rate = step_rate(2047, 3, F)
    accel = acceleration_rate(100, 3, 3, F)
    assert rate == pytest.approx(62_469.5, abs=0.1)
    assert accel == pytest.approx(745_058, abs=1)
    assert rate / accel == pytest.approx(0.0838, abs=1e-4)
    assert rate * rate / (2 * accel) == pytest.approx(2618.9, abs=0.1)


@pytest.mark.parametrize(("a_max", "ramp_div", "pulse_div", "pmul", "pdiv"), [
    (1000, 0, 0, 247, 2), (1000, 3, 3, 247, 2), (2047, 0, 0, 253, 1), (100, 3, 3, 198, 5),
    (10, 3, 3, 158, 8), (1, 0, 0, 253, 12), (50, 5, 3, 198, 8), (500, 7, 3, 247, 7),
    (1000, 4, 5, 247, 1),
])
def test_pmul_pdiv_pairs(a_max: int, ramp_div: int, pulse_div: int, pmul: int, pdiv: int) -> None:
    assert pmul_pdiv(a_max, ramp_div, pulse_div) == (pmul, pdiv)


def test_a_max_limits() -> None:
    assert a_max_upper_limit(5, 3) == 1023  # PD - RD = 2
    assert a_max_upper_limit(6, 3) == 511
    assert a_max_upper_limit(3, 3) == 2047
    assert a_max_lower_limit(3, 6) == 4  # 2**(RD - PD - 1)
    assert a_max_lower_limit(3, 4) == 1


def test_firmware_choices_for_the_manual_example() -> None:
    """SAP 4 = SAP 5 = 51200 (manual §2.4): PULSE_DIV 3, V 1678, RAMP_DIV 7, A_MAX 110."""
    pulse_div = choose_pulse_div(51200, F)
    assert pulse_div == 3
    assert velocity_register(51200, pulse_div, F) == 1678
    ramp_div, a_max = choose_ramp_div(51200, pulse_div, F)
    assert (ramp_div, a_max) == (8, 220)  # RAMP_DIV stays within PULSE_DIV + 5
    assert acceleration_rate(a_max, pulse_div, ramp_div, F) == pytest.approx(51200, rel=0.001)
    assert choose_pulse_div(10_000_000, F) == 0  # beyond the chip: the fastest range
    assert last_step_speed(247, 2) == isqrt_2048p(247 / 32)


def isqrt_2048p(p: float) -> int:
    return int((2048 * p) ** 0.5)
