#!/usr/bin/env python3
"""Loop skipping against the stepping reference on many random programs and worlds (the long
version of tests/tmcl_server/test_loop_skipping.py, with its strategies): every difference is
printed with the program and world that show it.

    .venv/bin/python scripts/fuzz_skipping.py [--examples N] [--seed S] [--shapes a,b]

Each shape (poll, wrap, monitor, wait, s-ramp, calc, positioning-speed) gets ``--examples``
random programs and worlds; the skipping run advances the clock as its world says (one call,
or 1 ms, 0.37 ms or mixed steps), the stepping reference in one call, both with the world's
recorder if it has one.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hypothesis import HealthCheck, given, seed, settings

from tests.tmcl_server.test_loop_skipping import SHAPES, World, run, scenarios


def fuzz(shape: str, examples: int, seed_value: int) -> tuple[int, int, list[str]]:
    """(examples run, how many skipped passes, the differences found) for one shape."""
    stats = {"examples": 0, "skipping": 0}
    found: list[str] = []

    @seed(seed_value)
    @settings(max_examples=examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(scenarios(shape))
    def compare(scenario: tuple[str, World]) -> None:
        fast, slow = run(*scenario, True), run(*scenario, False)
        stats["examples"] += 1
        stats["skipping"] += fast[-1][1] != 0
        assert fast[:-1] == slow[:-1], f"differs:\n{scenario[0]}\n{scenario[1]!r}"

    try:
        compare()
    except AssertionError as exc:  # hypothesis has shrunk it to a small one
        found.append(str(exc))
    return stats["examples"], stats["skipping"], found


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=2000, help="per shape")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--shapes", default=",".join(SHAPES),
                        help=f"comma-separated, of {', '.join(SHAPES)}")
    args = parser.parse_args()
    shapes = [name for name in args.shapes.split(",") if name]
    unknown = sorted(set(shapes) - set(SHAPES))
    if unknown:
        parser.error(f"unknown shape(s) {', '.join(unknown)}; the shapes are {', '.join(SHAPES)}")
    failed = False
    for shape in shapes:
        examples, skipping, found = fuzz(shape, args.examples, args.seed)
        verdict = "skipping == stepping in every one" if not found else "DIFFERS"
        print(f"{shape}: {examples} random programs and worlds, seed {args.seed} ({skipping} of "
              f"them skipped passes): {verdict}", flush=True)
        for text in found:
            print(text, flush=True)
        failed = failed or bool(found)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
