#!/usr/bin/env python3
"""What ``tmcl proxy`` adds to each request: its latency beside a host talking to the module
directly, in the same run (goal: the proxy's own p50 under 100 us on loopback).

One module (``tmcl-server`` on a free loopback port, its own process) and one ``tmcl proxy``
in front of it (its own process, capturing to a file, and once without ``--capture``); a
lockstep host (9-byte GAP 1 requests, each waiting for its reply) measures round trips
straight to the module and through the proxy, alternating in blocks so the machine's noise
falls on both alike.  The proxy's own latency is the difference of the medians (p50), and of
the 90th percentiles.  Two bare forwarders of a dozen lines each show the floor any proxy in
Python pays for the extra hop on this machine: one blocking (recv, send, recv, send), one on a
``selectors`` loop as ``tmcl proxy`` is (it must serve several hosts and time replies out).

    .venv/bin/python scripts/bench_proxy.py [--seconds 0.3] [--rounds 5]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_wire import lockstep_tcp  # the lockstep host: GAP 1 requests, each awaiting its reply
from local_server import wait_for_ready

#: The floors: forwarders that do nothing else (one host; argv: module port, ready file).
_LISTEN = r"""
import json, os, selectors, socket, sys
module = socket.create_connection(("127.0.0.1", int(sys.argv[1])))
module.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
server = socket.socket(); server.bind(("127.0.0.1", 0)); server.listen()
with open(sys.argv[2] + ".tmp", "w") as f:
    json.dump({"tcp": ["127.0.0.1:%d" % server.getsockname()[1]]}, f)
os.replace(sys.argv[2] + ".tmp", sys.argv[2])
"""
BLOCKING_FORWARDER = _LISTEN + r"""
while True:
    host, _ = server.accept(); host.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    while data := host.recv(9):
        module.sendall(data); host.sendall(module.recv(9))
"""
LOOP_FORWARDER = _LISTEN + r"""
module.setblocking(False); server.setblocking(False)
loop = selectors.DefaultSelector(); hosts = []
def accept():
    host, _ = server.accept(); host.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    host.setblocking(False); hosts.append(host)
    loop.register(host, selectors.EVENT_READ, lambda: module.send(host.recv(4096)))
loop.register(server, selectors.EVENT_READ, accept)
loop.register(module, selectors.EVENT_READ, lambda: hosts[-1].send(module.recv(4096)))
while True:
    for key, _ in loop.select(5.0):
        key.data()
"""


def start(argv: list[str], ready: Path) -> subprocess.Popen[str]:
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        wait_for_ready(proc, ready, what=" ".join(argv), details=lambda: proc.communicate()[1])
    except RuntimeError as exc:
        raise SystemExit(str(exc)) from None
    return proc


def endpoint(ready: Path) -> tuple[str, int]:
    host, port = json.loads(ready.read_text())["tcp"][0].rsplit(":", 1)
    return host, int(port)


def percentile(values: list[float], q: float) -> float:
    return statistics.quantiles(values, n=100)[int(q) - 1] if len(values) > 1 else values[0]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=0.3, help="seconds per block")
    parser.add_argument("--rounds", type=int, default=5, help="blocks per case, alternating")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        tmp = Path(folder)
        module = start([sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0",
                        "--ready-file", str(tmp / "module.json")], tmp / "module.json")
        module_at = endpoint(tmp / "module.json")
        target = f"{module_at[0]}:{module_at[1]}"
        proxies = []
        try:
            cases: dict[str, tuple[str, int]] = {"direct": module_at}
            tool = [sys.executable, "-m", "tmcl_server.tool", "--tcp", target, "proxy",
                    "--listen-tcp", "127.0.0.1:0", "--ready-file"]
            for name, argv in (
                    ("proxy", [*tool, "{ready}", "--capture", str(tmp / "capture.jsonl")]),
                    ("proxy, no capture", [*tool, "{ready}"]),
                    ("floor: blocking", [sys.executable, "-c", BLOCKING_FORWARDER,
                                         str(module_at[1]), "{ready}"]),
                    ("floor: selectors", [sys.executable, "-c", LOOP_FORWARDER,
                                          str(module_at[1]), "{ready}"])):
                ready = tmp / f"proxy-{len(proxies)}.json"
                proxies.append(start([a.replace("{ready}", str(ready)) for a in argv], ready))
                cases[name] = endpoint(ready)
            samples: dict[str, list[float]] = {name: [] for name in cases}
            counts: list[int] = []
            for _ in range(args.rounds):
                for name, address in cases.items():
                    latencies: list[int] = []
                    lockstep_tcp(f"{address[0]}:{address[1]}", args.seconds, latencies, counts)
                    samples[name] += [ns / 1e9 for ns in latencies[50:]]  # the first warm up
        finally:
            for proc in [*proxies, module]:
                proc.terminate()
                proc.wait(timeout=30)
    direct50, direct90 = percentile(samples["direct"], 50), percentile(samples["direct"], 90)
    print(f"{args.rounds} blocks of {args.seconds:g} s of GAP round trips per case, alternating "
          f"({sum(counts)} in all); loopback TCP")
    print(f"{'case':<20} {'p50 us':>8} {'p90 us':>8} {'added p50 us':>13} {'added p90 us':>13}")
    for name, values in samples.items():
        p50, p90 = percentile(values, 50), percentile(values, 90)
        added = "" if name == "direct" else f"{(p50 - direct50) * 1e6:13.1f} {(p90 - direct90) * 1e6:13.1f}"
        print(f"{name:<20} {p50 * 1e6:8.1f} {p90 * 1e6:8.1f} {added}")
    own = (percentile(samples["proxy"], 50) - direct50) * 1e6
    print(f"the proxy's own latency (p50, capturing): {own:.1f} us (goal < 100 us): "
          f"{'met' if own < 100 else 'NOT met'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
