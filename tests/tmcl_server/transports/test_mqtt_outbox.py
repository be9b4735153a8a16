"""The MQTT bridge's outbox is bounded (issue 27, item 3): events beyond the bound are dropped
and counted on ``PREFIX/dropped``, retained messages keep their latest value, replies keep
their own room; a program's 1 ms timer with the bridge on neither grows the server nor slows
its hosts (the 10-minute soak is scripts/soak_mqtt.py)."""

from __future__ import annotations

import asyncio
import json
import time
import uuid

import pytest

from interpreter.assembler import assemble
from tests.conftest import RawClient
from tests.helpers.mosquitto import MOSQUITTO, Broker
from tests.tmcl_server.transports.test_mqtt import _session_expiry, json_of, probe_client, probing, start_sim
from tmcl_server.embed import SimulatorThread
from tmcl_server.server import ServerConfig
from tmcl_server.transports.mqtt.bridge import MqttBridge, Outbox, _Outgoing
from tmcl_server.upload import StreamClient, upload
from tmcl_spec.commands import Opcode

pytestmark = pytest.mark.skipif(MOSQUITTO is None, reason="mosquitto is not installed")

#: One ``interrupt_taken`` event per millisecond.
TIMER_PROGRAM = """
#include Interrupts.inc
    VECT TI_TIMER0, Tick
    SGP TI_TIMER0, 3, 1
    EI TI_TIMER0
    EI TI_GLOBAL
Loop:
    WAIT TICKS, 0, 10
    JA Loop
Tick:
    GGP 7, 2
    CALC ADD, 1
    AGP 7, 2
    RETI
"""


def message(topic: str, n: int = 0, retain: bool = False) -> _Outgoing:
    return _Outgoing(topic, str(n).encode(), retain=retain)


def test_the_outbox_bounds_events_and_replies_apart_and_keeps_the_latest_retained() -> None:
    outbox = Outbox(limit=3)
    assert [outbox.event(message("e", n)) for n in range(5)] == [True] * 3 + [False] * 2
    assert all(outbox.reply(message("r", n)) for n in range(3))  # replies have their own room
    assert not outbox.reply(message("r", 3))
    for n in range(4):
        outbox.retained(message("faults", n, retain=True))
    assert outbox.dropped == {"events": 2, "replies": 1, "requests": 0}
    assert len(outbox) == 3 + 3 + 1 and outbox.latest["faults"].payload == b"3"
    picked = outbox.batch(size=16)
    assert [(kind, m.payload) for kind, m in picked] == [
        ("replies", b"0"), ("replies", b"1"), ("replies", b"2"), ("latest", b"3"),
        ("events", b"0"), ("events", b"1"), ("events", b"2")]
    outbox.retained(message("faults", 9, retain=True))  # replaced while in flight: kept
    outbox.sent(picked)
    assert len(outbox) == 1 and outbox.latest["faults"].payload == b"9"


def run_timer_program(sim: SimulatorThread) -> None:
    client = StreamClient.tcp(sim.tcp, 1, 5.0)
    try:
        upload(client, assemble(TIMER_PROGRAM).instructions, run=True)
    finally:
        client.close()


def test_while_the_broker_is_away_events_beyond_the_bound_are_dropped_and_counted(broker: Broker) -> None:
    sim = start_sim(broker)
    limit = 1000
    session = f"probe-{uuid.uuid4().hex[:8]}"
    bridge = next(t for t in sim.server.transports if isinstance(t, MqttBridge))  # type: ignore[union-attr]

    async def subscribe_persistently() -> None:
        async with probe_client(broker, identifier=session, clean_start=False,
                                properties=_session_expiry()) as client:
            await client.subscribe("rig/tmcl/1/event", qos=1)

    async def after_restart() -> tuple[dict[str, int], int]:
        async with probing(broker, identifier=session, clean_start=False,
                           properties=_session_expiry()) as probe:
            await probe.client.subscribe("rig/tmcl/dropped", qos=1)
            dropped = await probe.wait(lambda m: m.topic.value == "rig/tmcl/dropped"
                                       and json_of(m)["events"] > 0, timeout=15)
            deadline = time.monotonic() + 15
            while len(probe.on("rig/tmcl/1/event")) < limit and time.monotonic() < deadline:
                await asyncio.sleep(0.05)
            return json_of(dropped), len(probe.on("rig/tmcl/1/event"))

    try:
        asyncio.run(subscribe_persistently())
        # a bound of 1,000 (MAX_QUEUED is ten times that): what a persistent session in the
        # test broker keeps for a client while it is away (mosquitto's max_queued_messages)
        sim.call(lambda: setattr(bridge.outbox, "limit", limit))
        broker.stop()
        run_timer_program(sim)
        sim.advance(3.0)  # 3,000 timer interrupts, each an event the bridge owes
        queued = sim.call(lambda: len(bridge.outbox.events))
        dropped_now = sim.call(lambda: dict(bridge.outbox.dropped))
        assert queued == limit
        assert dropped_now["events"] >= 3000 - limit - 20 and dropped_now["replies"] == 0
        tcp = RawClient(sim.tcp)  # the module answers throughout
        assert tcp.request(1, Opcode.GAP, 4, 0).value == 51200
        tcp.close()
        broker.start()
        counts, delivered = asyncio.run(after_restart())
        assert counts == {"events": dropped_now["events"], "replies": 0, "requests": 0}
        assert delivered == limit  # the ones kept, none lost beyond those counted
    finally:
        sim.stop()


def test_a_1ms_timer_with_the_bridge_on_stays_bounded_and_the_host_is_served(broker: Broker) -> None:
    """The short soak: a real clock, a 1 ms timer interrupt, a slow broker (stopped and
    started), a TCP host polling; the outbox never exceeds its bound."""
    config = ServerConfig(clock="real", endpoints={"tcp": ["127.0.0.1:0"],
                                                   "mqtt": [f"{broker.url}/rig/tmcl"]})
    with SimulatorThread(config) as sim:
        bridge = next(t for t in sim.server.transports if isinstance(t, MqttBridge))  # type: ignore[union-attr]
        limit = 500  # a smaller bound, so that 2 s away fill it
        sim.call(lambda: setattr(bridge.outbox, "limit", limit))
        run_timer_program(sim)
        host = RawClient(sim.tcp)
        latencies: list[float] = []
        peak = 0
        try:
            for phase in ("connected", "away", "back"):
                if phase == "away":
                    broker.stop()
                elif phase == "back":
                    broker.start()
                end = time.monotonic() + 2.0
                while time.monotonic() < end:
                    began = time.perf_counter()
                    assert host.request(1, Opcode.GGP, 7, 2).status == 100
                    latencies.append(time.perf_counter() - began)
                    peak = max(peak, sim.call(lambda: len(bridge.outbox)))
        finally:
            host.close()
        dropped = sim.call(lambda: dict(bridge.outbox.dropped))
    assert peak <= 2 * limit + 8
    assert dropped["events"] > 0  # 2 s away: about 2,000 events, most of them beyond the bound
    latencies.sort()
    assert latencies[len(latencies) // 2] < 0.01
    assert json.dumps(dropped)
