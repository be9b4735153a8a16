"""Faults over MQTT: ``sim/fault`` installs them, ``PREFIX/faults`` lists them, and replies on
the reply topic are lost or altered like on every other transport."""

from __future__ import annotations

import asyncio
import json
import time

import pytest

from tests.helpers.mosquitto import Broker, missing_reason
from tests.helpers.requirements import needs
from tests.tmcl_server.transports.test_mqtt import json_of, probing, start_sim
from tmcl_server.protocol import Request, decode_reply
from tmcl_spec.commands import Opcode

pytestmark = needs(missing_reason())


def test_sim_fault_alters_and_loses_replies_and_is_listed(broker: Broker) -> None:
    sim = start_sim(broker, mqtt_faults=True)

    async def scenario() -> None:
        async with probing(broker) as probe:
            client = probe.client
            for topic in ("rig/tmcl/1/reply", "rig/tmcl/faults", "rig/tmcl/1/sim_error"):
                await client.subscribe(topic, qos=1)
            await client.publish("rig/tmcl/1/sim/fault", b"status:opcode=GAP,status=3", qos=1)
            listed = json_of(await probe.wait(lambda m: m.topic.value == "rig/tmcl/faults"))
            assert [f["spec"] for f in listed] == ["status:opcode=GAP,status=3,module=1"]
            await client.publish("rig/tmcl/1/request", json.dumps({"cmd": "GAP", "type": 1}), qos=1)
            reply = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply")
            assert json_of(reply)["status"] == 3
            await client.publish("rig/tmcl/1/sim/fault", b'{"kind": "checksum"}', qos=1)
            mark = probe.mark()
            await client.publish("rig/tmcl/1/request", Request(1, Opcode.GGP, 66, 0, 0).encode(), qos=1)
            binary = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply", since=mark)
            with pytest.raises(ValueError, match="checksum"):
                decode_reply(binary.payload)
            await client.publish("rig/tmcl/1/sim/fault", b"clear", qos=1)
            await probe.wait(lambda m: m.topic.value == "rig/tmcl/faults" and json_of(m) == [])
            await client.publish("rig/tmcl/1/sim/fault", b"noreply:rate=2", qos=1)
            error = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/sim_error")
            assert "rate must be 0..1" in json_of(error)["error"]

    try:
        asyncio.run(scenario())
    finally:
        sim.stop()


def test_faults_over_mqtt_are_off_unless_asked_for(broker: Broker) -> None:
    """Every client of the broker could otherwise silence (noreply) or reset the module."""
    sim = start_sim(broker)

    async def scenario() -> None:
        async with probing(broker) as probe:
            client = probe.client
            for topic in ("rig/tmcl/1/reply", "rig/tmcl/1/sim_error"):
                await client.subscribe(topic, qos=1)
            for topic, payload in (("sim/fault", b"noreply"), ("sim/fault", b"reset:rate=1"),
                                   ("sim/power_cycle", b"1"), ("sim/fault/remove", b"1")):
                mark = probe.mark()
                await client.publish(f"rig/tmcl/1/{topic}", payload, qos=1)
                error = json_of(await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/sim_error",
                                                 since=mark))
                assert error["topic"] == topic and "--mqtt-faults" in error["error"], error
            await client.publish("rig/tmcl/1/request", json.dumps({"cmd": "GAP", "type": 4}), qos=1)
            reply = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply")
            assert json_of(reply)["value"] == 51200

    try:
        asyncio.run(scenario())
        from tmcl_server.faults import FaultInjector
        assert sim.call(lambda: FaultInjector.of(sim.simulation).describe()) == []
    finally:
        sim.stop()


def test_a_flood_of_faults_over_mqtt_is_bounded(broker: Broker) -> None:
    """The issue: 2,000 faults republished the retained list 2,000 times (341 MB sent).  Now
    at most MAX_FAULTS are installed, the rest answered on sim_error, and the retained list is
    coalesced: it is published far fewer times than faults were sent."""
    from tmcl_server.fault_language import MAX_FAULTS
    from tmcl_server.faults import FaultInjector

    sim = start_sim(broker, mqtt_faults=True)
    sent = MAX_FAULTS + 44

    async def scenario() -> tuple[int, int]:
        async with probing(broker) as probe:
            client = probe.client
            for topic in ("rig/tmcl/faults", "rig/tmcl/1/sim_error"):
                await client.subscribe(topic, qos=1)
            for _ in range(sent):
                await client.publish("rig/tmcl/1/sim/fault", b"noreply:opcode=GAP", qos=1)
            deadline = time.monotonic() + 30
            while (len(probe.on("rig/tmcl/1/sim_error")) < sent - MAX_FAULTS
                   and time.monotonic() < deadline):
                await asyncio.sleep(0.05)
            errors = len(probe.on("rig/tmcl/1/sim_error"))
            await probe.wait(lambda m: m.topic.value == "rig/tmcl/faults"
                             and len(json_of(m)) == MAX_FAULTS, timeout=10)
            assert "256 faults are installed" in json_of(probe.on("rig/tmcl/1/sim_error")[0])["error"]
            return errors, len(probe.on("rig/tmcl/faults"))

    try:
        errors, lists = asyncio.run(scenario())
        assert errors == sent - MAX_FAULTS
        assert sim.call(lambda: len(FaultInjector.of(sim.simulation).faults)) == MAX_FAULTS
        assert lists <= MAX_FAULTS
    finally:
        sim.stop()
