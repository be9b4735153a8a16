"""Faults over MQTT: ``sim/fault`` installs them, ``PREFIX/faults`` lists them, and replies on
the reply topic are lost or altered like on every other transport."""

from __future__ import annotations

import asyncio
import json

import pytest

from tests.helpers.mosquitto import Broker, missing_reason
from tests.helpers.requirements import needs
from tests.tmcl_server.transports.test_mqtt import json_of, probing, start_sim
from tmcl_server.protocol import Request, decode_reply
from tmcl_spec.commands import Opcode

pytestmark = needs(missing_reason())


@pytest.fixture
def broker(tmp_path):
    b = Broker(tmp_path)
    yield b
    b.stop()


def test_sim_fault_alters_and_loses_replies_and_is_listed(broker: Broker) -> None:
    sim = start_sim(broker)

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
