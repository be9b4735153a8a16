#!/usr/bin/env python3
"""Benchmark the TMCL interpreter.

1. Throughput: a tight CALC/COMP/JC loop on the virtual clock, run through the whole
   simulation (module, event planning), in TMCL instructions per wall-clock second.
   Goal: at least 1,000,000 per second.  Also with a breakpoint set (on the STOP, never
   reached): the interpreter then runs its checking loop, one instruction at a time.
2. What one instruction costs, by kind, on the virtual clock: CALC (the interpreter alone),
   GGP/AGP (a trip into the module), GAP of a stored parameter, GAP of the actual position on
   an idle and on a moving axis (the chip is brought to the instruction's instant and read over
   SPI).  Each as wall-clock microseconds per instruction and as a multiple of CALC; at the
   modelled 10 us per instruction, a program of such instructions needs cost/10 us of a core
   on a real clock (docs/scheduling.md).  These loops change nothing, so by default they would
   be skipped (docs/scheduling.md, "Loops that change nothing"): they run in the stepping
   reference here, every instruction executed.
3. Direct-mode latency while a program runs: a busy program on a real clock, and a host
   sending GAP over TCP; round-trip times of the replies.

    .venv/bin/python scripts/bench_interpreter.py [--seconds S] [--requests N]

Numbers vary with the machine and its load: the script repeats each measurement and
prints the best and the median.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from local_server import tcp_host

from interpreter.assembler import assemble
from tmcl_server.clock import VirtualClock
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCM6212
from tmcl_server.protocol import Request, decode_reply
from tmcl_server.simulation import Simulation

TIGHT_LOOP = """
    CALC LOAD, 0
Loop:
    CALC ADD, 1
    COMP 2000000000
    JC LT, Loop
    STOP
"""

BUSY_PROGRAM = """
Loop:
    GAP 1, 0
    CALC ADD, 1
    AGP 0, 2
    COMP 0
    JC NE, Loop
    JA Loop
"""


def throughput(simulated_s: float, breakpoint: bool = False) -> float:
    module = TMCM6212()
    simulation = Simulation([module], VirtualClock())
    module.program.interpreter.load(assemble(TIGHT_LOOP).instructions)
    if breakpoint:
        module.program.interpreter.breakpoints.add(4)  # the STOP, never reached
    module.program.interpreter.start(0)
    before = module.program.interpreter.executed
    t0 = time.perf_counter()
    simulation.advance(simulated_s)
    elapsed = time.perf_counter() - t0
    return (module.program.interpreter.executed - before) / elapsed


#: Six axes turning at 100,000 pps, for the "moving axis" rows.
_TURNING = "".join(f"    SAP 4, {a}, 200000\n    SAP 5, {a}, 400000\n    ROR {a}, 100000\n"
                   for a in range(6))

#: (what, the instruction repeated in the loop, setup before the loop)
INSTRUCTION_KINDS = [
    ("CALC ADD", "CALC ADD, 1", ""),
    ("GGP (user variable)", "GGP 1, 2", ""),
    ("AGP (user variable)", "AGP 1, 2", ""),
    ("GAP 4 (stored parameter)", "GAP 4, 0", _TURNING),
    ("GAP 1, idle axis", "GAP 1, 0", ""),
    ("GAP 1, moving axis", "GAP 1, 0", _TURNING),
]


def instruction_cost_us(body: str, setup: str, simulated_s: float) -> float:
    """Wall-clock microseconds per instruction of a loop of nine ``body`` and one JA."""
    module = TMCM6212()
    simulation = Simulation([module], VirtualClock())
    source = setup + "Loop:\n" + f"    {body}\n" * 9 + "    JA Loop\n"
    module.program.skip_loops = False  # the cost of executing it (such a loop is skipped)
    module.program.interpreter.load(assemble(source).instructions)
    module.program.interpreter.start(0)
    simulation.advance(0.01)  # past the setup
    before = module.program.interpreter.executed
    t0 = time.perf_counter()
    simulation.advance(simulated_s)
    elapsed = time.perf_counter() - t0
    return elapsed / (module.program.interpreter.executed - before) * 1e6


def latency(requests: int) -> list[float]:
    with SimulatorThread(clock="real", tcp=["127.0.0.1:0"]) as sim:
        program = assemble(BUSY_PROGRAM).instructions

        def start() -> None:
            module = sim.simulation.module(1)
            module.program.interpreter.load(program)
            module.program.interpreter.start(module.now_ns)

        sim.call(start)
        host = tcp_host(sim.tcp, timeout=None)
        try:
            frame = Request(1, 6, 1, 0, 0).encode()
            times = []
            for _ in range(requests):
                t0 = time.perf_counter()
                data = host.exchange(frame)
                times.append(time.perf_counter() - t0)
                assert decode_reply(data).status == 100
        finally:
            host.close()
        running = sim.call(lambda: sim.simulation.module(1).program.interpreter.executed)
        print(f"  (the program executed {running} instructions meanwhile)")
        return times


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0,
                        help="simulated seconds per throughput run (default 20)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--requests", type=int, default=2000)
    args = parser.parse_args()

    rates = [throughput(args.seconds) for _ in range(args.repeat)]
    print(f"tight CALC/COMP/JC loop, virtual clock: best {max(rates):,.0f} instr/s, "
          f"median {statistics.median(rates):,.0f} instr/s (goal >= 1,000,000)")
    checked = [throughput(args.seconds / 4, breakpoint=True) for _ in range(args.repeat)]
    print(f"the same with a breakpoint set (checking loop): best {max(checked):,.0f} instr/s, "
          f"median {statistics.median(checked):,.0f} instr/s")

    print("cost of one instruction, virtual clock (median of the repeats):")
    base = None
    for what, body, setup in INSTRUCTION_KINDS:
        cost = statistics.median(instruction_cost_us(body, setup, args.seconds / 20)
                                 for _ in range(args.repeat))
        base = base or cost
        print(f"  {what:26s} {cost:6.2f} us  {cost / base:5.1f} x CALC  "
              f"({cost / 10:4.0%} of a core at 100,000 instructions/s)")

    times = sorted(latency(args.requests))
    ms = [t * 1000 for t in times]
    print(f"direct-mode GAP over TCP while a program runs ({args.requests} requests): "
          f"median {statistics.median(ms):.3f} ms, p99 {ms[int(len(ms) * 0.99) - 1]:.3f} ms, "
          f"max {ms[-1]:.3f} ms")
    return 0 if max(rates) >= 1_000_000 else 1


if __name__ == "__main__":
    sys.exit(main())
