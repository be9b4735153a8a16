#!/usr/bin/env python3
"""The TMC429 chip model against the TMC4210 in the same run: three motors on one TMC429
versus three TMC4210 chips, each motor looping MVP ±512000 at 51200 pps and 51200 pps²
(the manual's example program) for one simulated hour.

Each motor is driven the way a firmware layer drives an axis: look ahead on a clone to the
next notable instant (at most 4 simulated seconds ahead), adopt the clone, reverse the target
at each arrival.  The figure that matters is the ratio TMC429 / 3 x TMC4210 (the cost of the
shared chip: cloning three motors per lookahead instead of one).

    .venv/bin/python scripts/bench_tmc429.py [--hours H] [--repeat N]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from axes.chips.tmc42x.registers import MASK24, Reg, datagram
from axes.chips.tmc42x.tmc429 import TMC429, motor_address
from axes.chips.tmc42x.tmc4210 import EN_SD, TMC4210
from axes.chips.tmc42x.units import (
    choose_pulse_div,
    choose_ramp_div,
    pmul_pdiv,
    stop_speed,
    velocity_register,
)
from axes.core import Stop

SPEED = 51200
ACCELERATION = 51200
DISTANCE = 512_000
HORIZON_NS = 4_000_000_000
NS_PER_HOUR = 3600 * 1_000_000_000


def registers(clock_hz: int) -> dict[Reg, int]:
    """The axis registers a firmware layer writes for SPEED and ACCELERATION."""
    pulse_div = choose_pulse_div(SPEED, clock_hz)
    ramp_div, a_max = choose_ramp_div(ACCELERATION, pulse_div, clock_hz)
    pmul, pdiv = pmul_pdiv(a_max, ramp_div, pulse_div)
    v_max = velocity_register(SPEED, pulse_div, clock_hz)
    return {Reg.V_MIN: stop_speed(a_max, pmul, pdiv, v_max, ramp_div, pulse_div),
            Reg.V_MAX: v_max,
            Reg.A_MAX: a_max, Reg.PMUL_PDIV: pmul << 8 | pdiv,
            Reg.DIVIDERS: pulse_div << 12 | ramp_div << 8}


def loop(axis, address_of, hours: float) -> tuple[int, object]:
    """Drive one axis (a ChipModel with adopt) for ``hours``; returns (moves, final model)."""
    end = axis.ticks_at(round(hours * NS_PER_HOUR))
    target = DISTANCE
    axis.spi(datagram(address_of(Reg.X_TARGET), target & MASK24))
    moves = 0
    while axis.t < end:
        twin = axis.clone()
        horizon = min(end, twin.ticks_at(twin.ns_at(twin.t) + HORIZON_NS))
        stop = twin.run(horizon)
        axis = axis.adopt(twin)
        if stop is Stop.ARRIVED:
            moves += 1
            target = -target
            axis.spi(datagram(address_of(Reg.X_TARGET), target & MASK24))
    return moves, axis


def bench_tmc4210(hours: float) -> tuple[float, int]:
    """Three TMC4210 chips, one motor each."""
    chips = []
    for _ in range(3):
        chip = TMC4210()
        chip.write(Reg.IF_CONFIGURATION, EN_SD)
        for reg, value in registers(chip.clock_hz).items():
            chip.write(reg, value)
        chips.append(chip)
    start = time.perf_counter()
    moves = sum(loop(chip, lambda reg: reg, hours)[0] for chip in chips)
    return time.perf_counter() - start, moves


def bench_tmc429(hours: float) -> tuple[float, int]:
    """One TMC429, three motors, each driven through its own per-motor view."""
    chip = TMC429()
    chip.write(Reg.IF_CONFIGURATION, 1 << 5)  # en_sd: Step/Dir, as on the TMCL modules
    for index in range(3):
        for reg, value in registers(chip.clock_hz).items():
            chip.write(motor_address(index, reg), value)
    start = time.perf_counter()
    moves = 0
    for index in range(3):
        done, _ = loop(chip.motor(index), lambda reg, i=index: motor_address(i, reg), hours)
        moves += done
    return time.perf_counter() - start, moves


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    base, mine = [], []
    for _ in range(args.repeat):
        seconds, moves_4210 = bench_tmc4210(args.hours)
        base.append(seconds)
        seconds, moves_429 = bench_tmc429(args.hours)
        mine.append(seconds)
    if moves_429 != moves_4210:
        raise SystemExit(f"the chips disagree: {moves_429} moves on the TMC429, {moves_4210} on 3 x TMC4210")
    b, m = statistics.median(base), statistics.median(mine)
    print(f"3 motors x MVP +-{DISTANCE} at {SPEED} pps, {args.hours:g} simulated h, {moves_429} moves: "
          f"3 x TMC4210 {b * 1000:.1f} ms, TMC429 {m * 1000:.1f} ms, ratio {m / b:.2f} "
          f"(median of {args.repeat})")


if __name__ == "__main__":
    main()
