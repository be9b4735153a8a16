#!/usr/bin/env python3
"""The TMC4361A chip alone on the manual's loop program, beside the TMC4210 doing the same.

Six chips, each running MVP ABS ±512000 back and forth (the firmware manual's example
program, §2.4) for a simulated hour, each next move written at the arrival instant.  No
firmware layer: the host side is a handful of SPI datagrams per move, as a driver would send.
Both chips run in the same process, one after the other, so the figure that matters is the
ratio (the machine is shared and noisy).

Ramps (each chip in its own units, same physical motion):
  * ``trapezoid``: 51 200 pps, 51 200 pps² (axis 5 at twice both), as in the manual;
  * ``sixpoint``: TMC4361A SixPoint ramp (VSTART, VBREAK, ASTART, DFINAL, VSTOP), 200 000 pps;
  * ``sshape``: TMC4361A S-shaped ramp, 200 000 pps with bows.

    .venv/bin/python scripts/bench_tmc4361a.py [--hours H] [--profile NAME] [--repeat N]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from axes.chips.tmc42x.tmc4210 import EN_SD, MASK24, TMC4210, RampMode
from axes.chips.tmc42x.tmc4210 import Reg as Reg4210
from axes.chips.tmc42x.tmc4210 import datagram as datagram4210
from axes.chips.tmc42x.units import (
    choose_pulse_div,
    choose_ramp_div,
    pmul_pdiv,
    stop_speed,
)
from axes.chips.tmc42x.units import velocity_register as velocity_register_4210
from axes.chips.tmc4361a import (
    TMC4361A,
    Reg,
    acceleration_register,
    bow_register,
    velocity_register,
)
from axes.core import Stop

CLOCK_HZ = 16_000_000
AXES = 6
SPAN = 512_000


def setup_4361a(chip: TMC4361A, axis: int, profile: str) -> None:
    scale = 2 if axis == 5 else 1
    if profile == "trapezoid":
        chip.write(Reg.RAMPMODE, 0b101)
        chip.write(Reg.VMAX, velocity_register(51_200 * scale))
        chip.write(Reg.AMAX, acceleration_register(51_200 * scale))
        chip.write(Reg.DMAX, acceleration_register(51_200 * scale))
    elif profile == "sixpoint":
        chip.write(Reg.RAMPMODE, 0b101)
        chip.write(Reg.VMAX, velocity_register(200_000))
        chip.write(Reg.VSTART, velocity_register(500))
        chip.write(Reg.VSTOP, velocity_register(1_000))
        chip.write(Reg.VBREAK, velocity_register(50_000))
        chip.write(Reg.ASTART, acceleration_register(100_000))
        chip.write(Reg.AMAX, acceleration_register(60_000))
        chip.write(Reg.DMAX, acceleration_register(80_000))
        chip.write(Reg.DFINAL, acceleration_register(120_000))
    else:
        chip.write(Reg.RAMPMODE, 0b110)
        chip.write(Reg.VMAX, velocity_register(200_000))
        chip.write(Reg.AMAX, acceleration_register(100_000))
        chip.write(Reg.DMAX, acceleration_register(100_000))
        for reg in (Reg.BOW1, Reg.BOW2, Reg.BOW3, Reg.BOW4):
            chip.write(reg, bow_register(400_000))


def run_4361a(hours: float, profile: str) -> tuple[float, int]:
    chips = [TMC4361A(CLOCK_HZ) for _ in range(AXES)]
    for axis, chip in enumerate(chips):
        setup_4361a(chip, axis, profile)
    end = round(hours * 3600 * CLOCK_HZ)
    moves = 0
    start = time.perf_counter()
    for chip in chips:
        target = SPAN
        chip.write(Reg.XTARGET, target)
        while chip.t < end:
            if chip.run(end) is Stop.ARRIVED:
                target = -target
                chip.write(Reg.XTARGET, target & 0xFFFF_FFFF)
                moves += 1
    return time.perf_counter() - start, moves


def setup_4210(chip: TMC4210, axis: int) -> None:
    scale = 2 if axis == 5 else 1
    pps, pps2 = 51_200 * scale, 51_200 * scale
    pulse_div = choose_pulse_div(pps, CLOCK_HZ)
    ramp_div, a_max = choose_ramp_div(pps2, pulse_div, CLOCK_HZ)
    pmul, pdiv = pmul_pdiv(a_max, ramp_div, pulse_div) or (128, 0)
    chip.spi(datagram4210(Reg4210.IF_CONFIGURATION, EN_SD))
    v_max = velocity_register_4210(pps, pulse_div, CLOCK_HZ)
    chip.spi(datagram4210(Reg4210.V_MIN, stop_speed(a_max, pmul, pdiv, v_max, ramp_div,
                                                    pulse_div)))
    chip.spi(datagram4210(Reg4210.V_MAX, v_max))
    chip.spi(datagram4210(Reg4210.A_MAX, a_max))
    chip.spi(datagram4210(Reg4210.PMUL_PDIV, pmul << 8 | pdiv))
    chip.spi(datagram4210(Reg4210.DIVIDERS, pulse_div << 12 | ramp_div << 8))
    chip.spi(datagram4210(Reg4210.REF_CONF_RAMP_MODE, RampMode.RAMP))


def run_4210(hours: float) -> tuple[float, int]:
    chips = [TMC4210(CLOCK_HZ) for _ in range(AXES)]
    for axis, chip in enumerate(chips):
        setup_4210(chip, axis)
    end = round(hours * 3600 * CLOCK_HZ / 32)
    moves = 0
    start = time.perf_counter()
    for chip in chips:
        target = SPAN
        chip.spi(datagram4210(Reg4210.X_TARGET, target & MASK24))
        while chip.t < end:
            if chip.run(end) is Stop.ARRIVED:
                target = -target
                chip.spi(datagram4210(Reg4210.X_TARGET, target & MASK24))
                moves += 1
    return time.perf_counter() - start, moves


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=1.0)
    parser.add_argument("--profile", choices=("trapezoid", "sixpoint", "sshape"),
                        default="trapezoid")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    rows = []
    for _ in range(args.repeat):
        wall_4210, moves_4210 = run_4210(args.hours)
        wall_4361a, moves_4361a = run_4361a(args.hours, args.profile)
        rows.append((wall_4210, moves_4210, wall_4361a, moves_4361a))
    w10 = statistics.median(r[0] for r in rows)
    w61 = statistics.median(r[2] for r in rows)
    print(f"{args.hours:g} simulated hour(s), six chips, MVP ±{SPAN} loop, "
          f"TMC4361A profile {args.profile}")
    print(f"  TMC4210 : {w10:7.3f} s wall  ({rows[0][1]} moves)")
    print(f"  TMC4361A: {w61:7.3f} s wall  ({rows[0][3]} moves)")
    print(f"  ratio TMC4361A / TMC4210: {w61 / w10:.2f}")


if __name__ == "__main__":
    main()
