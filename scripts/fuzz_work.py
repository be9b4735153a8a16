"""Bounded work: random parameter combinations on every chip core, on the virtual clock.

Each trial builds a module, writes random axis parameters (range ends and extreme values),
maybe raw chip registers and switches, starts a motion (MVP, ROL/ROR, MST, RFS) and advances
the virtual clock, asking for positions on the way.  Every operation's CPU time is measured;
the worst are reported, and the sequence that led to any operation above the bound.
"""

from __future__ import annotations

import argparse
import random
import signal
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from tmcl_server.clock import VirtualClock
from tmcl_server.eeprom import Eeprom
from tmcl_server.module import TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode

#: (module type, chip core) pairs: every core the simulator has, on the modules it serves.
CORES = [("tmcm-6212", None), ("tmcm-1110", None), ("tmcm-6110", None),
         ("tmcm-6212", "tmc4361a")]
#: Rows that shape the motion (speeds, accelerations, dividers, switches, reference search).
MOTION_PARAMETERS = frozenset({4, 5, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26,
                               27, 28, 31, 130, 135, 138, 140, 149, 153, 154, 193, 194, 195,
                               200, 254, 255})
EXTREMES = (0, 1, -1, 2, 2**31 - 1, -2**31, 2047, 2048, 65535, 1 << 23, -(1 << 23))


@dataclass
class Trace:
    ops: list[str] = field(default_factory=list)


class Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise Timeout


def values_for(spec, rng: random.Random) -> int:
    pool = list(EXTREMES)
    if spec.allowed:
        pool += sorted(spec.allowed)
    else:
        pool += [spec.minimum, spec.maximum, spec.minimum + 1, spec.maximum - 1]
        if spec.maximum - spec.minimum > 2:
            pool.append(rng.randint(spec.minimum, spec.maximum))
    return rng.choice(pool)


def trial(number: int, rng: random.Random, kind: str, core: str | None, directory: Path,
          costs: list[tuple[float, str, list[str], int]], limit: float) -> None:
    module = TMCLModule(1, Eeprom(directory), kind=kind, chip_core=core)
    sim = Simulation([module], VirtualClock())
    ops: list[str] = []
    axes = len(module.axes)
    params = [s for s in module.type.axis_parameters.values() if s.writable]

    def timed(label: str, action) -> None:
        ops.append(label)
        signal.setitimer(signal.ITIMER_PROF, limit)
        start = time.process_time()
        try:
            action()
        except Timeout:
            costs.append((float("inf"), label, list(ops), number))
            raise
        finally:
            signal.setitimer(signal.ITIMER_PROF, 0)
        costs.append((time.process_time() - start, label, list(ops), number))

    def send(op: int, type_: int, motor: int, value: int) -> None:
        value = (value + 2**31) % 2**32 - 2**31
        frame = Request(1, op, type_, motor, value).encode()
        timed(f"{kind}/{core} {Opcode(op).name if op in Opcode._value2member_map_ else op} "
              f"{type_} {motor} {value}", lambda: sim.handle_serial_frame(frame))

    motor = rng.randrange(axes)
    if rng.random() < 0.3:
        side = rng.choice(["left", "right", "home"])
        where = rng.choice([None, 0, 100, -100, 10_000, -10_000])
        if where is None:
            module.force_switch(motor, side, True)
        else:
            module.set_switch(motor, side, where, rng.choice([None, 1, 1000]))
        sim.notify_changed()
        ops.append(f"switch {side} at {where}")
    if rng.random() < 0.1:
        module.set_axis_stuck(motor, True, rng.choice([None, 0]))
        sim.notify_changed()
        ops.append("stuck")
    motion = [s for s in params if s.number in MOTION_PARAMETERS]
    for _ in range(rng.randint(1, 10)):
        spec = rng.choice(motion if motion and rng.random() < 0.6 else params)
        send(Opcode.SAP, spec.number, motor, values_for(spec, rng))
    if rng.random() < 0.3:
        for _ in range(rng.randint(1, 4)):
            send(Opcode.WRITE_MC, rng.randrange(0x80), motor, rng.choice((*EXTREMES, rng.getrandbits(24))))
    for _ in range(rng.randint(1, 3)):
        choice = rng.random()
        if choice < 0.35:
            send(Opcode.MVP, rng.choice([0, 1]), motor, rng.choice((*EXTREMES, 1000, -1000)))
        elif choice < 0.7:
            send(rng.choice([Opcode.ROR, Opcode.ROL]), 0, motor, rng.choice((*EXTREMES, 1000)))
        elif choice < 0.85:
            send(Opcode.RFS, 0, motor, 0)
        else:
            spec = rng.choice(params)
            send(Opcode.SAP, spec.number, motor, values_for(spec, rng))
        for _ in range(rng.randint(1, 3)):
            dt = rng.choice([0.001, 0.1, 1.0, 4.0, 10.0])
            timed(f"advance {dt}", lambda dt=dt: sim.advance(dt))
            send(Opcode.GAP, 1, motor, 0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--limit", type=float, default=5.0, help="CPU seconds per operation")
    parser.add_argument("--core", type=int, default=None, help="index into CORES")
    parser.add_argument("--only", type=int, default=None, help="run only this trial")
    parser.add_argument("--profile", action="store_true")
    parser.add_argument("--show", type=int, default=8, help="how many of the worst to show")
    args = parser.parse_args()
    signal.signal(signal.SIGPROF, _alarm)
    costs: list[tuple[float, str, list[str], int]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in range(args.trials):
            if args.only is not None and n != args.only:
                continue
            kind, core = CORES[args.core if args.core is not None else n % len(CORES)]
            rng = random.Random(args.seed * 1_000_003 + n)
            profiler = None
            if args.profile:
                import cProfile
                profiler = cProfile.Profile()
                profiler.enable()
            try:
                trial(n, rng, kind, core, Path(tmp) / f"m{n}", costs, args.limit)
            except Timeout:
                print("TIMEOUT:", "\n   ".join(costs[-1][2]), flush=True)
            if profiler is not None:
                import pstats
                profiler.disable()
                pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
    costs.sort(key=lambda c: c[0], reverse=True)
    for kind, core in CORES:
        tag = f"{kind}/{core}"
        mine = [c for c in costs if tag in " ".join(c[2])]
        if mine:
            print(f"{tag}: worst {mine[0][0]:.3f} s of {len(mine)} ({mine[0][1]})")
    print(f"{len(costs)} operations; worst:")
    seen = set()
    for cost, label, ops, n in costs[:args.show]:
        print(f"  {cost:.3f} s  {label}  (trial {n})")
        if n not in seen:
            print("      after:", " | ".join(ops))
        seen.add(n)


if __name__ == "__main__":
    main()
