#!/usr/bin/env python3
"""Request/reply rate and latency over the CAN gateways: socketcand and the SLCAN pty.

Starts ``tmcl-server`` (real clock) in a subprocess with both gateways, then drives it from
this process:

* lockstep with python-can (``socketcand`` and ``slcan`` interfaces): one request, wait for
  its reply, repeat - what pytrinamic and most host code do;
* pipelined by hand (raw socketcand elements, raw Lawicel lines) with a window of requests
  in flight - what the gateways and the modules can carry, without python-can's own cost;
* python-can's slcan client against a stand-in adapter that does no work (a Python loop that
  answers each line at once): the ceiling of that client on this machine, since it reads the
  port one byte at a time.  The simulator's slcan rate is printed as a share of it.

Goal: a 1 Mbit/s CAN bus carries about 4,500 TMCL round trips per second (two 8-byte frames
of ~111 bits each); the simulator should keep up with that.  Loopback only; bounded counts.

    .venv/bin/python scripts/bench_can.py [--count 5000] [--window 16] [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import select
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

import can
from local_server import wait_for_ready

from tmcl_server.protocol import Request
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

GOAL_PER_S = 4_500
MODULE_ID = 3
REPLY_ID = 2
REQUEST_DATA = Request(MODULE_ID, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0).encode_can() + b"\x00"
TIME_LIMIT_S = 60.0  # per scenario, whatever --count says
#: Untimed round trips first: the socketcand server holds a new raw client's first frames
#: for 20 ms (docs/can.md), which is a connection cost, not a round-trip cost.
WARM_UP = 20


def summarize(name: str, latencies_ns: list[int], elapsed_s: float) -> dict[str, float | str]:
    micros = sorted(ns / 1000 for ns in latencies_ns)
    rate = len(micros) / elapsed_s
    return {"scenario": name, "round_trips": len(micros), "per_s": round(rate),
            "p50_us": round(statistics.median(micros), 1),
            "p99_us": round(micros[min(len(micros) - 1, int(len(micros) * 0.99))], 1),
            "max_us": round(micros[-1], 1), "meets_goal": rate >= GOAL_PER_S}


def lockstep(name: str, bus: can.BusABC, count: int) -> dict[str, float | str]:
    message = can.Message(arbitration_id=MODULE_ID, is_extended_id=False, data=REQUEST_DATA)
    latencies = []
    start = time.perf_counter()
    for i in range(-WARM_UP, count):
        if i == 0:
            latencies.clear()
            start = time.perf_counter()
        sent = time.perf_counter_ns()
        bus.send(message)
        while True:
            reply = bus.recv(5.0)
            if reply is None:
                raise RuntimeError(f"{name}: no reply")
            if reply.arbitration_id == REPLY_ID:
                break
        latencies.append(time.perf_counter_ns() - sent)
        if time.perf_counter() - start > TIME_LIMIT_S:
            break
    return summarize(name, latencies, time.perf_counter() - start)


def pipelined(name: str, send: Callable[[], None], read_replies: Callable[[], int],
              count: int, window: int) -> dict[str, float | str]:
    """Keep ``window`` requests in flight; replies come back in order (one module, FIFO)."""
    in_flight: deque[int] = deque()
    latencies: list[int] = []
    for _ in range(WARM_UP):
        send()
        warm = 0
        while not warm:
            warm = read_replies()
    start = time.perf_counter()
    while len(latencies) < count and time.perf_counter() - start < TIME_LIMIT_S:
        while len(in_flight) < window and len(latencies) + len(in_flight) < count:
            in_flight.append(time.perf_counter_ns())
            send()
        for _ in range(read_replies()):
            latencies.append(time.perf_counter_ns() - in_flight.popleft())
    return summarize(name, latencies, time.perf_counter() - start)


class RawSocketcand:
    def __init__(self, address: str, channel: str = "can0") -> None:
        host, port = address.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=5)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buffer = b""
        self._expect(b"< hi >")
        self.sock.sendall(f"< open {channel} >".encode())
        self._expect(b"< ok >")
        self.sock.sendall(b"< rawmode >")
        self._expect(b"< ok >")
        data = " ".join(f"{b:X}" for b in REQUEST_DATA)
        self.request = f"< send {MODULE_ID:03X} {len(REQUEST_DATA)} {data} >".encode()

    def _expect(self, element: bytes) -> None:
        while element not in self.buffer:
            self.buffer += self.sock.recv(4096)
        self.buffer = self.buffer.split(element, 1)[1]

    def send(self) -> None:
        self.sock.sendall(self.request)

    def read_replies(self) -> int:
        self.buffer += self.sock.recv(65536)
        *elements, self.buffer = self.buffer.split(b">")
        return sum(1 for e in elements if e.strip().startswith(b"< frame %03X" % REPLY_ID))


class RawSlcan:
    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY)
        self.buffer = b""
        os.write(self.fd, b"C\rS8\rO\r")
        self.request = f"t{MODULE_ID:03X}{len(REQUEST_DATA)}{REQUEST_DATA.hex().upper()}\r".encode()

    def send(self) -> None:
        os.write(self.fd, self.request)

    def read_replies(self) -> int:
        select.select([self.fd], [], [], 5.0)
        self.buffer += os.read(self.fd, 65536)
        *lines, self.buffer = self.buffer.split(b"\r")
        return sum(1 for line in lines if line.startswith(b"t%03X" % REPLY_ID))

    def close(self) -> None:
        os.write(self.fd, b"C\r")
        os.close(self.fd)


#: A stand-in SLCAN adapter that does no work: it answers every frame line at once with the
#: transmit acknowledgement and one fixed reply line (the bytes the simulator sends), as fast
#: as a Python loop on a pty can.  python-can's lockstep rate
#: against it is the ceiling of that client on this machine (it reads the port a byte at a
#: time), measured beside the simulator's in the same run.
INSTANT_ADAPTER = r"""
import os, pty, sys, tty
master, slave = pty.openpty()
tty.setraw(slave)
print(os.ttyname(slave), flush=True)
reply = b"z\rt%03X7" % int(sys.argv[1]) + b"02640600000000\r"
buffer = b""
while True:
    data = os.read(master, 4096)
    if not data:
        break
    buffer += data
    *lines, buffer = buffer.split(b"\r")
    out = b"".join(reply if line[:1] == b"t" else b"\r" for line in lines)
    if out:
        os.write(master, out)
"""


def instant_adapter() -> tuple[subprocess.Popen[str], str]:
    process = subprocess.Popen([sys.executable, "-c", INSTANT_ADAPTER, str(REPLY_ID)],
                               stdout=subprocess.PIPE, text=True)
    assert process.stdout is not None
    return process, process.stdout.readline().strip()


def start_server(workdir: Path) -> tuple[subprocess.Popen[bytes], dict[str, list[str]]]:
    ready = workdir / "ready.json"
    process = subprocess.Popen(
        [sys.executable, "-m", "tmcl_server", "--modules", "5", "--no-tcp",
         "--socketcand", "127.0.0.1:0", "--slcan-pty", str(workdir / "ttySLCAN"),
         "--ready-file", str(ready)], stdout=subprocess.DEVNULL)
    return process, wait_for_ready(process, ready, poll_s=0.05)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=5000, help="round trips per scenario")
    parser.add_argument("--window", type=int, default=16, help="requests in flight when pipelined")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        process, endpoints = start_server(Path(tmp))
        try:
            address, pty = endpoints["socketcand"][0], endpoints["slcan"][0]
            host, port = address.rsplit(":", 1)
            with can.Bus(interface="socketcand", host=host, port=int(port), channel="can0",
                         tcp_tune=True) as bus:
                results.append(lockstep("socketcand, python-can, lockstep", bus, args.count))
            with can.Bus(interface="slcan", channel=pty, bitrate=1_000_000,
                         sleep_after_open=0) as bus:
                results.append(lockstep("slcan pty, python-can, lockstep", bus, args.count))
            adapter, adapter_pty = instant_adapter()
            try:
                with can.Bus(interface="slcan", channel=adapter_pty, bitrate=1_000_000,
                             sleep_after_open=0) as bus:
                    results.append(lockstep("slcan pty, python-can, instant adapter", bus,
                                            args.count))
            finally:
                adapter.kill()
                adapter.wait()
            raw = RawSocketcand(address)
            results.append(pipelined(f"socketcand, raw, window {args.window}", raw.send,
                                     raw.read_replies, args.count, args.window))
            raw.sock.close()
            slcan = RawSlcan(pty)
            # lockstep with whole-buffer reads: the adapter's own latency, without python-can's
            # byte-at-a-time reading of the port
            results.append(pipelined("slcan pty, raw, lockstep", slcan.send, slcan.read_replies,
                                     args.count, 1))
            results.append(pipelined(f"slcan pty, raw, window {args.window}", slcan.send,
                                     slcan.read_replies, args.count, args.window))
            slcan.close()
        finally:
            process.send_signal(signal.SIGTERM)
            process.wait(10)
    if args.json:
        print(json.dumps(results, indent=2))
    else:
        print(f"{'scenario':40} {'round trips':>11} {'per s':>8} {'p50 us':>8} {'p99 us':>8} "
              f"{'max us':>8}  goal {GOAL_PER_S}/s")
        for r in results:
            print(f"{r['scenario']:40} {r['round_trips']:>11} {r['per_s']:>8} {r['p50_us']:>8} "
                  f"{r['p99_us']:>8} {r['max_us']:>8}  {'ok' if r['meets_goal'] else 'BELOW'}")
        by_name = {r["scenario"]: r["per_s"] for r in results}
        ceiling = by_name["slcan pty, python-can, instant adapter"]
        print(f"slcan with python-can, lockstep: {by_name['slcan pty, python-can, lockstep'] / ceiling:.0%} "
              "of the same client against an adapter that does no work (its ceiling here)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
