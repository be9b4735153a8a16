#!/usr/bin/env python3
"""Soak: a TMCL program with a 1 ms timer interrupt (about 1,000 module events a second) and
the MQTT bridge on, while a TCP host polls; does request latency stay flat, does the server's
memory stay bounded?  (Issue 27, item 3: the bridge's outbox used to grow by 10-12 MB a
minute and the longest request stall with it, from 60 ms to 650-790 ms in ten minutes.)

Starts a throwaway mosquitto and ``tmcl-server --tcp ... --mqtt ...`` as a process, downloads
and runs the program, then a host sends GAP every ``--poll-ms`` and a subscriber counts what
the broker delivers.  Prints one line per ``--period`` seconds (requests, p50/p99/max
latency, server RSS, events received, the bridge's ``dropped`` counter) and a JSON summary.
``--compare DIR`` runs a second server from another checkout (e.g. the code before the fix)
at the same time against its own broker, so both see the same machine load.

    .venv/bin/python scripts/soak_mqtt.py                          # 10 minutes
    .venv/bin/python scripts/soak_mqtt.py --minutes 1 --compare /work/main
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import aiomqtt

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.helpers: the throwaway broker

from local_server import UploadError, rss_kb, tcp_host, wait_for_ready  # noqa: E402

from interpreter.assembler import assemble  # noqa: E402
from tests.helpers.mosquitto import Broker  # noqa: E402
from tmcl_server.protocol import Request, decode_reply  # noqa: E402
from tmcl_server.upload import StreamClient, upload  # noqa: E402
from tmcl_spec.commands import Opcode  # noqa: E402

PREFIX = "soak"

#: A counter in a user variable, bumped by a 1 ms timer interrupt: each tick is one
#: ``interrupt_taken`` event for every listener (MQTT publishes each).  ``--timers 3`` uses
#: all three timers and ``--toggle`` flips an output in each handler (an ``output_changed``
#: event more): up to 6,000 events a second, more than a broker on a quiet machine takes.
PROGRAM = """
#include Interrupts.inc
{setup}
    EI TI_GLOBAL
Loop:
    WAIT TICKS, 0, 10
    JA Loop
{handlers}
"""
SETUP = """
    VECT TI_TIMER{n}, Tick{n}
    SGP TI_TIMER{n}, 3, {period}
    EI TI_TIMER{n}
"""
HANDLER = """
Tick{n}:
    GGP {n}, 2
    CALC ADD, 1
    AGP {n}, 2
{toggle}
    RETI
"""
TOGGLE = """
    CALC AND, 1
    ACO 0, 0
    SIO {n}, 2, 0
"""


def program(timers: int, period_ms: int, toggle: bool) -> str:
    setup = "".join(SETUP.format(n=n, period=period_ms) for n in range(timers))
    handlers = "".join(HANDLER.format(n=n, toggle=TOGGLE.format(n=n) if toggle else "")
                       for n in range(timers))
    return PROGRAM.format(setup=setup, handlers=handlers)


class Server:
    """One tmcl-server process from a checkout, bridged to its own broker."""

    def __init__(self, name: str, checkout: Path, python: str, workdir: Path, source: str) -> None:
        self.name = name
        directory = workdir / name
        directory.mkdir()
        self.broker = Broker(directory)
        ready = directory / "ready.json"
        self.stderr_path = directory / "stderr.log"
        self.proc = subprocess.Popen(
            [python, "-m", "tmcl_server", "--tcp", "127.0.0.1:0",
             "--mqtt", f"{self.broker.url}/{PREFIX}", "--ready-file", str(ready)],
            cwd=checkout, stdout=subprocess.DEVNULL, stderr=open(self.stderr_path, "wb"),  # noqa: SIM115
            env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})  # leave another checkout as it is
        self.tcp = wait_for_ready(self.proc, ready, what=f"{name}: server", poll_s=0.05,
                                  details=self.stderr_path.read_text)["tcp"][0]
        client = StreamClient.tcp(self.tcp, 1, 5.0)
        try:
            upload(client, assemble(source).instructions, run=True)
        finally:
            client.close()
        self.latencies: list[float] = []
        self.events = 0
        self.dropped: dict[str, int] | None = None
        self.failures = 0
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._poll, daemon=True),
                         threading.Thread(target=self._count, daemon=True)]
        self._counter: subprocess.Popen[str] | None = None

    def start(self, poll_s: float) -> None:
        self.poll_s = poll_s
        for thread in self._threads:
            thread.start()

    def _poll(self) -> None:
        host = tcp_host(self.tcp)
        frame = Request(1, Opcode.GGP, 7, 2, 0).encode()
        while not self._stop.is_set():
            began = time.perf_counter()
            try:
                decode_reply(host.exchange(frame))
            except (OSError, UploadError):  # UploadError: the server closed the connection
                self.failures += 1
                time.sleep(0.1)
                continue
            self.latencies.append(time.perf_counter() - began)
            time.sleep(self.poll_s)
        host.close()

    def _count(self) -> None:
        """What the broker delivers, counted by a subscriber in a process of its own (in this
        one it would take the GIL from the polling host and spoil its latencies)."""
        self._counter = subprocess.Popen([sys.executable, __file__, "--count-events",
                                          str(self.broker.port)],
                                         stdout=subprocess.PIPE, text=True)
        assert self._counter.stdout is not None
        for line in self._counter.stdout:
            events, dropped = json.loads(line)
            self.events += events
            if dropped is not None:
                self.dropped = dropped

    def rss_kb(self) -> int:
        return rss_kb(self.proc.pid)

    def take(self) -> tuple[list[float], int]:
        latencies, self.latencies = self.latencies, []
        events, self.events = self.events, 0
        return latencies, events

    def stop(self) -> None:
        self._stop.set()
        if self._counter is not None:
            self._counter.terminate()
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
        self.broker.stop()


def figures(latencies: list[float]) -> dict[str, float]:
    if not latencies:
        return {"requests": 0, "p50_ms": 0.0, "p99_ms": 0.0, "max_ms": 0.0}
    ordered = sorted(latencies)
    return {"requests": len(ordered), "p50_ms": round(statistics.median(ordered) * 1e3, 2),
            "p99_ms": round(ordered[int(len(ordered) * 0.99)] * 1e3, 2),
            "max_ms": round(ordered[-1] * 1e3, 1)}


async def count_events(port: int) -> None:
    """``--count-events PORT``: print [events, dropped] once a second."""
    events, dropped, last = 0, None, time.monotonic()
    try:
        async with aiomqtt.Client("127.0.0.1", port, protocol=aiomqtt.ProtocolVersion.V5) as client:
            await client.subscribe(f"{PREFIX}/1/event", qos=0)
            await client.subscribe(f"{PREFIX}/dropped", qos=0)
            async for message in client.messages:
                if message.topic.value.endswith("/dropped"):
                    dropped = json.loads(message.payload)  # type: ignore[arg-type]
                else:
                    events += 1
                if time.monotonic() - last >= 1.0:
                    print(json.dumps([events, dropped]), flush=True)
                    events, last = 0, time.monotonic()
    except aiomqtt.MqttError:  # the broker stopped at the end
        pass


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--period", type=float, default=60.0, metavar="S",
                        help="seconds per report line (default 60)")
    parser.add_argument("--timer-ms", type=int, default=1, help="the timer interrupt's period")
    parser.add_argument("--timers", type=int, choices=(1, 2, 3), default=1,
                        help="timer interrupts running at once (default 1)")
    parser.add_argument("--toggle", action="store_true",
                        help="each handler also flips an output (one event more per tick)")
    parser.add_argument("--poll-ms", type=float, default=5.0, help="pause between two requests")
    parser.add_argument("--compare", metavar="DIR", type=Path,
                        help="also run the server of this checkout (its .venv), side by side")
    parser.add_argument("--count-events", type=int, metavar="PORT", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.count_events:
        asyncio.run(count_events(args.count_events))
        return 0
    rows: dict[str, list[dict[str, Any]]] = {}
    with tempfile.TemporaryDirectory(prefix="soak-mqtt-") as tmp:
        source = program(args.timers, args.timer_ms, args.toggle)
        servers = [Server("this", ROOT, sys.executable, Path(tmp), source)]
        if args.compare is not None:
            python = args.compare / ".venv" / "bin" / "python"
            servers.append(Server("compare", args.compare,
                                  str(python if python.exists() else sys.executable),
                                  Path(tmp), source))
        try:
            for server in servers:
                server.start(args.poll_ms / 1000)
                rows[server.name] = []
            began = time.monotonic()
            end = began + args.minutes * 60
            while time.monotonic() < end:
                time.sleep(max(0.0, min(args.period, end - time.monotonic())))
                for server in servers:
                    latencies, events = server.take()
                    row = {"t_s": round(time.monotonic() - began), **figures(latencies),
                           "rss_kb": server.rss_kb(), "events_per_s": round(events / args.period),
                           "dropped": server.dropped, "failures": server.failures}
                    rows[server.name].append(row)
                    print(f"{server.name:8} {json.dumps(row)}", flush=True)
        finally:
            for server in servers:
                server.stop()
    summary = {}
    for name, series in rows.items():
        if series:
            summary[name] = {"first": series[0], "last": series[-1],
                             "rss_growth_kb": series[-1]["rss_kb"] - series[0]["rss_kb"],
                             "max_ms_first": series[0]["max_ms"], "max_ms_last": series[-1]["max_ms"]}
    print(json.dumps(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
