#!/usr/bin/env python3
"""Start-up: from process start to the ready file, for one module with TCP only.

Starts ``tmcl-server --tcp 127.0.0.1:0 --ready-file F`` ``--repeat`` times and reports the
median time until the ready file exists, beside the time a bare ``python -c pass`` takes in
the same run.  Python writes and reuses its bytecode caches here as on any installation
(``PYTHONDONTWRITEBYTECODE``, which some sandboxes set, is removed for the children; one
warm-up start fills the caches).  Goal (issue 10): the ready file within 150 ms.

``--plugin``: what the pytest plugin (installed into every pytest run of the environment)
adds to pytest's start instead: its import's cumulative time by ``python -X importtime``,
median of ``--repeat`` runs beside pytest's own import; ``--compare DIR`` measures another
checkout's plugin in the same runs, alternating (e.g. a worktree of main).  Goal (issue 37):
under 30 ms.

    .venv/bin/python scripts/bench_startup.py [--repeat 9] [--loop auto|asyncio|uvloop]
    .venv/bin/python scripts/bench_startup.py --plugin [--compare ../base] [--repeat 15]
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


def import_times(env: dict[str, str], checkout: Path | None) -> tuple[float, float]:
    """(pytest's import, the plugin's import after it), cumulative seconds, from one
    ``python -X importtime`` run; ``checkout``: import the plugin from there."""
    if checkout is not None:
        env = {**env, "PYTHONPATH": str(checkout)}
    done = subprocess.run([sys.executable, "-X", "importtime", "-c",
                           "import pytest; import tmcl_server.pytest_plugin"],
                          env=env, capture_output=True, text=True, check=True,
                          cwd=checkout)  # (-c puts the directory first on sys.path)
    cumulative = {}
    for line in done.stderr.splitlines():  # "import time: self | cumulative | name"
        parts = [p.strip() for p in line.removeprefix("import time:").split("|")]
        if len(parts) == 3 and parts[1].isdigit():
            cumulative[parts[2]] = int(parts[1]) / 1e6
    return cumulative["pytest"], cumulative["tmcl_server.pytest_plugin"]


def bench_plugin(env: dict[str, str], repeat: int, compare: Path | None) -> None:
    own = Path(__file__).resolve().parents[1]
    checkouts: list[tuple[str, Path | None]] = [("this checkout", own)]
    if compare is not None:
        checkouts.append((str(compare), compare.resolve()))
    for _, where in checkouts:
        import_times(env, where)  # fills the bytecode caches
    results: dict[str, list[tuple[float, float]]] = {name: [] for name, _ in checkouts}
    for _ in range(repeat):  # alternating: the machine's load hits each alike
        for name, where in checkouts:
            results[name].append(import_times(env, where))
    for name, times in results.items():
        plugin = statistics.median(t[1] for t in times) * 1000
        pytest_ms = statistics.median(t[0] for t in times) * 1000
        print(f"{name}: the plugin's import {plugin:.1f} ms (median of {repeat}, min "
              f"{min(t[1] for t in times) * 1000:.1f}) beside pytest's own {pytest_ms:.0f} ms; "
              "goal < 30 ms")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=9)
    parser.add_argument("--loop", default="auto", choices=("auto", "asyncio", "uvloop"))
    parser.add_argument("--plugin", action="store_true", help="the pytest plugin's import instead")
    parser.add_argument("--compare", type=Path, metavar="DIR",
                        help="with --plugin: also another checkout's plugin, alternating")
    args = parser.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    if args.plugin:
        bench_plugin(env, args.repeat, args.compare)
        return 0
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
