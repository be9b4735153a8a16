#!/usr/bin/env python3
"""Start-up: from process start to the ready file, for one module with TCP only.

Starts ``tmcl-server --tcp 127.0.0.1:0 --ready-file F`` ``--repeat`` times and reports the
median time until the ready file exists, beside the time a bare ``python -c pass`` takes in
the same run.  Python writes and reuses its bytecode caches here as on any installation
(``PYTHONDONTWRITEBYTECODE``, which some sandboxes set, is removed for the children; one
warm-up start fills the caches).  Goal (issue 10): the ready file within 150 ms.

    .venv/bin/python scripts/bench_startup.py [--repeat 9] [--loop auto|asyncio|uvloop]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def start_once(env: dict[str, str], loop: str) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        ready = Path(tmp) / "ready.json"
        started = time.perf_counter()
        process = subprocess.Popen(
            [sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", "--ready-file",
             str(ready), "--loop", loop], env=env, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL)
        try:
            while not ready.exists():
                if process.poll() is not None:
                    raise RuntimeError("tmcl-server exited")
                time.sleep(0.0005)
            return time.perf_counter() - started
        finally:
            process.terminate()
            process.wait(10)


def bare_python(env: dict[str, str]) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], env=env, check=True)
    return time.perf_counter() - started


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--loop", default="auto", choices=("auto", "asyncio", "uvloop"))
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    start_once(env, args.loop)  # fills the bytecode caches
    starts, bares = [], []
    for _ in range(args.repeat):  # interleaved: the machine's load hits both alike
        starts.append(start_once(env, args.loop))
        bares.append(bare_python(env))
    print(f"ready file after {statistics.median(starts) * 1000:.0f} ms (median of {args.repeat}, "
          f"min {min(starts) * 1000:.0f}); bare python {statistics.median(bares) * 1000:.0f} ms; "
          f"loop {args.loop}; goal < 150 ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
