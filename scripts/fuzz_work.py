"""Bounded work, the long version: random parameter combinations on every chip core.

The trials are those of ``tests/tmcl_server/test_bounded_work.py`` (``tests/helpers/
work_fuzz.py``), many more of them: every operation's CPU time is measured, the worst per
core are printed with the operations that led to them, and an operation past ``--limit``
CPU seconds is interrupted and reported.  ``--only N --profile`` replays one trial under
cProfile.  docs/robustness.md ("Bounded work") has the figures.

    PYTHONPATH=$PWD .venv/bin/python scripts/fuzz_work.py --trials 1500 --core 1 --seed 11
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from tests.helpers.work_fuzz import CORES, Cost, OverLimit, arm_limit, engine_trial, trial, trial_rng

ROOT = Path(__file__).resolve().parent.parent


def _worst(args: list[str], pythonpath: str) -> tuple[float, float]:
    """Run this script with ``args`` (no --baseline) on ``pythonpath``: its worst operation
    and its total CPU seconds (operations past the limit count as the limit)."""
    env = dict(os.environ, PYTHONPATH=pythonpath)
    out = subprocess.run([sys.executable, __file__, *args], env=env, cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    print(out, end="")
    match = re.search(r"^WORST ([0-9.]+|inf) s CPU.*total ([0-9.]+) s", out, re.M)
    assert match, "no WORST line"
    return float(match.group(1)), float(match.group(2))


def baseline(rev: str, argv: list[str], limit: float) -> None:
    """The same trials with the ``axes`` package of ``rev``, then with this tree's."""
    rest = []
    skip = False
    for arg in argv:
        if skip:
            skip = False
        elif arg == "--baseline":
            skip = True
        elif not arg.startswith("--baseline="):
            rest.append(arg)
    with tempfile.TemporaryDirectory() as tmp:
        archive = subprocess.run(["git", "archive", rev, "axes"], cwd=ROOT, check=True,
                                 capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        print(f"== axes/ of {rev}")
        before, total_before = _worst(rest, f"{tmp}{os.pathsep}{ROOT}")
    print("== axes/ of this tree")
    after, total_after = _worst(rest, str(ROOT))
    over = before == float("inf")
    before = min(before, limit)  # interrupted at the limit: at least that much
    print(f"worst CPU per operation: {'over ' if over else ''}{before:.3f} s with {rev}, "
          f"{after:.3f} s now: {'at least ' if over else ''}{before / max(after, 1e-6):.0f}x less; "
          f"all operations: {total_before:.1f} s, {total_after:.1f} s "
          f"({total_before / max(total_after, 1e-6):.1f}x)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--trials", type=int, default=200)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--limit", type=float, default=5.0, help="CPU seconds per operation")
    parser.add_argument("--core", type=int, default=None,
                        help=f"index into {CORES} (default: each in turn)")
    parser.add_argument("--only", type=int, default=None, help="run only this trial")
    parser.add_argument("--profile", action="store_true", help="profile each trial")
    parser.add_argument("--show", type=int, default=8, help="how many of the worst to show")
    parser.add_argument("--engine", action="store_true",
                        help="random TMC42x engine states instead of module trials")
    parser.add_argument("--baseline", metavar="REV",
                        help="also run with the axes package of git revision REV; the ratio")
    args = parser.parse_args()
    if args.baseline:
        baseline(args.baseline, sys.argv[1:], args.limit)
        return
    arm_limit()
    costs: list[Cost] = []
    with tempfile.TemporaryDirectory() as tmp:
        for n in range(args.trials):
            if args.only is not None and n != args.only:
                continue
            kind, core = CORES[args.core if args.core is not None else n % len(CORES)]
            profiler = None
            if args.profile:
                import cProfile

                profiler = cProfile.Profile()
                profiler.enable()
            try:
                if args.engine:
                    engine_trial(n, trial_rng(args.seed, n), costs, args.limit)
                else:
                    trial(n, trial_rng(args.seed, n), kind, core, Path(tmp) / f"m{n}", costs,
                          args.limit)
            except OverLimit:
                print("OVER THE LIMIT:", "\n   ".join(costs[-1].ops), flush=True)
            if profiler is not None:
                import pstats

                profiler.disable()
                pstats.Stats(profiler).sort_stats("tottime").print_stats(20)
    costs.sort(key=lambda c: c.seconds, reverse=True)
    for kind, core in CORES:
        mine = [c for c in costs if c.ops and any(f"{kind}/{core} " in op for op in c.ops)]
        if mine:
            print(f"{kind}/{core}: worst {mine[0].seconds:.3f} s CPU of {len(mine)} operations "
                  f"({mine[0].label}, trial {mine[0].trial})")
    if costs:
        total = sum(min(c.seconds, args.limit) for c in costs)
        print(f"WORST {costs[0].seconds:.4f} s CPU ({costs[0].label}, trial {costs[0].trial}); "
              f"total {total:.2f} s")
    print(f"{len(costs)} operations; the worst:")
    seen: set[int] = set()
    for cost in costs[:args.show]:
        print(f"  {cost.seconds:.3f} s  {cost.label}  (trial {cost.trial})")
        if cost.trial not in seen:
            print("      after:", " | ".join(cost.ops))
        seen.add(cost.trial)


if __name__ == "__main__":
    main()
