#!/usr/bin/env python3
"""Simulated seconds per wall second: six axes in continuous motion on the virtual clock.

Goal (issue 3): one simulated hour in under 2 s of wall time; issue 12: the TMC4361A core
(``--axis-core tmc4361a``) no slower than the TMC4210 core, both measured in the same run.

Two workloads, every axis always moving, the virtual clock jumping from event to event, and
each next move issued at the target-reached instant (as WAIT POS would):

* ``program`` (the goal's workload): axes 0-3 and 5 run the manual's example program (§2.4:
  MVP ABS ±512000 at 51200 pps and 51200 pps²; axis 5 at twice the speed); axis 4 rotates
  at 80 000 pps and reverses every 7 s.
* ``hops`` (stress): the same, but axis 5 makes 20 000-step hops at 200 000 pps and
  1 000 000 pps², so ramps dominate.  Braking follows the chip's distance law one ramp tick
  at a time (it has no closed form), so time goes with the number of ramp ticks.
* ``sramp`` (TMC4361A only): the ``program`` workload with S-shaped ramps, chosen through
  command 146 (RAMPMODE profile 2, BOW1..4 = 400 000 pps³) on every axis, AP 20 = 0; the
  moving axes at 200 000 pps and 100 000 pps².  S-ramps go through the firmware's look-ahead
  (a clone run with a work budget), so this shows what they cost there.

Each workload runs on every chip core (``--cores``, default tmc4210 and tmc4361a).

    .venv/bin/python scripts/bench_motion.py [--hours H] [--repeat N] [--cores LIST]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tmcl_server.clock import VirtualClock
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode

NS = 1_000_000_000
REVERSE_EVERY_NS = 7 * NS


def command(module: TMCLModule, opcode: int, type_: int, motor: int, value: int) -> None:
    module.execute(Request(1, opcode, type_, motor, value))


def run(hours: float, workload: str = "program", core: str = "tmc4210") -> tuple[float, int, int]:
    """Returns (wall seconds, moves completed, events handled)."""
    module = TMCLModule(kind="tmcm-6212", chip_core=core)
    simulation = Simulation([module], VirtualClock())
    arrived: list[int] = []
    events = 0

    def on_event(event: ModuleEvent) -> None:
        nonlocal events
        events += 1
        if event.kind == "target_reached":
            arrived.append(event.axis)

    module.listeners.append(on_event)
    targets = {axis: 512_000 for axis in (0, 1, 2, 3, 5)}
    # AP 17 (maximum deceleration) = AP 5: the same ramps on both cores (the TMC4210 core
    # decelerates with AP 5, the TMC4361A core with AP 17)
    for axis in targets:
        for parameter, value in ((4, 51200), (5, 51200), (17, 51200)):
            command(module, Opcode.SAP, parameter, axis, value)
    if workload == "hops":
        targets[5] = 20_000
        for parameter, value in ((4, 200_000), (5, 1_000_000), (17, 1_000_000)):
            command(module, Opcode.SAP, parameter, 5, value)
    elif workload == "sramp":
        for axis in range(6):
            command(module, Opcode.WRITE_MC, 0x20, axis, 0b10)  # RAMPMODE: S-shaped profile
            for bow in range(0x2D, 0x31):  # BOW1..BOW4
                command(module, Opcode.WRITE_MC, bow, axis, 400_000)
            command(module, Opcode.SAP, 20, axis, 0)
        for axis in targets:
            for parameter, value in ((4, 200_000), (5, 100_000), (17, 100_000)):
                command(module, Opcode.SAP, parameter, axis, value)
    else:
        for parameter, value in ((4, 102_400), (5, 102_400), (17, 102_400)):
            command(module, Opcode.SAP, parameter, 5, value)
    for axis, target in targets.items():
        command(module, Opcode.MVP, 0, axis, target)
    command(module, Opcode.SAP, 5, 4, 100_000)
    direction = 1
    command(module, Opcode.ROR, 0, 4, 80_000)
    next_reverse = REVERSE_EVERY_NS
    end = round(hours * 3600 * NS)
    moves = 0
    start = time.perf_counter()
    while simulation.now_ns < end:
        simulation.replan()  # the commands below went straight to the module
        nxt = simulation.next_event_ns()
        step = min(end, next_reverse, nxt if nxt is not None else end)
        simulation.advance_to_ns(max(step, simulation.now_ns))
        while arrived:
            axis = arrived.pop()
            targets[axis] = -targets[axis]
            command(module, Opcode.MVP, 0, axis, targets[axis])
            moves += 1
        if simulation.now_ns >= next_reverse:
            direction = -direction
            command(module, Opcode.ROR, 0, 4, direction * 80_000)
            next_reverse += REVERSE_EVERY_NS
    return time.perf_counter() - start, moves, events


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--hours", type=float, default=1.0, help="simulated hours (default 1)")
    parser.add_argument("--repeat", type=int, default=3, help="runs; the median is reported")
    parser.add_argument("--cores", default="tmc4210,tmc4361a",
                        help="chip cores to run, comma-separated (default tmc4210,tmc4361a)")
    args = parser.parse_args()
    simulated = args.hours * 3600
    cores = [c for c in args.cores.split(",") if c]
    reference = None  # the first core's time on the program workload
    for workload in ("program", "hops", "sramp"):
        baseline = None
        for core in cores if workload != "sramp" else [c for c in cores if c == "tmc4361a"]:
            # the cores of one workload run one after the other: they see similar machine load
            results = [run(args.hours, workload, core) for _ in range(args.repeat)]
            walls = sorted(r[0] for r in results)
            wall = statistics.median(walls)
            _, moves, events = results[0]
            print(f"{workload} on {core}: six axes, {simulated:.0f} simulated s, {moves} moves, "
                  f"{events} events")
            if baseline is None:
                baseline = (core, wall)
            if reference is None:
                reference = (core, wall)
            ratio_to = reference if baseline[0] == core else baseline
            print(f"  wall time median {wall:.3f} s (min {walls[0]:.3f}, max {walls[-1]:.3f}, "
                  f"{args.repeat} runs): {simulated / wall:,.0f} simulated s per wall s; "
                  f"{wall / ratio_to[1]:.2f} x {ratio_to[0]}"
                  + ("" if ratio_to is baseline else " on program"))
    print(f"goal: one simulated hour in < 2 s wall ({3600 / 2:,.0f} simulated s per wall s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
