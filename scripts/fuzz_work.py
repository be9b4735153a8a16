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
import tempfile
from pathlib import Path

from tests.helpers.work_fuzz import CORES, Cost, OverLimit, arm_limit, trial, trial_rng


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
    args = parser.parse_args()
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
    print(f"{len(costs)} operations; the worst:")
    seen: set[int] = set()
    for cost in costs[:args.show]:
        print(f"  {cost.seconds:.3f} s  {cost.label}  (trial {cost.trial})")
        if cost.trial not in seen:
            print("      after:", " | ".join(cost.ops))
        seen.add(cost.trial)


if __name__ == "__main__":
    main()
