"""The MQTT bridge against a real mosquitto broker, with a separate aiomqtt client."""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import AsyncIterator, Callable

import aiomqtt
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from interpreter.assembler import assemble
from tests.conftest import RawClient
from tests.helpers.mosquitto import Broker, missing_reason
from tests.helpers.requirements import needs
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_reply
from tmcl_server.server import ServerConfig
from tmcl_server.transports.mqtt.bridge import MqttSettings
from tmcl_server.upload import StreamClient, upload
from tmcl_spec.commands import Opcode

pytestmark = needs(missing_reason())


@pytest.fixture
def sim(broker):
    simulator = start_sim(broker)
    yield simulator
    simulator.stop()


@contextlib.asynccontextmanager
async def probing(broker: Broker, **kwargs) -> AsyncIterator[Probe]:
    """A connected test-side client with its recorder."""
    async with probe_client(broker, **kwargs) as client:
        yield Probe(client)


def start_sim(broker: Broker, **config) -> SimulatorThread:
    config.setdefault("mqtt_commands", True)  # the remote TMCL host the tests play (N8: opt-in)
    cfg = ServerConfig(clock="virtual", mqtt_rate=50,
                       endpoints={"tcp": ["127.0.0.1:0"], "mqtt": [f"{broker.url}/rig/tmcl"]},
                       **config)
    return SimulatorThread(cfg).start()


class Probe:
    """A test-side MQTT client that records every message it gets, in order."""

    def __init__(self, client: aiomqtt.Client) -> None:
        self.client = client
        self.messages: list[aiomqtt.Message] = []
        self._arrived = asyncio.Event()
        self._task = asyncio.create_task(self._collect())

    async def _collect(self) -> None:
        try:
            async for message in self.client.messages:
                self.messages.append(message)
                self._arrived.set()
        except aiomqtt.MqttError:
            pass  # the test closed its client

    def mark(self) -> int:
        """Position after the messages seen so far (for ``wait(..., since=...)``)."""
        return len(self.messages)

    async def wait(self, predicate: Callable[[aiomqtt.Message], bool],
                   timeout: float = 5.0, since: int = 0) -> aiomqtt.Message:
        deadline = time.monotonic() + timeout
        while True:
            for message in self.messages[since:]:
                if predicate(message):
                    return message
            self._arrived.clear()
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                topics = [m.topic.value for m in self.messages]
                raise AssertionError(f"no matching message; got {topics}")
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._arrived.wait(), remaining)

    def on(self, topic: str) -> list[aiomqtt.Message]:
        return [m for m in self.messages if m.topic.value == topic]


def probe_client(broker: Broker, **kwargs) -> aiomqtt.Client:
    return aiomqtt.Client("127.0.0.1", broker.port, protocol=aiomqtt.ProtocolVersion.V5,
                          **kwargs)


def json_of(message: aiomqtt.Message) -> dict:
    return json.loads(message.payload)


def test_settings_from_url():
    s = MqttSettings.from_url("mqtts://bob:p%40ss@broker.lan/lab/rig1", env={})
    assert (s.host, s.port, s.tls, s.prefix, s.username, s.password) == (
        "broker.lan", 8883, True, "lab/rig1", "bob", "p@ss")
    s = MqttSettings.from_url("mqtt://127.0.0.1", env={"TMCL_MQTT_USERNAME": "u",
                                                       "TMCL_MQTT_PASSWORD": "pw"})
    assert (s.port, s.prefix, s.username, s.password) == (1883, "tmcl", "u", "pw")
    assert "pw" not in s.display
    with pytest.raises(ValueError):
        MqttSettings.from_url("http://x")
    with pytest.raises(ValueError):
        MqttSettings.from_url("mqtt://x/a/#")


def test_state_follows_a_move_and_requests_in_json_and_binary(broker, sim):
    async def scenario():
        async with probing(broker) as probe:
            client = probe.client
            # retain as published: the flag says "retained" also when the state arrives live
            # (the bridge may publish it after this subscription, on a loaded machine)
            await client.subscribe("rig/tmcl/#", options=SubscribeOptions(qos=1, retainAsPublished=True))
            assert (await probe.wait(lambda m: m.topic.value == "rig/tmcl/status")).payload == b"online"
            first = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/state")
            assert first.retain and json_of(first)["axes"][0]["position"] == 0
            await client.publish("rig/tmcl/1/request", json.dumps(
                {"cmd": "MVP", "type": "ABS", "motor": 0, "value": 51200}), qos=1)
            reply = json_of(await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply"))
            assert reply == {"status": 100, "status_name": "OK", "cmd": "MVP", "opcode": 4,
                             "value": 51200}
            await asyncio.to_thread(sim.advance, 0.5)
            moving = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/state"
                                      and 0 < json_of(m)["axes"][0]["position"] < 51200)
            mark = probe.mark()
            axis = json_of(moving)["axes"][0]
            assert axis["target"] == 51200 and axis["velocity"] > 0 and not axis["reached"]
            assert axis["mode"] == "position"
            await asyncio.to_thread(sim.advance, 3)
            done = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/state"
                                    and json_of(m)["axes"][0]["reached"], since=mark)
            assert json_of(done)["axes"][0]["position"] == 51200
            # the same module, binary frames
            await client.publish("rig/tmcl/1/request", Request(1, Opcode.GAP, 1, 0, 0).encode(),
                                 qos=1)
            binary = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply"
                                      and len(m.payload) == 9)
            assert decode_reply(binary.payload).value == 51200

    asyncio.run(scenario())


def test_events_arrive_in_order_with_simulated_time(broker, sim):
    async def scenario():
        async with probing(broker) as probe:
            client = probe.client
            await client.subscribe("rig/tmcl/1/event", qos=1)
            await client.subscribe("rig/tmcl/status", qos=1)
            await probe.wait(lambda m: m.topic.value == "rig/tmcl/status")
            for motor, target in ((0, 60000), (1, 1000), (2, 20000)):
                await client.publish("rig/tmcl/1/request", json.dumps(
                    {"cmd": "MVP", "motor": motor, "value": target}), qos=1)
            await client.publish("rig/tmcl/1/sim/input/2", b"1", qos=1)
            is_event = lambda m: m.topic.value == "rig/tmcl/1/event"  # noqa: E731
            await probe.wait(lambda m: is_event(m) and json_of(m)["kind"] == "input_changed")
            await asyncio.to_thread(sim.advance, 5)
            await probe.wait(lambda m: is_event(m) and json_of(m).get("axis") == 0)
            events = [json_of(m) for m in probe.on("rig/tmcl/1/event")]
            reached = [e for e in events if e["kind"] == "target_reached"]
            assert [e["axis"] for e in reached] == [1, 2, 0]
            times = [e["t"] for e in reached]
            assert times == sorted(times) and 0 < times[0] < times[-1] <= 5
            assert events[0] == {"t": 0.0, "kind": "input_changed", "port": 2, "level": 1}

    asyncio.run(scenario())


def test_response_topic_and_correlation_data(broker, sim):
    async def scenario():
        async with probing(broker) as probe:
            client = probe.client
            await client.subscribe("answers/me", qos=1)
            properties = Properties(PacketTypes.PUBLISH)
            properties.ResponseTopic = "answers/me"
            properties.CorrelationData = b"req-17"
            await client.publish("rig/tmcl/1/request", json.dumps({"cmd": 136, "type": 1}),
                                 qos=1, properties=properties)
            reply = await probe.wait(lambda m: True)
            assert reply.properties.CorrelationData == b"req-17"
            assert json_of(reply)["value"] == (6212 << 16) | (1 << 8) | 5
            await client.publish("rig/tmcl/1/request", json.dumps(
                {"cmd": "GET_FIRMWARE_VERSION"}), qos=1, properties=properties)
            version = await probe.wait(lambda m: "text" in json_of(m))
            assert json_of(version)["text"] == "6212V105"

    asyncio.run(scenario())


@pytest.mark.parametrize(("payload", "message"), [
    (b"{not json", "not valid JSON"),
    (b'{"cmd": "FLY"}', "unknown mnemonic 'FLY'"),
    (b'{"cmd": "MVP", "type": "SIDEWAYS"}', "unknown type 'SIDEWAYS'"),
    (b'{"cmd": "SAP", "type": 4, "moter": 0}', "unknown field(s) moter"),
    (b'{"cmd": "SAP", "value": 1e3}', "value must be an integer"),
    (b'{"type": 4}', 'needs "cmd"'),
    (b"[1, 2]", "must be a JSON object"),
    (b"\x01\x02\x03", "not valid JSON"),
    # issue 11 item 10
    (b"[" * 100_000 + b"]" * 100_000, "longer than 65536"),
    (b'{"cmd": ' + b"[" * 5_000 + b"]" * 5_000 + b"}", "nested deeper than 16"),
    (bytes(range(246, 256)), "not UTF-8 text"),  # 10 binary bytes: not a frame, not text
    (b'{"cmd": "SAP", "type": 4, "value": 1e999}', "out of range"),
    (b'{"cmd": "SAP", "type": 4, "value": NaN}', "NaN is not a number"),
    (b'{"cmd": "SAP", "type": 4, "value": -Infinity}', "-Infinity is not a number"),
    (b'{"cmd": "SAP", "value": ' + b"9" * 5000 + b"}", "not valid JSON"),
])
def test_bad_requests_get_clear_errors(broker, sim, payload, message):
    async def scenario():
        async with probing(broker) as probe:
            client = probe.client
            await client.subscribe("rig/tmcl/1/reply", qos=1)
            await client.publish("rig/tmcl/1/request", payload, qos=1)
            reply = json_of(await probe.wait(lambda m: True))
            assert message in reply["error"]

    asyncio.run(scenario())


def test_bad_checksum_and_bad_values_get_tmcl_statuses(broker, sim):
    async def scenario():
        async with probing(broker) as probe:
            client = probe.client
            await client.subscribe("rig/tmcl/1/reply", qos=1)
            frame = bytearray(Request(1, Opcode.SAP, 4, 0, 5).encode())
            frame[8] ^= 1
            await client.publish("rig/tmcl/1/request", bytes(frame), qos=1)
            assert decode_reply((await probe.wait(lambda m: True)).payload).status == 1
            await client.publish("rig/tmcl/1/request", json.dumps(
                {"cmd": "SAP", "type": 4, "motor": 9, "value": 5}), qos=1)
            reply = await probe.wait(lambda m: m.payload[:1] == b"{")
            assert json_of(reply)["status_name"] == "INVALID_VALUE"

    asyncio.run(scenario())


def test_broker_restart_is_survived_and_nothing_is_lost(broker, sim):
    tcp = RawClient(sim.tcp)
    session = f"probe-{uuid.uuid4().hex[:8]}"

    async def subscribe_persistently():
        async with probe_client(broker, identifier=session, clean_start=False,
                                properties=_session_expiry()) as client:
            await client.subscribe("rig/tmcl/#", qos=1)

    async def after_restart():
        async with probing(broker, identifier=session, clean_start=False,
                           properties=_session_expiry()) as probe:
            event = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/event"
                                     and json_of(m)["kind"] == "target_reached", timeout=15)
            assert json_of(event)["axis"] == 3
            await probe.wait(lambda m: m.topic.value == "rig/tmcl/status"
                             and m.payload == b"online")
            state = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/state"
                                     and json_of(m)["axes"][3]["position"] == 4000)
            assert json_of(state)["axes"][3]["reached"]
            await probe.client.publish("rig/tmcl/1/request", json.dumps(
                {"cmd": "GAP", "type": 1, "motor": 3}), qos=1)
            reply = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply")
            assert json_of(reply)["value"] == 4000

    try:
        asyncio.run(subscribe_persistently())
        broker.stop()
        # With the broker gone, the simulator keeps serving its other transports ...
        assert tcp.request(1, Opcode.MVP, 0, 3, 4000).status == 100
        sim.advance(2)  # ... and an event happens that MQTT owes the world
        assert tcp.request(1, Opcode.GAP, 8, 3).value == 1
        broker.start()
        asyncio.run(after_restart())
    finally:
        tcp.close()


def _session_expiry() -> Properties:
    properties = Properties(PacketTypes.CONNECT)
    properties.SessionExpiryInterval = 300
    return properties


def test_last_will_says_offline_when_the_process_dies(broker, tmp_path):
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen([sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0",
                             "--mqtt", f"{broker.url}/dies", "--ready-file", str(ready)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    async def scenario():
        async with probing(broker) as probe:
            await probe.client.subscribe("dies/status", qos=1)
            await probe.wait(lambda m: m.payload == b"online", timeout=20)
            proc.send_signal(signal.SIGKILL)
            await probe.wait(lambda m: m.payload == b"offline", timeout=10)

    try:
        asyncio.run(scenario())
    finally:
        proc.kill()
        proc.wait(10)


def test_clean_shutdown_says_offline(broker, sim):
    async def scenario():
        async with probing(broker) as probe:
            await probe.client.subscribe("rig/tmcl/status", qos=1)
            await probe.wait(lambda m: m.payload == b"online")
            await asyncio.to_thread(sim.stop)
            await probe.wait(lambda m: m.payload == b"offline")

    asyncio.run(scenario())


RIG_PROGRAM = """
    VECT 27, LeftHit          // left stop switch of axis 0
    VECT 40, InputOne         // input 1 changed
    SGP 27, 3, 1              // trigger on low -> high
    SGP 40, 3, 3              // either edge
    EI 27
    EI 40
    EI 255
    ROL 0, 20000
Idle:
    JA Idle
LeftHit:
    SIO 0, 2, 1
    RETI
InputOne:
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2                  // count input changes in user variable 0
    RETI
"""


def test_sim_topics_trigger_a_limit_stop_and_interrupts_in_a_running_program(broker, sim):
    client = StreamClient.tcp(sim.tcp, 1, timeout=5)
    upload(client, assemble(RIG_PROGRAM).instructions, run=True)

    async def scenario():
        async with probing(broker) as probe:
            await probe.client.subscribe("rig/tmcl/1/#", qos=1)
            await asyncio.to_thread(sim.advance, 1.0)  # the program turns axis 0 left
            moving = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/state"
                                      and json_of(m)["axes"][0]["velocity"] < 0)
            assert json_of(moving)["program"]["state"] == 1
            mark = probe.mark()
            await probe.client.publish("rig/tmcl/1/sim/switch/0/left", b"1", qos=1)
            # Two edges of input 1, simulated time apart (edges at one instant latch one
            # pending interrupt, as a hardware flag does).
            for payload in (b"1", b'{"analog": 0}'):
                seen = probe.mark()
                await probe.client.publish("rig/tmcl/1/sim/input/1", payload, qos=1)
                await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/event"
                                 and json_of(m)["kind"] == "input_changed", since=seen)
                await asyncio.to_thread(sim.advance, 0.1)
            await probe.client.publish("rig/tmcl/1/sim/switch/0/sideways", b"1", qos=1)
            error = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/sim_error")
            assert "sideways" in json_of(error)["error"]
            await asyncio.to_thread(sim.advance, 0.5)
            stopped = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/state"
                                       and json_of(m)["axes"][0]["left"]
                                       and json_of(m)["outputs"][0] == 1, since=mark)
            axis = json_of(stopped)["axes"][0]
            assert axis["velocity"] == 0  # the limit switch stopped the motor
            events = [json_of(m) for m in probe.on("rig/tmcl/1/event")]
            kinds = [e["kind"] for e in events]
            assert {"kind": "left_switch", "axis": 0, "active": True} in [
                {k: e[k] for k in ("kind", "axis", "active") if k in e} for e in events]
            taken = [e["vector"] for e in events if e["kind"] == "interrupt_taken"]
            assert taken.count(27) == 1 and taken.count(40) == 2
            assert kinds.index("left_switch") < kinds.index("interrupt_taken")

    try:
        asyncio.run(scenario())
        assert client.send(Opcode.GGP, 0, 2, 0)[3] == 2  # both input edges were counted
    finally:
        client.close()


def test_an_idle_module_on_a_real_clock_publishes_its_state_once(broker):
    """The time stamp alone is no change: an idle module is quiet until something changes."""
    cfg = ServerConfig(clock="real", mqtt_rate=50,
                       endpoints={"tcp": ["127.0.0.1:0"], "mqtt": [f"{broker.url}/idle"]})
    simulator = SimulatorThread(cfg).start()
    try:
        async def scenario():
            async with probing(broker) as probe:
                await probe.client.subscribe("idle/1/state", qos=1)
                # idle once the firmware's passes switched every axis to standby (by 66 ms)
                first = await probe.wait(lambda m: m.topic.value == "idle/1/state" and all(
                    axis["standby"] for axis in json_of(m)["axes"]))
                mark = probe.mark()
                # 25 publishing periods of 20 ms; before the fix each one sent a new message
                with contextlib.suppress(AssertionError):
                    await probe.wait(lambda m: True, timeout=0.5, since=mark)
                assert probe.messages[mark:] == [], [json_of(m)["t"] for m in probe.messages[mark:]]
                press = lambda: simulator.module(1).set_digital_input(3, True)  # noqa: E731
                await asyncio.to_thread(simulator.call, press)
                changed = await probe.wait(lambda m: m.topic.value == "idle/1/state", since=mark)
                assert json_of(changed)["inputs"][3] == 1
                assert json_of(changed)["t"] > json_of(first)["t"]  # stamped with its own time

        asyncio.run(scenario())
    finally:
        simulator.stop()


def test_every_event_kind_is_documented():
    """docs/mqtt.md names every kind a module emits (axis events, module and program events)."""
    import re
    from pathlib import Path

    from axes.interface import AxisEventKind

    root = Path(__file__).resolve().parents[3]
    kinds = {kind.value for kind in AxisEventKind}
    for path in [*root.joinpath("tmcl_server").rglob("*.py"), *root.joinpath("interpreter").rglob("*.py")]:
        text = path.read_text()
        kinds.update(re.findall(r'\bemit\(\s*"(\w+)"', text))
        kinds.update(re.findall(r'program_event\([^,]+,\s*"(\w+)"', text))
    assert {"current_changed", "heartbeat_timeout", "interrupt_taken", "supply_changed"} <= kinds
    doc = (root / "docs" / "mqtt.md").read_text()
    undocumented = sorted(k for k in kinds if f"`{k}`" not in doc)
    assert not undocumented, f"event kinds missing from docs/mqtt.md: {undocumented}"


#: (topic under rig/tmcl/1/sim/, payload, words of the sim_error answer), issue 11 item 10
BAD_SIM_MESSAGES = [
    ("switch/0/left", b'{"position": 1e999}', "out of range"),
    ("switch/0/left", b'{"position": NaN}', "NaN"),
    ("switch/0/left", b'{"position": 1.5}', "position must be an integer"),
    ("switch/0/left", b'{"position": 0, "width": Infinity}', "Infinity"),
    ("switch/0/left", b'{"position": 0, "side": 5}', "side must be a string"),
    ("load/0", b'{"zones": [[-1e999, 5, 0]]}', "out of range"),
    ("load/0", b'{"zones": [["a", 5, 0]]}', "zone start must be an integer"),
    ("encoder_slip/0", b"NaN", "NaN"),
    ("supply", b"Infinity", "Infinity"),
    ("supply", b'"24"', "supply voltage must be a number"),
    ("input/0", bytes(range(246, 256)), "not UTF-8 text"),
    ("input/0", b"[" * 5_000 + b"]" * 5_000, "nested deeper than 16"),
    ("input/0", b"[" * 100_000 + b"]" * 100_000, "longer than 65536"),
    ("fault", b'{"kind": "delay", "ms": NaN}', "NaN"),
    ("fault", b'{"kind": "delay", "ms": 1e999}', "out of range"),
    ("fault", b"\xff\xfe", "not UTF-8 text"),
    ("fault", b"{" * 5_000, "nested deeper than 16"),
]


def test_bad_sim_messages_get_a_clear_error_and_change_nothing(broker):
    sim = start_sim(broker, mqtt_faults=True)

    async def scenario():
        async with probing(broker) as probe:
            await probe.client.subscribe("rig/tmcl/1/sim_error", qos=1)
            for topic, payload, words in BAD_SIM_MESSAGES:
                seen = probe.mark()
                await probe.client.publish(f"rig/tmcl/1/sim/{topic}", payload, qos=1)
                error = json_of(await probe.wait(lambda m: True, since=seen))
                assert error["topic"] == f"sim/{topic}" and words in error["error"], (topic, error)
            # and the bridge still works: a good message after all of them is applied
            await probe.client.subscribe("rig/tmcl/1/reply", qos=1)
            await probe.client.publish("rig/tmcl/1/request", b'{"cmd": "GAP", "type": 1}', qos=1)
            reply = await probe.wait(lambda m: m.topic.value == "rig/tmcl/1/reply")
            assert json_of(reply)["status_name"] == "OK"

    try:
        asyncio.run(scenario())
    finally:
        sim.stop()
    module = sim.server.simulation.modules[0]
    world = module.axis_world(0)  # the server has stopped: nothing else touches the module
    assert "left" not in world.switches and world.encoder_slip == 0
    assert module.supply_voltage == module.type.nominal_supply_voltage
    assert list(module.axis_world(0).load_zones) == []
    from tmcl_server.faults import FaultInjector
    assert dict(FaultInjector.of(sim.server.simulation).faults) == {}
