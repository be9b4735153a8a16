#!/usr/bin/env python3
"""Write the behaviour snapshots again (tests/snapshots/, compared by tests/test_snapshots.py):
after a change of behaviour made on purpose, so that its diff goes into the same commit.

    .venv/bin/python scripts/update_snapshots.py [--only tmcm-6212-tmc4210 ...]

Prints which transcripts changed (and how many lines)."""

from __future__ import annotations

import argparse
import difflib
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from tests.helpers.snapshot import COMBINATIONS, run_script, snapshot_path


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", nargs="*", metavar="MODULE-CORE",
                        help="just these transcripts (e.g. tmcm-6212-tmc4210)")
    args = parser.parse_args()
    chosen = [(kind, core) for kind, core in COMBINATIONS
              if not args.only or f"{kind}-{core}" in args.only]
    if args.only and len(chosen) != len(args.only):
        known = ", ".join(f"{kind}-{core}" for kind, core in COMBINATIONS)
        print(f"update_snapshots.py: unknown name in {args.only}; known: {known}", file=sys.stderr)
        return 2
    for kind, core in chosen:
        path = snapshot_path(kind, core)
        before = path.read_text().splitlines() if path.exists() else []
        text = run_script(kind, core)
        changed = sum(1 for line in difflib.unified_diff(before, text.splitlines(), n=0)
                      if line[:1] in "+-" and line[:3] not in ("+++", "---"))
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        print(f"{path.name}: {'unchanged' if not changed else f'{changed} lines changed'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
