#!/usr/bin/env python3
"""Hostile neighbours of a TCP host (issue 27, item 7): how much of its lockstep request rate
is left while something else hammers the server.

For each case a fresh ``tmcl-server --tcp ... --http ...`` process is started, the attack is
started from a separate process (so that it does not take this process's GIL), and a TCP host
sends GAP and waits for each reply for ``--seconds``:

* ``baseline``: nothing else;
* ``api-flood``: 50 connections asking ``GET /api/frame`` as fast as they are answered;
* ``websockets``: 1,000 WebSockets opened to ``/ws``, each acknowledging every frame;
* ``idle-tcp``: 600 idle TCP connections opened first (the limit is 256), then the host
  connects.

Prints the host's rate and its ratio to the baseline per case, and the server's RSS growth.
``--compare DIR`` measures a second checkout (e.g. the code before the fix) in the same run,
case by case, alternating which goes first.

    .venv/bin/python scripts/bench_hostile.py [--seconds 5] [--compare /work/main]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from local_server import StreamClient, UploadError, rss_kb, tcp_host, wait_for_ready

ROOT = Path(__file__).resolve().parents[1]
CASES = ("baseline", "api-flood", "websockets", "idle-tcp")
GAP = bytes([1, 6, 1, 0, 0, 0, 0, 0, 8])


class Server:
    def __init__(self, checkout: Path, python: str, workdir: Path) -> None:
        ready = workdir / "ready.json"
        self.proc = subprocess.Popen(
            [python, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", "--http", "127.0.0.1:0",
             "--ready-file", str(ready)], cwd=checkout, stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})  # leave another checkout as it is
        endpoints = wait_for_ready(self.proc, ready, what="server", poll_s=0.05)
        host, port = endpoints["tcp"][0].rsplit(":", 1)
        self.tcp = (host, int(port))
        self.http = endpoints["http"][0]

    def rss_kb(self) -> int:
        return rss_kb(self.proc.pid)

    def stop(self) -> None:
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def host_rate(tcp: tuple[str, int], seconds: float) -> float:
    """Lockstep GAP requests per second; a refused or closed connection is retried (a locked
    out host scores what it manages)."""
    done = 0
    end = time.monotonic() + seconds
    host: StreamClient | None = None
    while time.monotonic() < end:
        try:
            if host is None:
                host = tcp_host(tcp, timeout=1)
            host.exchange(GAP)
            done += 1
        except (OSError, UploadError):  # UploadError: the server closed the connection
            if host is not None:
                host.close()
            host = None
            time.sleep(0.05)
    if host is not None:
        host.close()
    return done / seconds


# -- attackers (run as ``bench_hostile.py --attack CASE URL``) ----------------------------------

async def api_flood(url: str) -> None:
    import aiohttp

    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=50)) as session:
        async def one() -> None:
            while True:
                try:
                    async with session.get(f"{url}api/frame") as response:
                        await response.read()
                except aiohttp.ClientError:
                    await asyncio.sleep(0.01)
        await asyncio.gather(*(one() for _ in range(50)))


async def websockets(url: str) -> None:
    import aiohttp

    async with aiohttp.ClientSession(connector=aiohttp.TCPConnector(limit=0)) as session:
        async def one() -> None:
            while True:
                try:
                    async with session.ws_connect(f"{url}ws") as ws:
                        async for message in ws:
                            if message.type == aiohttp.WSMsgType.TEXT and '"frame"' in message.data[:20]:
                                await ws.send_str('{"op":"ack"}')
                except aiohttp.ClientError:
                    pass
                await asyncio.sleep(0.5)
        await asyncio.gather(*(one() for _ in range(1000)))


def attacker(case: str, server: Server) -> subprocess.Popen[bytes] | list[socket.socket] | None:
    if case == "baseline":
        return None
    if case == "idle-tcp":
        idle = []
        for _ in range(600):
            try:
                idle.append(socket.create_connection(server.tcp, timeout=2))
            except OSError:
                break
        return idle
    proc = subprocess.Popen([sys.executable, __file__, "--attack", case, server.http],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(2.0)  # let it open its connections
    return proc


def stop_attacker(attack: subprocess.Popen[bytes] | list[socket.socket] | None) -> None:
    if isinstance(attack, list):
        for sock in attack:
            sock.close()
    elif attack is not None:
        attack.terminate()
        attack.wait(10)


def measure(case: str, checkout: Path, python: str, seconds: float) -> dict[str, float]:
    with tempfile.TemporaryDirectory(prefix="bench-hostile-") as tmp:
        server = Server(checkout, python, Path(tmp))
        try:
            rss = server.rss_kb()
            attack = attacker(case, server)
            try:
                rate = host_rate(server.tcp, seconds)
                grown = server.rss_kb() - rss
            finally:
                stop_attacker(attack)
        finally:
            server.stop()
    return {"rate": round(rate), "rss_growth_kb": grown}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=5.0)
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--compare", type=Path, metavar="DIR")
    parser.add_argument("--attack", nargs=2, metavar=("CASE", "URL"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.attack:
        case, url = args.attack
        asyncio.run(api_flood(url) if case == "api-flood" else websockets(url))
        return 0
    checkouts = {"this": (ROOT, sys.executable)}
    if args.compare is not None:
        python = args.compare / ".venv" / "bin" / "python"
        checkouts["compare"] = (args.compare, str(python if python.exists() else sys.executable))
    results: dict[str, dict[str, dict[str, float]]] = {name: {} for name in checkouts}
    for index, case in enumerate(args.cases.split(",")):
        order = list(checkouts.items())
        if index % 2:
            order.reverse()
        for name, (checkout, python) in order:
            results[name][case] = measure(case, checkout, python, args.seconds)
    for name, cases in results.items():
        base = cases.get("baseline", {}).get("rate") or 1
        for case, figures in cases.items():
            figures["ratio"] = round(figures["rate"] / base, 3)
            print(f"{name:8} {case:11} {json.dumps(figures)}", flush=True)
    print(json.dumps(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
