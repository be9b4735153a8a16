#!/usr/bin/env python3
"""Loop skipping against the stepping reference on many random programs and worlds (the long
version of tests/tmcl_server/test_loop_skipping.py): every difference is printed with the
program and world that show it.

    .venv/bin/python scripts/fuzz_skipping.py [--examples N] [--seed S]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hypothesis import HealthCheck, given, seed, settings

from tests.tmcl_server.test_loop_skipping import programs, run, worlds


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--examples", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    stats = {"examples": 0, "skipping": 0}

    @seed(args.seed)
    @settings(max_examples=args.examples, deadline=None, database=None,
              suppress_health_check=list(HealthCheck))
    @given(programs(), worlds())
    def compare(source, world):  # type: ignore[no-untyped-def]
        fast, slow = run(source, world, True), run(source, world, False)
        stats["examples"] += 1
        stats["skipping"] += fast[-1] != ("skipped", 0)
        assert fast[:-1] == slow[:-1], f"differs:\n{source}\n{world}"

    compare()
    print(f"{stats['examples']} random programs and worlds ({stats['skipping']} of them skipped "
          "passes): skipping == stepping in every one")
    return 0


if __name__ == "__main__":
    sys.exit(main())
