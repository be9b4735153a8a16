"""Issue 36, N3, N4, N8: what a broker's other clients can make the bridge do, with a real
mosquitto the test starts: commands that change the module only when allowed, nothing taken
from retained messages, and a flood of requests bounded in memory and in the loop's time."""

from __future__ import annotations

import asyncio
import json

from tests.conftest import RawClient
from tests.helpers.mosquitto import missing_reason
from tests.helpers.requirements import needs
from tests.tmcl_server.transports.test_mqtt import json_of, probing, start_sim
from tmcl_server.protocol import Request, decode_reply
from tmcl_server.transports.mqtt import bridge as bridge_module
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

pytestmark = needs(missing_reason())

def _bridge(sim):
    (bridge,) = [t for t in sim.server.transports if t.kind == "mqtt"]
    return bridge


def test_commands_that_change_the_module_are_refused_unless_allowed(broker):
    """N8: any client of the broker could SAP+STAP, download and run a program, send 137 or
    move the module's address; without --mqtt-commands only reads are served, the rest is
    answered with an error naming the option and changes nothing."""
    sim = start_sim(broker, mqtt_commands=False)
    host = RawClient(sim.tcp)
    try:
        speed = host.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value

        async def scenario() -> None:
            async with probing(broker) as probe:
                await probe.client.subscribe("rig/tmcl/1/reply", qos=1)
                for request in (Request(1, Opcode.SAP, AP.MAX_SPEED, 0, 1234),
                                Request(1, Opcode.SGP, 66, 0, 7),  # the serial address
                                Request(1, 137, 0, 0, 1234)):       # factory reset
                    since = probe.mark()
                    await probe.client.publish("rig/tmcl/1/request", request.encode(), qos=1)
                    answer = json_of(await probe.wait(
                        lambda m: m.topic.value == "rig/tmcl/1/reply", since=since))
                    assert "--mqtt-commands" in answer["error"], answer
                since = probe.mark()
                await probe.client.publish("rig/tmcl/1/request", json.dumps(
                    {"cmd": "GAP", "type": AP.MAX_SPEED, "motor": 0}), qos=1)
                reply = json_of(await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply",
                                                 since=since))
                assert reply["status"] == 100 and reply["value"] == speed

        asyncio.run(scenario())
        assert host.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value == speed  # unchanged
        assert host.request(1, Opcode.GGP, 66, 0).value == 1
        assert sim.call(lambda: _bridge(sim).refused["commands"]) == 3
    finally:
        host.close()
        sim.stop()


def test_retained_commands_are_never_acted_on(broker):
    """N4: a retained request (here SAP 4, the maximum speed; the issue's was a 137 that
    factory-reset the module at every start) and a retained switch press, left on the broker
    by any client, are not taken as commands at the bridge's start nor at its reconnect."""
    async def leave_retained() -> None:
        async with probing(broker) as probe:
            await probe.client.publish("rig/tmcl/1/request", Request(
                1, Opcode.SAP, AP.MAX_SPEED, 0, 1234).encode(), qos=1, retain=True)
            await probe.client.publish("rig/tmcl/1/sim/switch/0/left", b"1", qos=1, retain=True)

    asyncio.run(leave_retained())
    sim = start_sim(broker)
    host = RawClient(sim.tcp)
    try:
        for restart in range(2):
            if restart:  # a reconnect subscribes again
                broker.stop()
                broker.start()

            async def ask() -> dict:
                async with probing(broker) as probe:
                    await probe.client.subscribe("rig/tmcl/1/reply", qos=1)
                    while True:  # a live request: answered once the bridge has subscribed
                        since = probe.mark()
                        await probe.client.publish("rig/tmcl/1/request", json.dumps(
                            {"cmd": "GAP", "type": AP.MAX_SPEED, "motor": 0}), qos=1)
                        try:
                            return json_of(await probe.wait(
                                lambda m: m.topic.value == "rig/tmcl/1/reply", since=since,
                                timeout=2.0))
                        except AssertionError:
                            continue  # not connected yet

            assert asyncio.run(ask())["value"] != 1234
            assert host.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value != 1234
            assert host.request(1, Opcode.GAP, AP.LEFT_SWITCH, 0).value == 0
    finally:
        host.close()
        sim.stop()


def test_a_request_flood_is_bounded_counted_and_leaves_the_hosts_served(broker, monkeypatch):
    """N3: requests from the broker wait in a bounded inbox and are handled at a bounded
    rate, each followed by a turn of the loop; what does not fit is refused, counted on
    PREFIX/dropped and logged at a bounded rate, and a TCP host polling meanwhile gets every
    reply.  (The limits are made small here so that a test's flood overflows them.)"""
    monkeypatch.setattr(bridge_module, "MAX_INBOX", 50)
    monkeypatch.setattr(bridge_module, "INBOX_RATE", 200.0)
    sim = start_sim(broker)
    host = RawClient(sim.tcp)
    sent = 2_000
    try:
        async def flood() -> tuple[int, dict]:
            async with probing(broker) as probe:
                await probe.client.subscribe("rig/tmcl/1/reply", qos=0)
                await probe.client.subscribe("rig/tmcl/dropped", qos=1)
                gap = Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0).encode()
                for _ in range(sent):
                    await probe.client.publish("rig/tmcl/1/request", gap, qos=0)
                for _ in range(20):  # the host is served while the flood waits
                    reply = await asyncio.to_thread(host.request, 1, Opcode.GAP, AP.MAX_SPEED, 0)
                    assert reply.status == 100
                counts = json_of(await probe.wait(
                    lambda m: m.topic.value == "rig/tmcl/dropped" and json_of(m)["requests"] > 0,
                    timeout=30))
                replies = probe.on("rig/tmcl/1/reply")
                assert all(decode_reply(m.payload).status == 100 for m in replies)
                return len(replies), counts

        received, counts = asyncio.run(flood())
        refused = sim.call(lambda: _bridge(sim).outbox.dropped["requests"])
        assert refused >= counts["requests"] > 0
        assert received + refused <= sent
    finally:
        host.close()
        sim.stop()
