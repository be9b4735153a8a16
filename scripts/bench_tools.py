#!/usr/bin/env python3
"""The tools against hostile input (issue 27, items 6 and 8): how long ``tmcl-asm`` takes to end
each hostile source with its one error line, and how much memory ``tmcl decode --file`` needs
for a small and a ten times larger ``hexdump -C`` capture (flat: it streams).

    python scripts/bench_tools.py [--repeat 3] [--baseline /path/to/older/checkout]

Each case runs in a fresh process (``python -m interpreter.cli``, ``python -m tmcl_server.tool``)
and is timed from start to exit, interpreter start included (its own line: ``startup``).
With ``--baseline`` the decode cases also run against that checkout's code (its packages first
on ``PYTHONPATH``), side by side, for the memory ratio; its assembler is not run (issue 27
measured it: > 20 s or a traceback for most of these).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.interpreter.test_assembler import _hostile  # noqa: E402  (the sources the test uses)

MEASURE = ("import resource, sys, os\n"
           "import tmcl_server\n"
           "from tmcl_server.tool import main\n"
           "sys.stdout = open(os.devnull, 'w')\n"
           "code = main(sys.argv[1:])\n"
           "print(tmcl_server.__file__, code, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,\n"
           "      file=sys.stderr)\n")


def timed(argv: list[str], env: dict[str, str] | None = None
          ) -> tuple[float, subprocess.CompletedProcess[str]]:
    start = time.perf_counter()
    result = subprocess.run(argv, capture_output=True, text=True, timeout=120, env=env,
                            cwd=tempfile.gettempdir())  # not a checkout: PYTHONPATH decides
    return time.perf_counter() - start, result


def bench_assembler(folder: Path, repeat: int) -> None:
    print("tmcl-asm: each hostile source, median wall seconds (process start included)")
    startup = statistics.median(timed([sys.executable, "-c", "import interpreter.cli"])[0]
                                for _ in range(repeat))
    print(f"  {'startup':<24} {startup:6.2f} s")
    for name, source in _hostile(folder).items():
        runs = [timed([sys.executable, "-m", "interpreter.cli", "assemble", str(source)])
                for _ in range(repeat)]
        err = runs[-1][1].stderr.strip().splitlines()
        line = err[0].split(": ", 1)[-1] if err else "(no message)"
        print(f"  {name:<24} {statistics.median(t for t, _ in runs):6.2f} s  {len(err)} line: {line[:70]}")


def bench_decode(folder: Path, baseline: Path | None) -> None:
    if shutil.which("hexdump") is None:
        print("decode: hexdump not installed, skipped")
        return
    frame = bytes([1, 6, 1, 0, 0, 0, 0, 0, 8, 2, 1, 100, 6, 0, 0, 0, 0, 109])  # GAP and its reply
    print("tmcl decode --file (hexdump -C capture): peak RSS in MiB")
    checkouts = [("this checkout", ROOT)] + ([("baseline", baseline)] if baseline else [])
    for label, checkout in checkouts:
        env = {**os.environ, "PYTHONPATH": str(checkout)}
        cells = []
        for pairs in (20_000, 200_000):
            raw = folder / f"capture-{pairs}.bin"
            raw.write_bytes(frame * pairs)
            dump = folder / f"capture-{pairs}.txt"
            with dump.open("w") as out:
                subprocess.run(["hexdump", "-C", str(raw)], stdout=out, check=True)
            seconds, result = timed([sys.executable, "-c", MEASURE, "decode", "--file", str(dump)], env)
            where, code, rss_kib = result.stderr.split()[-3:]
            assert where.startswith(str(checkout)), where  # that checkout's code ran
            cells.append(f"{dump.stat().st_size / 2**20:5.1f} MiB in: {int(rss_kib) / 1024:6.1f} MiB, "
                         f"{seconds:5.1f} s (exit {code})")
        print(f"  {label:<14} " + "   ".join(cells))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--baseline", type=Path, help="an older checkout to compare decode with")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        bench_assembler(Path(tmp), args.repeat)
        bench_decode(Path(tmp), args.baseline)


if __name__ == "__main__":
    main()
