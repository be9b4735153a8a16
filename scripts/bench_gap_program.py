#!/usr/bin/env python3
"""Benchmark a busy TMCL program that reads the position of moving axes.

Six axes are driven back and forth between -20000 and +20000 by target-reached interrupts
(SAP 4 200000, SAP 5 400000: they ramp most of the time), while the main loop reads the
position of two of them (GAP 1) every 70 us of simulated time.  A GAP brings the axis's chip
to the instruction's instant and reads X_ACTUAL over SPI, so on a real clock this is what
such a program costs.  Runs on the virtual clock and prints wall-clock seconds per simulated
second (below 1: the program keeps up with a real clock on one core).

    .venv/bin/python scripts/bench_gap_program.py [--seconds S] [--repeat N]

Numbers vary with the machine and its load: compare two versions side by side, interleaved.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from interpreter.assembler import assemble
from tmcl_server.clock import VirtualClock
from tmcl_server.module import TMCM6212
from tmcl_server.simulation import Simulation

AXES = range(6)
SETUP = "".join(f"    SAP 4, {a}, 200000\n    SAP 5, {a}, 400000\n    VECT {3 + a}, Target{a}\n"
                f"    EI {3 + a}\n" for a in AXES) + "    EI 255\n" + "".join(
    f"    MVP ABS, {a}, 20000\n" for a in AXES)
#: Seven instructions of 10 us: each of the two axes is read every 70 us.
MAIN_LOOP = "Loop:\n    GAP 1, 0\n    GAP 1, 1\n" + "    CALC ADD, 1\n" * 4 + "    JA Loop\n"
#: On arrival, off to the other end.
HANDLERS = "".join(f"Target{a}:\n    GAP 0, {a}\n    COMP 20000\n    JC EQ, Back{a}\n"
                   f"    MVP ABS, {a}, 20000\n    RETI\nBack{a}:\n    MVP ABS, {a}, -20000\n"
                   f"    RETI\n" for a in AXES)
PROGRAM = SETUP + MAIN_LOOP + HANDLERS


def wall_per_simulated_second(simulated_s: float) -> float:
    module = TMCM6212()
    simulation = Simulation([module], VirtualClock())
    module.program.interpreter.load(assemble(PROGRAM).instructions)
    module.program.interpreter.start(0)
    simulation.advance(0.01)  # past the setup
    t0 = time.perf_counter()
    simulation.advance(simulated_s)
    return (time.perf_counter() - t0) / simulated_s


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=3.0,
                        help="simulated seconds per run (default 3)")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    costs = [wall_per_simulated_second(args.seconds) for _ in range(args.repeat)]
    print(f"busy GAP 1 program (6 axes back and forth, GAP 1 on two every 70 us), virtual "
          f"clock: median {statistics.median(costs):.3f} s, best {min(costs):.3f} s of wall "
          f"time per simulated second")
    return 0


if __name__ == "__main__":
    sys.exit(main())
