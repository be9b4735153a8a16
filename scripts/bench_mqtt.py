#!/usr/bin/env python3
"""MQTT bridge throughput: request/reply round trips through a real broker, and telemetry.

Starts a throwaway mosquitto and a simulator (real clock) bridged to it, then measures
* lockstep request/reply round trips per second (JSON and binary GAP) with p50/p99 latency,
* state messages per second received for six axes in continuous motion at --mqtt-rate.
Figures are medians of ``--repeat`` runs.

    .venv/bin/python scripts/bench_mqtt.py [--seconds 2] [--repeat 3] [--rate 100]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

import aiomqtt

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.helpers: the throwaway broker

from tests.helpers.mosquitto import Broker
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request
from tmcl_server.server import ServerConfig

PREFIX = "bench"


def make_client(port: int) -> aiomqtt.Client:
    return aiomqtt.Client("127.0.0.1", port, protocol=aiomqtt.ProtocolVersion.V5,
                          socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)])


async def round_trips(port: int, payload: bytes, seconds: float) -> dict[str, float]:
    async with make_client(port) as client:
        await client.subscribe(f"{PREFIX}/1/reply", qos=1)
        messages = client.messages
        latencies: list[int] = []
        deadline = time.perf_counter() + seconds
        start = time.perf_counter()
        while time.perf_counter() < deadline:
            t0 = time.perf_counter_ns()
            await client.publish(f"{PREFIX}/1/request", payload, qos=1)
            await anext(messages)
            latencies.append(time.perf_counter_ns() - t0)
        elapsed = time.perf_counter() - start
    latencies.sort()
    return {"rate": len(latencies) / elapsed, "p50_ms": latencies[len(latencies) // 2] / 1e6,
            "p99_ms": latencies[int(len(latencies) * 0.99)] / 1e6}


async def telemetry(port: int, seconds: float) -> dict[str, float]:
    async with make_client(port) as client:
        await client.subscribe(f"{PREFIX}/1/state", qos=1)
        for motor in range(6):
            await client.publish(f"{PREFIX}/1/request", json.dumps(
                {"cmd": "ROR", "motor": motor, "value": 10000 + 5000 * motor}), qos=1)
        count = 0
        positions: set[int] = set()
        start = time.perf_counter()
        async with asyncio.timeout(seconds + 5):
            async for message in client.messages:
                count += 1
                positions.add(json.loads(message.payload)["axes"][5]["position"])
                if time.perf_counter() - start >= seconds:
                    break
        elapsed = time.perf_counter() - start
    return {"rate": count / elapsed, "distinct": float(len(positions))}


def median(runs: list[dict[str, float]]) -> dict[str, float]:
    return {k: statistics.median(r[k] for r in runs) for k in runs[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--rate", type=float, default=100.0, help="--mqtt-rate of the simulator")
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        broker = Broker(Path(tmp))
        config = ServerConfig(endpoints={"mqtt": [f"{broker.url}/{PREFIX}"]},
                              mqtt_rate=args.rate)
        sim = SimulatorThread(config).start()
        try:
            json_gap = json.dumps({"cmd": "GAP", "type": 1, "motor": 0}).encode()
            binary_gap = Request(1, 6, 1, 0, 0).encode()
            rows = {
                "JSON request/reply": median([asyncio.run(round_trips(
                    broker.port, json_gap, args.seconds)) for _ in range(args.repeat)]),
                "binary request/reply": median([asyncio.run(round_trips(
                    broker.port, binary_gap, args.seconds)) for _ in range(args.repeat)]),
            }
            tele = median([asyncio.run(telemetry(broker.port, args.seconds))
                           for _ in range(args.repeat)])
        finally:
            sim.stop()
            broker.stop()

    print(f"median of {args.repeat} runs of {args.seconds:g} s, broker: mosquitto on loopback")
    for label, r in rows.items():
        print(f"{label:22} {r['rate']:8.0f} round trips/s   p50 {r['p50_ms']:.2f} ms"
              f"   p99 {r['p99_ms']:.2f} ms")
    print(f"{'telemetry, 6 axes':22} {tele['rate']:8.1f} state messages/s at --mqtt-rate "
          f"{args.rate:g} ({tele['distinct']:.0f} distinct positions of axis 5 per run)")


if __name__ == "__main__":
    main()
