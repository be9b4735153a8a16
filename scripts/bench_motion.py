#!/usr/bin/env python3
"""Simulated seconds per wall second: six axes in continuous motion on the virtual clock.

Goal (issue 3): one simulated hour in under 2 s of wall time; issue 12: the TMC4361A core
(``--axis-core tmc4361a``) no slower than the TMC4210 core, both measured in the same run;
issue 23: the ``program`` workload's hour in at most 0.5 s on the TMC4210 and TMC429 cores.

The workloads, every axis always moving, the virtual clock jumping from event to event, and
each next move issued at the target-reached instant (as WAIT POS would):

* ``program`` (the goal's workload): axes 0-3 and 5 run the manual's example program (§2.4:
  MVP ABS ±512000 at 51200 pps and 51200 pps²; axis 5 at twice the speed); axis 4 rotates
  at 80 000 pps and reverses every 7 s.
* ``hops`` (stress): the same, but axis 5 makes 20 000-step hops at 200 000 pps and
  1 000 000 pps², so ramps dominate.  Braking follows the chip's distance law one ramp tick
  at a time (it has no closed form), so time goes with the number of ramp ticks.
* ``varied``: the ``program`` workload, but every move goes to a new target (±512 000 plus
  a random offset of up to 100 000 steps, seeded): no two moves brake from the same state, so
  this is what a move costs when the engine has not seen its braking before (the TMC42x
  engine remembers the braking of moves it has made: ``program`` repeats its moves).
* ``sramp`` (TMC4361A only): the ``program`` workload with S-shaped ramps, chosen through
  command 146 (RAMPMODE profile 2, BOW1..4 = 400 000 pps³) on every axis, AP 20 = 0; the
  moving axes at 200 000 pps and 100 000 pps².  S-ramps go through the firmware's look-ahead
  (a clone run with a work budget), so this shows what they cost there.

Each workload runs on every setup (``--setups``): by default a TMCM-6212 on its TMC4210 core
and on the TMC4361A core (speeds in pps), and a TMCM-6110 (six axes on two TMC429 chips, each
axis's look-ahead copying its whole chip; the same speeds and accelerations as register
values with AP 154/153, as the firmware would choose them).

    .venv/bin/python scripts/bench_motion.py [--hours H] [--repeat N] [--setups LIST]
"""

from __future__ import annotations

import argparse
import random
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from axes.chips.tmc42x.units import choose_pulse_div, choose_ramp_div, velocity_register
from tmcl_server.clock import VirtualClock
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode

NS = 1_000_000_000
REVERSE_EVERY_NS = 7 * NS
CLOCK_HZ = 16_000_000
#: module type / chip core ("-": the module type's own)
SETUPS = "tmcm-6212/tmc4210,tmcm-6212/tmc4361a,tmcm-6110/-"


def command(module: TMCLModule, opcode: int, type_: int, motor: int, value: int) -> None:
    module.execute(Request(1, opcode, type_, motor, value))


def limits(module: TMCLModule, axis: int, speed: int, acceleration: int) -> int:
    """Set the speed and acceleration limits for ``speed`` pps and ``acceleration`` pps² (and
    AP 17 = AP 5: the same ramps on every core); returns the value a rotation at ``speed``
    takes (pps, or on the TMC429 modules the register value)."""
    if module.type.key == "tmcm-6212":
        for parameter, value in ((4, speed), (5, acceleration), (17, acceleration)):
            command(module, Opcode.SAP, parameter, axis, value)
        return speed
    pulse_div = choose_pulse_div(speed, CLOCK_HZ)
    ramp_div, a_max = choose_ramp_div(acceleration, pulse_div, CLOCK_HZ)
    v_max = velocity_register(speed, pulse_div, CLOCK_HZ)
    for number, value in ((154, pulse_div), (153, ramp_div), (4, v_max), (5, a_max)):
        command(module, Opcode.SAP, number, axis, value)
    return v_max


def run(hours: float, workload: str, kind: str, core: str | None) -> tuple[float, int, int]:
    """Returns (wall seconds, moves completed, events handled)."""
    module = TMCLModule(kind=kind, chip_core=core)
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
    offsets = random.Random(23)
    for axis in targets:
        limits(module, axis, 51200, 51200)
    if workload == "hops":
        targets[5] = 20_000
        limits(module, 5, 200_000, 1_000_000)
    elif workload == "sramp":
        for axis in range(6):
            command(module, Opcode.WRITE_MC, 0x20, axis, 0b10)  # RAMPMODE: S-shaped profile
            for bow in range(0x2D, 0x31):  # BOW1..BOW4
                command(module, Opcode.WRITE_MC, bow, axis, 400_000)
            command(module, Opcode.SAP, 20, axis, 0)
        for axis in targets:
            limits(module, axis, 200_000, 100_000)
    else:
        limits(module, 5, 102_400, 102_400)
    for axis, target in targets.items():
        command(module, Opcode.MVP, 0, axis, target)
    rotation = limits(module, 4, 80_000, 100_000)
    direction = 1
    command(module, Opcode.ROR, 0, 4, rotation)
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
            if workload == "varied":
                targets[axis] = (512_000 if targets[axis] > 0 else -512_000) + offsets.randrange(
                    -100_000, 100_000)
            command(module, Opcode.MVP, 0, axis, targets[axis])
            moves += 1
        if simulation.now_ns >= next_reverse:
            direction = -direction
            command(module, Opcode.ROR, 0, 4, direction * rotation)
            next_reverse += REVERSE_EVERY_NS
    return time.perf_counter() - start, moves, events


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--hours", type=float, default=1.0, help="simulated hours (default 1)")
    parser.add_argument("--repeat", type=int, default=3, help="runs; the median is reported")
    parser.add_argument("--setups", default=SETUPS,
                        help=f"MODULE/CORE pairs, comma-separated (default {SETUPS})")
    args = parser.parse_args()
    simulated = args.hours * 3600
    setups = [tuple(s.split("/")) for s in args.setups.split(",") if s]
    for workload in ("program", "varied", "hops", "sramp"):
        baseline = None
        for kind, core in setups:
            if workload == "sramp" and core != "tmc4361a":
                continue  # S-ramps are the TMC4361A's
            # the setups of one workload run one after the other: they see similar load
            results = [run(args.hours, workload, kind, None if core == "-" else core)
                       for _ in range(args.repeat)]
            walls = sorted(r[0] for r in results)
            wall = statistics.median(walls)
            _, moves, events = results[0]
            label = f"{kind} on {core if core != '-' else 'its own core'}"
            baseline = baseline or (label, wall)
            print(f"{workload}, {label}: six axes, {simulated:.0f} simulated s, {moves} moves, "
                  f"{events} events")
            print(f"  wall time median {wall:.3f} s (min {walls[0]:.3f}, max {walls[-1]:.3f}, "
                  f"{args.repeat} runs): {simulated / wall:,.0f} simulated s per wall s; "
                  f"{wall / baseline[1]:.2f} x {baseline[0]}")
    print(f"goal: one simulated hour in < 2 s wall ({3600 / 2:,.0f} simulated s per wall s); "
          f"issue 23: <= 0.5 s for the program workload on the TMC4210 and TMC429 cores "
          f"({3600 / 0.5:,.0f} simulated s per wall s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
