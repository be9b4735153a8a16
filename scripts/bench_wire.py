#!/usr/bin/env python3
"""Lockstep request/reply rate and latency of the simulator's wire, next to a bare echo server.

Runs, in one go and on the same machine:
* a bare asyncio server that only echoes 9-byte frames (the ceiling of Python on loopback),
* ``tmcl-server`` (TCP and a pty), each in its own process,
* ``tmcl-server --trace FILE`` (text, and ``--trace-format jsonl``): the same with the
  telegram trace on, writing two lines per request to a file,
* ``tmcl-server --http`` with a page open on the dashboard (``--page chromium``: a headless
  Chromium showing the page; ``--page ws``: a WebSocket client that acknowledges every frame
  at once, with the Parameters section open, so the server does its most work; ``--page
  none``: no dashboard case),
and measures, for 1 and 16 lockstep TCP clients and for one pty client, requests per second
and p50/p99 round-trip latency.  Every figure is the median of ``--repeat`` runs.  The traced
rates and the rate with a dashboard page are reported as a ratio to the plain one measured in
the same run (goal >= 80%).

Then, with ``--wire-timing`` (docs/faults.md), the GAP round trip on a pty at 9600 and at
115200 baud next to the figure the line model computes (goals: within 10 % and 20 %);
``--wire-only`` measures just that.

    .venv/bin/python scripts/bench_wire.py [--seconds 2] [--repeat 3] [--page chromium|ws|none]
"""

from __future__ import annotations

import argparse
import asyncio
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import serial
from local_server import tcp_host, wait_for_ready

REQUEST = bytes([1, 6, 1, 0, 0, 0, 0, 0, 8])  # GAP 1, 0: the actual position, the usual poll

ECHO_SERVER = r"""
import asyncio, sys
class Echo(asyncio.Protocol):
    def connection_made(self, t):
        self.t = t
        import socket
        t.get_extra_info("socket").setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = b""
    def data_received(self, data):
        self.buf += data
        while len(self.buf) >= 9:
            self.t.write(self.buf[:9]); self.buf = self.buf[9:]
async def main():
    server = await asyncio.get_running_loop().create_server(Echo, "127.0.0.1", 0)
    print(server.sockets[0].getsockname()[1], flush=True)
    await server.serve_forever()
asyncio.run(main())
"""


def lockstep_tcp(endpoint: str, seconds: float, latencies: list[int], counts: list[int]) -> None:
    host = tcp_host(endpoint, timeout=None)
    local: list[int] = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        t0 = time.perf_counter_ns()
        host.exchange(REQUEST)
        local.append(time.perf_counter_ns() - t0)
    host.close()
    latencies.extend(local)
    counts.append(len(local))


def lockstep_pty(path: str, seconds: float, latencies: list[int], counts: list[int]) -> None:
    port = serial.Serial(path, 115200, timeout=2)
    local: list[int] = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        t0 = time.perf_counter_ns()
        port.write(REQUEST)
        if len(port.read(9)) != 9:
            raise RuntimeError("pty reply timed out")
        local.append(time.perf_counter_ns() - t0)
    port.close()
    latencies.extend(local)
    counts.append(len(local))


def lockstep_pytrinamic(endpoint: str, seconds: float, latencies: list[int],
                        counts: list[int]) -> None:
    """The same lockstep loop through pytrinamic's socket_serial_tmcl, as users drive it.

    Against the echo server the request is chosen so that its echo parses as a valid reply
    (the type byte lands in the status field: type 100 reads as status 100).
    """
    from pytrinamic.connections.socket_tmcl_interface import SocketTmclInterface

    iface = SocketTmclInterface(endpoint)
    echo = endpoint == ECHO_ENDPOINT[0]
    local: list[int] = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline:
        t0 = time.perf_counter_ns()
        if echo:
            iface.send(6, 100, 0, 0)
        else:
            iface.get_axis_parameter(1, 0)
        local.append(time.perf_counter_ns() - t0)
    iface.close()
    latencies.extend(local)
    counts.append(len(local))


ECHO_ENDPOINT: list[str] = [""]


def cpu_seconds(pid: int | None) -> float:
    """CPU time (user + system) a process has used so far (Linux; 0 elsewhere)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, TypeError):
        return 0.0


def measure(target, endpoint: str, clients: int, seconds: float,
            pid: int | None = None) -> dict[str, float]:
    latencies: list[int] = []
    counts: list[int] = []
    threads = [threading.Thread(target=target, args=(endpoint, seconds, latencies, counts))
               for _ in range(clients)]
    cpu_before = cpu_seconds(pid)
    start = time.perf_counter()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.perf_counter() - start
    cpu = cpu_seconds(pid) - cpu_before
    latencies.sort()
    return {
        "rate": sum(counts) / elapsed,
        "p50_us": latencies[len(latencies) // 2] / 1000,
        "p99_us": latencies[int(len(latencies) * 0.99)] / 1000,
        # the server's CPU per request: steadier than the rate on a shared machine
        "cpu_us": cpu / max(1, sum(counts)) * 1e6,
    }


def median_of(runs: list[dict[str, float]]) -> dict[str, float]:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def start_echo() -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-c", ECHO_SERVER], stdout=subprocess.PIPE, text=True)
    port = proc.stdout.readline().strip()
    return proc, f"127.0.0.1:{port}"


def start_simulator(tmp: Path, *extra: str, name: str = "plain"
                    ) -> tuple[subprocess.Popen, dict[str, list[str]]]:
    ready = tmp / f"ready-{name}.json"
    proc = subprocess.Popen([sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0",
                             "--pty", str(tmp / f"ttyBENCH-{name}"), "--ready-file", str(ready),
                             *extra], stdout=subprocess.DEVNULL)
    return proc, wait_for_ready(proc, ready, seconds=20, what="simulator")


class DashboardPage:
    """A page open on a simulator's dashboard for the whole benchmark (``--page``)."""

    def __init__(self, kind: str, url: str) -> None:
        self.kind = kind
        self.frames = 0
        self._stop = threading.Event()
        self._browser = None
        self._thread: threading.Thread | None = None
        if kind == "chromium":
            sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
            from tests.helpers.browser import HeadlessChromium

            self._browser = HeadlessChromium(1400, 1000)
            self._browser.driver.get(url)
        else:
            self._thread = threading.Thread(target=lambda: asyncio.run(self._acknowledge(url)),
                                            daemon=True)
            self._thread.start()

    async def _acknowledge(self, url: str) -> None:
        import aiohttp

        async with aiohttp.ClientSession() as session, session.ws_connect(f"{url}ws") as ws:
            await ws.receive_json()  # hello
            await ws.send_json({"op": "view", "module": 1, "parameters": True})
            while not self._stop.is_set():
                await ws.receive_str()
                self.frames += 1
                await ws.send_json({"op": "ack"})

    def frame_count(self) -> int:
        if self._browser is not None:
            return int(self._browser.driver.execute_script("return window.tmclDashboard.frames()"))
        return self.frames

    def close(self) -> None:
        self._stop.set()
        if self._browser is not None:
            self._browser.quit()


#: Baud rates of the wire-timing scenario, with the goal for each (measured / computed - 1).
WIRE_CASES = ((9600, 0.10), (115200, 0.20))


def wire_timing(seconds: float, repeat: int) -> None:
    """GAP round trips on paced ptys against the line model's figure (the median of each run,
    the median of the runs)."""
    from tmcl_server.transports.wire import DEFAULT_PROCESSING_S, serial_round_trip_s

    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        links = [f"{tmp}/ttyWIRE{baud},baud={baud}" for baud, _ in WIRE_CASES]
        proc, _ = start_simulator(tmp, "--wire-timing", *(a for link in links for a in ("--pty", link)),
                                  name="wire")
        try:
            medians: dict[int, list[float]] = {baud: [] for baud, _ in WIRE_CASES}
            for _ in range(repeat):
                for (baud, _), link in zip(WIRE_CASES, links, strict=True):
                    latencies: list[int] = []
                    lockstep_pty(link.split(",")[0], seconds, latencies, [])
                    medians[baud].append(statistics.median(latencies) / 1e6)
        finally:
            proc.terminate()
            proc.wait(10)
    print(f"--wire-timing, GAP round trip on a pty (processing {DEFAULT_PROCESSING_S * 1e3:g} ms; "
          f"median of {repeat} runs of {seconds:g} s):")
    for baud, goal in WIRE_CASES:
        computed = serial_round_trip_s(baud) * 1e3
        measured = statistics.median(medians[baud])
        print(f"  {baud:>6} baud: computed {computed:6.3f} ms, measured p50 {measured:6.3f} ms "
              f"({measured / computed - 1:+.1%}; goal within {goal:.0%})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="length of one run")
    parser.add_argument("--repeat", type=int, default=3, help="runs per figure (median)")
    parser.add_argument("--page", choices=["chromium", "ws", "none"], default="chromium",
                        help="what is open on the --http dashboard (default chromium)")
    parser.add_argument("--wire-only", action="store_true",
                        help="only the --wire-timing round trips at 9600 and 115200 baud")
    args = parser.parse_args()
    if args.wire_only:
        wire_timing(args.seconds, args.repeat)
        return

    with tempfile.TemporaryDirectory() as tmpdir:
        echo, echo_endpoint = start_echo()
        ECHO_ENDPOINT[0] = echo_endpoint
        tmp = Path(tmpdir)
        sim, endpoints = start_simulator(tmp)
        traced, traced_endpoints = start_simulator(tmp, "--trace", str(tmp / "trace.txt"),
                                                   name="traced")
        jsonl, jsonl_endpoints = start_simulator(tmp, "--trace", str(tmp / "trace.jsonl"),
                                                 "--trace-format", "jsonl", name="jsonl")
        # the default loop is uvloop where installed (the fast extra); asyncio's for comparison
        plain_loop, plain_endpoints = start_simulator(tmp, "--loop", "asyncio", name="asyncio")
        processes = [echo, sim, traced, jsonl, plain_loop]
        page = None
        if args.page != "none":
            http, http_endpoints = start_simulator(tmp, "--http", "127.0.0.1:0", name="http")
            processes.append(http)
            page = DashboardPage(args.page, http_endpoints["http"][0])
        try:
            cases = (
                ("echo  tcp  1 client ", lockstep_tcp, echo_endpoint, 1),
                ("sim   tcp  1 client ", lockstep_tcp, endpoints["tcp"][0], 1),
                ("asyncio-loop sim tcp", lockstep_tcp, plain_endpoints["tcp"][0], 1),
                ("trace tcp  1 client ", lockstep_tcp, traced_endpoints["tcp"][0], 1),
                ("jsonl tcp  1 client ", lockstep_tcp, jsonl_endpoints["tcp"][0], 1),
                ("echo  tcp 16 clients", lockstep_tcp, echo_endpoint, 16),
                ("sim   tcp 16 clients", lockstep_tcp, endpoints["tcp"][0], 16),
                ("sim   pty  1 client ", lockstep_pty, endpoints["pty"][0], 1),
                ("echo  tcp  pytrinamic", lockstep_pytrinamic, echo_endpoint, 1),
                ("sim   tcp  pytrinamic", lockstep_pytrinamic, endpoints["tcp"][0], 1),
                ("trace tcp  pytrinamic", lockstep_pytrinamic, traced_endpoints["tcp"][0], 1),
            )
            server_pid = {endpoints["tcp"][0]: sim.pid, traced_endpoints["tcp"][0]: traced.pid,
                          jsonl_endpoints["tcp"][0]: jsonl.pid, plain_endpoints["tcp"][0]: plain_loop.pid}
            if page is not None:
                server_pid[http_endpoints["tcp"][0]] = http.pid
                cases += (("http  tcp  1 client ", lockstep_tcp, http_endpoints["tcp"][0], 1),
                          ("http  tcp  pytrinamic", lockstep_pytrinamic, http_endpoints["tcp"][0], 1))
                frames_before, page_began = page.frame_count(), time.perf_counter()
            # Interleave the cases (echo, sim, echo, sim, ...) so that drifting background
            # load hits both sides of every ratio alike.
            runs: dict[str, list[dict[str, float]]] = {label: [] for label, *_ in cases}
            for _ in range(args.repeat):
                for label, target, endpoint, clients in cases:
                    runs[label].append(measure(target, endpoint, clients, args.seconds,
                                               server_pid.get(endpoint)))
            rows = [(label, median_of(r)) for label, r in runs.items()]
            # p50 latency is steadier than the rate on a shared machine: report both
            latency_ratios = [statistics.median(s["p50_us"] / t["p50_us"] for s, t in
                                                zip(runs["sim   tcp  1 client "], runs[label], strict=True))
                              for label in ("trace tcp  1 client ", "jsonl tcp  1 client ")]
            # the server's own cost per lockstep request: its p50 minus the bare echo's
            overheads = [statistics.median(s["p50_us"] - e["p50_us"] for s, e in
                                           zip(runs[label], runs["echo  tcp  1 client "], strict=True))
                         for label in ("sim   tcp  1 client ", "asyncio-loop sim tcp")]
            ratios = [statistics.median(s["rate"] / e["rate"] for s, e in
                                        zip(runs[sim_label], runs[echo_label], strict=True))
                      for sim_label, echo_label in (
                          ("sim   tcp  1 client ", "echo  tcp  1 client "),
                          ("sim   tcp 16 clients", "echo  tcp 16 clients"),
                          ("sim   tcp  pytrinamic", "echo  tcp  pytrinamic"),
                          ("trace tcp  1 client ", "sim   tcp  1 client "),
                          ("jsonl tcp  1 client ", "sim   tcp  1 client "),
                          ("trace tcp  pytrinamic", "sim   tcp  pytrinamic"))]
            if page is not None:
                frame_rate = (page.frame_count() - frames_before) / (time.perf_counter() - page_began)
                page_cpu = [statistics.median(r["cpu_us"] for r in runs[label])
                            for label in ("sim   tcp  1 client ", "http  tcp  1 client ")]
                page_ratios = [statistics.median(h["rate"] / s["rate"] for h, s in
                                                 zip(runs[http_label], runs[sim_label], strict=True))
                               for http_label, sim_label in (
                                   ("http  tcp  1 client ", "sim   tcp  1 client "),
                                   ("http  tcp  pytrinamic", "sim   tcp  pytrinamic"))]
        finally:
            if page is not None:
                page.close()
            for proc in processes:
                proc.terminate()
                proc.wait(10)

    print(f"machine: {os.cpu_count()} CPUs, Python {sys.version.split()[0]}; "
          f"median of {args.repeat} runs of {args.seconds:g} s")
    print(f"{'':22} {'req/s':>9} {'p50 us':>8} {'p99 us':>8} {'server CPU us/req':>18}")
    for label, r in rows:
        cpu = f"{r['cpu_us']:18.1f}" if r["cpu_us"] else ""
        print(f"{label:22} {r['rate']:9.0f} {r['p50_us']:8.1f} {r['p99_us']:8.1f} {cpu}")
    one, many, pytri, text_trace, jsonl_trace, pytrinamic_trace = ratios
    print(f"p50 overhead over the bare asyncio echo (median of paired runs): "
          f"{overheads[0]:+.1f} us on the default loop, {overheads[1]:+.1f} us on asyncio's "
          f"(goal <= 2 us)")
    print(f"ratio sim/echo (median of paired runs): 1 raw client {one:.0%}, 16 raw clients "
          f"{many:.0%}, 1 pytrinamic client {pytri:.0%} (goal: 1 client >= 80%)")
    print(f"ratio traced/untraced, 1 raw client: --trace text {text_trace:.0%}, "
          f"jsonl {jsonl_trace:.0%} (goal >= 80%); by p50 latency: text {latency_ratios[0]:.0%}, "
          f"jsonl {latency_ratios[1]:.0%}; 1 pytrinamic client, --trace text: {pytrinamic_trace:.0%}")
    if page is not None:
        print(f"ratio with a dashboard page open ({args.page}, {frame_rate:.1f} frames/s)/plain: "
              f"1 raw client {page_ratios[0]:.0%}, 1 pytrinamic client {page_ratios[1]:.0%} "
              f"(goal >= 80%); server CPU per request, 1 raw client: {page_cpu[1]:.1f} us "
              f"against {page_cpu[0]:.1f} us")
    wire_timing(args.seconds, args.repeat)


if __name__ == "__main__":
    main()
