"""TMC4210 unit conversions, as the TMC4210 datasheet gives them (its formulas for R, dR and p).

Step rate        R  = f_CLK * V / (2**PULSE_DIV * 2048 * 32)
Acceleration     dR = f_CLK**2 * A_MAX / 2**(PULSE_DIV + RAMP_DIV + 29)
Deceleration law p  = PMUL / 2**(3 + PDIV) ~= A_MAX / (128 * 2**(RAMP_DIV - PULSE_DIV)) * 0.99
"""

from __future__ import annotations

from math import isqrt

V_REGISTER_MAX = 2047
A_REGISTER_MAX = 2047
DIVIDER_MAX = 13
#: RAMP_DIV never exceeds PULSE_DIV by more than this: with one ramp tick spanning more pulse
#: ticks, the modelled braking curve can step past V_MIN and hunt around the target.
RAMP_SPAN_MAX = 5
#: p is reduced by this much below the ideal value to avoid a one-step overshoot (datasheet).
P_REDUCTION = 0.01


def step_rate(v: int, pulse_div: int, clock_hz: int) -> float:
    """Microsteps per second for velocity register value ``v``."""
    return clock_hz * v / (2**pulse_div * 65536)


def velocity_register(pps: float, pulse_div: int, clock_hz: int) -> int:
    """The nearest velocity register value for ``pps`` (magnitude), clamped to 0..2047."""
    return min(V_REGISTER_MAX, round(abs(pps) * 2**pulse_div * 65536 / clock_hz))


def acceleration_rate(a: int, pulse_div: int, ramp_div: int, clock_hz: int) -> float:
    """Microsteps per second squared for A_MAX value ``a``."""
    return clock_hz * clock_hz * a / 2 ** (pulse_div + ramp_div + 29)


def acceleration_register(pps2: float, pulse_div: int, ramp_div: int, clock_hz: int) -> int:
    return round(pps2 * 2 ** (pulse_div + ramp_div + 29) / (clock_hz * clock_hz))


def max_step_rate(pulse_div: int, clock_hz: int) -> float:
    return step_rate(V_REGISTER_MAX, pulse_div, clock_hz)


def choose_pulse_div(pps: float, clock_hz: int) -> int:
    """The largest PULSE_DIV whose range still covers ``pps``: V then lands in 1024..2047.

    Faster than the chip can step at PULSE_DIV 0 gives 0 (the caller clamps the speed).
    """
    for pulse_div in range(DIVIDER_MAX, -1, -1):
        if max_step_rate(pulse_div, clock_hz) >= abs(pps):
            return pulse_div
    return 0


def choose_ramp_div(pps2: float, pulse_div: int, clock_hz: int) -> tuple[int, int]:
    """(RAMP_DIV, A_MAX) for an acceleration: the finest A_MAX that fits 11 bits.

    When even RAMP_DIV 0 would need A_MAX > 2047, or the PULSE_DIV - RAMP_DIV >= 2 upper
    limit applies, A_MAX is clamped (the acceleration is then lower than asked); below the
    lower limit it is raised to it (higher than asked).  Both limits scale with RAMP_DIV like
    A_MAX itself, so no other RAMP_DIV would do better.
    """
    if pps2 <= 0:
        return pulse_div, 0
    for ramp_div in range(min(DIVIDER_MAX, pulse_div + RAMP_SPAN_MAX), -1, -1):
        a = acceleration_register(pps2, pulse_div, ramp_div, clock_hz)
        if a <= A_REGISTER_MAX:
            break
    a = max(1, a_max_lower_limit(pulse_div, ramp_div),
            min(a, A_REGISTER_MAX, a_max_upper_limit(pulse_div, ramp_div)))
    return ramp_div, a


def a_max_lower_limit(pulse_div: int, ramp_div: int) -> int:
    """Smallest A_MAX that positions without oscillating: 2**(RD - PD - 1) (datasheet §5.3).

    Below it the braking curve cannot bring the speed down to V_MIN before the target within
    one ramp tick, and the motor hunts around the target (the chip model reproduces that).
    """
    return 1 << (ramp_div - pulse_div - 1) if ramp_div - pulse_div >= 2 else 1


def a_max_upper_limit(pulse_div: int, ramp_div: int) -> int:
    """Largest A_MAX that positions without oscillating (datasheet §5.3)."""
    if pulse_div - ramp_div >= 2:
        return 2 ** (ramp_div - pulse_div + 12) - 1
    return A_REGISTER_MAX


def pmul_pdiv(a_max: int, ramp_div: int, pulse_div: int,
              reduction: float = P_REDUCTION) -> tuple[int, int] | None:
    """The datasheet's ``pmulpdiv.c``: the most precise (PMUL, PDIV), or None if none fits."""
    p_reduced = a_max / (128.0 * 2.0 ** (ramp_div - pulse_div)) * (1.0 - reduction)
    found = None
    for pdiv in range(DIVIDER_MAX + 1):
        pmul = int(p_reduced * 8.0 * 2.0**pdiv)
        if 128 <= pmul <= 255:
            found = (pmul, pdiv)
    return found


def last_step_speed(pmul: int, pdiv: int) -> int:
    """The ramp-mode target speed one microstep before the target: isqrt(2048 * p)."""
    return isqrt(((pmul | 0x80) << 8) >> pdiv)


def stop_speed(a_max: int, pmul: int, pdiv: int, v_max: int, ramp_div: int, pulse_div: int) -> int:
    """The smallest V_MIN from which ramp mode always stops on the target.

    The braking curve reaches the last microstep at ``last_step_speed``, and a ramp tick that
    spans many pulse ticks lets the motor arrive up to about A_MAX / 128 faster than the curve.
    Besides, the ramp generator sees that it must brake only at a ramp tick, up to one ramp
    period (V * 2**(RD - PD) / 2048 steps) after the curve fell below the speed V: that
    leaves p * 2**(RD - PD) * V more in V² than the curve, while braking at the chip's real
    rate (p_ideal = A_MAX / (128 * 2**(RD - PD))) instead of the curve's reduced p takes back
    r * V² (r = 1 - p / p_ideal, about the 1 % reduction).  What is left at the target,
    p k V - r V², is largest at V = p k / (2 r) (a short move that never reaches V_MAX), or at
    V_MAX if that is lower.  Below any of these the motor steps past the target and comes
    back (docs/motion.md, "V_MIN").
    """
    k = 2.0 ** (ramp_div - pulse_div)
    p = pmul / 2.0 ** (3 + pdiv)
    late = p * k  # extra V² per unit of speed from braking one ramp tick late
    r = 1.0 - p * 128.0 * k / a_max if a_max else 0.0
    speed = v_max if r <= 0 else min(v_max, late / (2.0 * r))
    surplus = max(0.0, late * speed - r * speed * speed)
    return max(1, last_step_speed(pmul, pdiv), a_max // 128 + 2, isqrt(int(surplus)) + 1)
