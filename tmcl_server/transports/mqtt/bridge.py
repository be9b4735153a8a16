"""MQTT bridge: live state, events and remote TMCL requests through a real broker (aiomqtt).

Topics, with PREFIX taken from the URL path (``mqtt://host:1883/tmcl`` -> ``tmcl``) and A the
address a module was started with (its slot):

* ``PREFIX/status``            ``online`` / ``offline`` (retained, last will)
* ``PREFIX/A/state``           retained JSON snapshot, on change, at most ``rate`` per second
* ``PREFIX/A/event``           one JSON message per module event, in order
* ``PREFIX/A/request``         a 9-byte TMCL frame or JSON -> reply on ``PREFIX/A/reply``
                               (or the MQTT 5 response topic, correlation data copied)
* ``PREFIX/A/sim/...``         set the simulated world (inputs, switches, load, slip), inject
                               faults (``sim/fault``; the list: ``PREFIX/faults``, retained)

Field names and payloads are documented in docs/mqtt.md.  The bridge keeps the replies and
events it owes in a bounded outbox until the broker has taken them: a short broker restart
loses nothing, a long one (or events faster than the broker takes them) loses the events that
do not fit, counted on ``PREFIX/dropped``; retained messages (the fault list, the counter)
keep only their latest value.  It reconnects with back-off and republishes the state.
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import logging
import os
import socket
import ssl
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any
from urllib.parse import unquote, urlsplit

import aiomqtt
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.subscribeoptions import SubscribeOptions

from tmcl_server.delivery import Delivery
from tmcl_server.dispatch import Interface
from tmcl_server.fault_language import FaultSpecError
from tmcl_server.faults import FaultInjector
from tmcl_server.module import READ_ONLY_OPCODES, ModuleEvent, TMCLModule
from tmcl_server.protocol import FRAME_LENGTH, ChecksumError, Reply, decode_request
from tmcl_server.sidechannel import SideChannel
from tmcl_server.simulation import Simulation
from tmcl_server.transports.admission import Pace
from tmcl_server.transports.base import Transport, TransportHost
from tmcl_server.transports.mqtt import DEFAULT_RATE_HZ
from tmcl_server.transports.mqtt.fault_topics import FAULT_TOPICS, apply_fault_message
from tmcl_server.transports.mqtt.requests import RequestError, reply_to_json, request_from_json
from tmcl_server.transports.mqtt.world_topics import WorldTopicError, apply_sim_message
from tmcl_spec.numbers import NS_PER_S

log = logging.getLogger(__name__)

DEFAULT_PREFIX = "tmcl"
ENV_USERNAME = "TMCL_MQTT_USERNAME"
ENV_PASSWORD = "TMCL_MQTT_PASSWORD"
BACKOFF_START_S = 0.2
BACKOFF_MAX_S = 5.0
#: Replies (and answers such as ``sim_error``) waiting for the broker, at most this many; and
#: as many events.  What comes beyond is dropped and counted (docs/mqtt.md, Reliability).
MAX_QUEUED = 10_000
#: Messages sent to the broker before their acknowledgements are awaited together (QoS 1):
#: one at a time, a broker's round trip limits the bridge to a few hundred a second.
IN_FLIGHT = 16
#: Messages from the broker (requests, sim topics) waiting to be handled, at most this many;
#: past it a message is refused, counted (``requests`` on PREFIX/dropped) and logged at a
#: bounded rate (issue 36, N3: 20,000 requests at once took 130 MB, 50,000 starved the hosts).
MAX_INBOX = 1_000
#: ... and handled at most this many a second (bursts of INBOX_BURST), each followed by a
#: turn of the event loop: a flood of MQTT requests leaves the TCP hosts their share.
INBOX_RATE, INBOX_BURST = 1_000.0, 100
#: Retained messages are never taken as commands (issue 36, N4): the broker sends none on
#: these topics at subscription (MQTT 5 Retain Handling 2), and one it sends anyway is dropped.
NO_RETAINED = SubscribeOptions(qos=1, retainHandling=SubscribeOptions.RETAIN_DO_NOT_SEND)


#: The answer to a command that changes the module while --mqtt-commands is off.
COMMANDS_OFF = ("commands that change the module are off over MQTT (only GAP, GGP, GIO and "
                "the version are served): start tmcl-server with --mqtt-commands to allow them")


@dataclass(frozen=True)
class MqttSettings:
    host: str
    port: int
    prefix: str = DEFAULT_PREFIX
    tls: bool = False
    username: str | None = None
    password: str | None = None

    @classmethod
    def from_url(cls, url: str, env: dict[str, str] | None = None) -> MqttSettings:
        env = dict(os.environ) if env is None else env
        parts = urlsplit(url if "://" in url else f"mqtt://{url}")
        if parts.scheme not in ("mqtt", "mqtts"):
            raise ValueError(f"MQTT URL must start with mqtt:// or mqtts://, got {url!r}")
        tls = parts.scheme == "mqtts"
        prefix = parts.path.strip("/") or DEFAULT_PREFIX
        if parts.fragment or url.endswith("#") or "+" in prefix:
            raise ValueError(f"MQTT topic prefix may not contain wildcards: {prefix!r}")
        return cls(
            host=parts.hostname or "127.0.0.1",
            port=parts.port or (8883 if tls else 1883),
            prefix=prefix,
            tls=tls,
            username=unquote(parts.username) if parts.username else env.get(ENV_USERNAME),
            password=unquote(parts.password) if parts.password else env.get(ENV_PASSWORD),
        )

    @property
    def display(self) -> str:
        """The URL without credentials (for logs and the ready file)."""
        scheme = "mqtts" if self.tls else "mqtt"
        return f"{scheme}://{self.host}:{self.port}/{self.prefix}"


@dataclass(slots=True)
class _Outgoing:
    topic: str
    payload: bytes
    qos: int = 1
    retain: bool = False
    correlation: bytes | None = None


class Outbox:
    """What the bridge owes the broker, bounded: replies and events in order, each queue at
    most :data:`MAX_QUEUED` long (beyond it a message is dropped and counted), and retained
    messages coalesced to the latest per topic."""

    def __init__(self, limit: int = MAX_QUEUED) -> None:
        self.limit = limit
        self.replies: deque[_Outgoing] = deque()
        self.events: deque[_Outgoing] = deque()
        self.latest: dict[str, _Outgoing] = {}
        #: Messages dropped so far, by kind (published on PREFIX/dropped); ``requests``: messages
        #: from the broker refused because the inbox was full.
        self.dropped = {"events": 0, "replies": 0, "requests": 0}
        self.ready = asyncio.Event()

    def __len__(self) -> int:
        return len(self.replies) + len(self.events) + len(self.latest)

    def reply(self, message: _Outgoing) -> bool:
        return self._add(self.replies, "replies", message)

    def event(self, message: _Outgoing) -> bool:
        return self._add(self.events, "events", message)

    def retained(self, message: _Outgoing) -> None:
        self.latest[message.topic] = message
        self.ready.set()

    def _add(self, queue: deque[_Outgoing], kind: str, message: _Outgoing) -> bool:
        if len(queue) >= self.limit:
            self.dropped[kind] += 1
            log.warning("MQTT outbox: %d %s wait for the broker (the limit); dropping more, "
                        "counted on PREFIX/dropped", len(queue), kind)
            return False
        queue.append(message)
        self.ready.set()
        return True

    def batch(self, size: int = IN_FLIGHT) -> list[tuple[str, _Outgoing]]:
        """The next messages to send, oldest first, replies before retained before events;
        they stay queued until :meth:`sent` (a lost connection sends them again)."""
        picked: list[tuple[str, _Outgoing]] = [("replies", m) for m in
                                               list(itertools.islice(self.replies, size))]
        picked += [("latest", m) for m in list(self.latest.values())[:size - len(picked)]]
        picked += [("events", m) for m in
                   list(itertools.islice(self.events, max(0, size - len(picked))))]
        return picked

    def sent(self, picked: list[tuple[str, _Outgoing]]) -> None:
        for kind, message in picked:
            if kind == "latest":
                if self.latest.get(message.topic) is message:  # not replaced meanwhile
                    del self.latest[message.topic]
            else:
                queue = self.replies if kind == "replies" else self.events
                if queue and queue[0] is message:
                    queue.popleft()
        if not len(self):
            self.ready.clear()


@dataclass
class _ModuleFeed:
    """Per-module publishing state."""

    module: TMCLModule
    base: str
    #: The last state published, without its time stamp (what "changed" is compared on).
    last_state: str | None = None
    listener: Callable[[ModuleEvent], None] | None = field(default=None, repr=False)


class _ReplyRoute:
    """Where replies to one request go (also later ones: command 138 events)."""

    def __init__(self, bridge: MqttBridge, topic: str, correlation: bytes | None,
                 as_json: bool) -> None:
        self._bridge = bridge
        self._topic = topic
        self._correlation = correlation
        self._as_json = as_json
        self.endpoint = "mqtt"

    def send(self, reply: Any) -> None:
        if type(reply) is Delivery:
            self._send_altered(reply)
            return
        payload = (json.dumps(reply_to_json(reply)).encode() if self._as_json
                   else reply.encode())
        self._bridge.enqueue(_Outgoing(self._topic, payload, correlation=self._correlation))

    def _send_altered(self, delivery: Delivery) -> None:
        """A reply the faults altered: a message cannot be torn (its pauses add up to a delay);
        JSON has no checksum to spoil or room for garbage bytes (docs/faults.md)."""
        if self._as_json:
            payloads = [json.dumps(reply_to_json(delivery.reply)).encode()] * delivery.copies
        else:
            frame = delivery.frame()
            payloads = [delivery.garbage + frame] + [frame] * (delivery.copies - 1)
        messages = [_Outgoing(self._topic, p, correlation=self._correlation) for p in payloads]
        if delivery.total_delay_s > 0:
            asyncio.get_running_loop().call_later(delivery.total_delay_s, self._enqueue_all, messages)
        else:
            self._enqueue_all(messages)

    def _enqueue_all(self, messages: list[_Outgoing]) -> None:
        for message in messages:
            self._bridge.enqueue(message)

    def send_unsolicited(self, reply: Reply) -> None:
        self.send(reply)


def _raise_if_cancelling() -> None:
    """Honour a cancellation that a publish swallowed: before Python 3.12, asyncio.wait_for
    (inside aiomqtt's publish) returns the result when the broker's acknowledgement and the
    cancellation arrive together, and the task, still marked as cancelling, would wait on
    forever while the server stops (seen on Ctrl-C, tests/tmcl_server/test_windows.py)."""
    task = asyncio.current_task()
    if task is not None and task.cancelling():
        raise asyncio.CancelledError


class MqttBridge(Transport):
    kind = "mqtt"

    def __init__(self, simulation: Simulation, url: str, rate_hz: float = DEFAULT_RATE_HZ,
                 connect_timeout: float = 5.0, allow_faults: bool = False,
                 allow_commands: bool = False) -> None:
        if rate_hz <= 0:
            raise ValueError("--mqtt-rate must be positive")
        self.simulation = simulation
        self.settings = MqttSettings.from_url(url)
        self.rate_hz = rate_hz
        self.connect_timeout = connect_timeout
        #: ``--mqtt-faults``: whether ``sim/fault`` and ``sim/power_cycle`` are served (every
        #: client of the broker could otherwise silence or reset the module).
        self.allow_faults = allow_faults
        #: ``--mqtt-commands``: whether requests that change the module (anything but GAP,
        #: GGP, GIO and the version) are served (issue 36, N8: every client of the broker
        #: could otherwise reconfigure, reprogram or factory-reset the module).
        self.allow_commands = allow_commands
        self.outbox = Outbox()
        #: Messages from the broker not acted on: ``retained`` (never a command),
        #: ``commands`` (without --mqtt-commands); a full inbox counts in outbox.dropped.
        self.refused = {"retained": 0, "commands": 0}
        self._inbox_pace = Pace(INBOX_RATE, INBOX_BURST)
        #: The dropped counts last queued for PREFIX/dropped.
        self._dropped_shown: dict[str, int] | None = None
        self._connected = asyncio.Event()
        #: The module events are a side channel: a failure stops them, never the module.
        self.events_channel = SideChannel("the MQTT bridge's events", self._remove_listeners)
        self._feeds = [_ModuleFeed(m, f"{self.settings.prefix}/{m.slot}")
                       for m in simulation.modules]
        self._task: asyncio.Task[None] | None = None
        self.connections = 0  # successful connections so far (for tests and logs)

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> MqttBridge:
        return cls(host.simulation, argument, rate_hz=host.option("mqtt_rate"),
                   allow_faults=bool(host.option("mqtt_faults")),
                   allow_commands=bool(host.option("mqtt_commands")))

    @property
    def status_topic(self) -> str:
        return f"{self.settings.prefix}/status"

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> list[str]:
        for feed in self._feeds:
            feed.listener = self._event_listener(feed)
            feed.module.listeners.append(feed.listener)
        self._task = asyncio.create_task(self._run(), name="mqtt-bridge")
        try:
            await asyncio.wait_for(self._connected.wait(), self.connect_timeout)
        except TimeoutError:
            log.warning("MQTT broker %s not reachable yet; retrying in the background",
                        self.settings.display)
        return [self.settings.display]

    async def close(self) -> None:
        self._remove_listeners()
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    def _remove_listeners(self) -> None:
        for feed in self._feeds:
            if feed.listener in feed.module.listeners:
                feed.module.listeners.remove(feed.listener)

    def enqueue(self, message: _Outgoing) -> None:
        """A reply or an answer (in order; dropped and counted past MAX_QUEUED)."""
        if message.retain:
            self.outbox.retained(message)
        else:
            self.outbox.reply(message)

    @property
    def dropped_topic(self) -> str:
        return f"{self.settings.prefix}/dropped"

    def _show_dropped(self) -> None:
        """Queue PREFIX/dropped when the counts changed (retained: the latest counts)."""
        if self.outbox.dropped != self._dropped_shown:
            self._dropped_shown = dict(self.outbox.dropped)
            self.outbox.retained(_Outgoing(self.dropped_topic, json.dumps(
                self._dropped_shown, separators=(",", ":")).encode(), retain=True))

    # -- connection ---------------------------------------------------------------------------

    def _client(self) -> aiomqtt.Client:
        s = self.settings
        tls_context = ssl.create_default_context() if s.tls else None
        client = aiomqtt.Client(
            s.host, s.port, username=s.username, password=s.password,
            identifier=f"tmcl-sim-{s.prefix}-{os.getpid()}",
            protocol=aiomqtt.ProtocolVersion.V5,
            will=aiomqtt.Will(self.status_topic, b"offline", qos=1, retain=True),
            tls_context=tls_context, keepalive=10, timeout=5,
            queue_type=self._inbox_type(), max_queued_incoming_messages=MAX_INBOX,
            # small request/reply messages: Nagle + delayed ACK would add ~40 ms each way
            socket_options=[(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)])
        # IN_FLIGHT publications (and the state's) await their acknowledgements at once: not a
        # "concerning number of pending calls" for aiomqtt to warn about
        client.pending_calls_threshold = 2 * IN_FLIGHT + len(self._feeds) + 8
        return client

    def _inbox_type(self) -> type[asyncio.Queue[aiomqtt.Message]]:
        """aiomqtt's queue of received messages, bounded (MAX_INBOX): a message past it is
        refused and counted here instead of vanishing with aiomqtt's own log line."""
        bridge = self

        class Inbox(asyncio.Queue[aiomqtt.Message]):
            def put_nowait(self, item: aiomqtt.Message) -> None:
                if self.full():
                    bridge._inbox_full(item)
                    return
                super().put_nowait(item)

        return Inbox

    def _inbox_full(self, message: aiomqtt.Message) -> None:
        self.outbox.dropped["requests"] += 1
        log.warning("MQTT: %d messages wait to be handled (the limit); %s refused (%d so far, "
                    "counted on PREFIX/dropped)", MAX_INBOX, message.topic.value,
                    self.outbox.dropped["requests"])

    async def _run(self) -> None:
        backoff = BACKOFF_START_S
        while True:
            try:
                async with self._client() as client:
                    backoff = BACKOFF_START_S
                    await self._session(client)
            except Exception as exc:  # MqttError, or a group of them from the session's tasks
                log.warning("MQTT connection to %s lost (%s); reconnecting in %.1f s",
                            self.settings.display, exc, backoff)
            finally:
                self._connected.clear()
            await asyncio.sleep(backoff)
            backoff = min(backoff * 2, BACKOFF_MAX_S)

    async def _session(self, client: aiomqtt.Client) -> None:
        prefix = self.settings.prefix
        await client.subscribe(f"{prefix}/+/request", options=NO_RETAINED)
        await client.subscribe(f"{prefix}/+/sim/#", options=NO_RETAINED)
        await client.publish(self.status_topic, b"online", qos=1, retain=True)
        for feed in self._feeds:
            feed.last_state = None  # the broker may have lost it: publish afresh
        self._dropped_shown = None
        self._show_dropped()
        self.connections += 1
        self._connected.set()
        try:
            async with asyncio.TaskGroup() as group:
                group.create_task(self._publish_outbox(client))
                group.create_task(self._publish_state(client))
                group.create_task(self._receive(client))
        except asyncio.CancelledError:  # shutting down: say so (the will is for crashes)
            with contextlib.suppress(Exception):
                await asyncio.wait_for(
                    client.publish(self.status_topic, b"offline", qos=1, retain=True), 2)
            raise

    # -- outgoing -----------------------------------------------------------------------------

    async def _publish_outbox(self, client: aiomqtt.Client) -> None:
        outbox = self.outbox
        while True:
            await outbox.ready.wait()
            picked = outbox.batch()
            if not picked:
                outbox.ready.clear()
                continue
            # sent in order, acknowledged together; removed only once the broker has them
            await asyncio.gather(*(self._publish(client, message) for _, message in picked))
            _raise_if_cancelling()
            outbox.sent(picked)

    @staticmethod
    async def _publish(client: aiomqtt.Client, message: _Outgoing) -> None:
        properties = None
        if message.correlation is not None:
            properties = Properties(PacketTypes.PUBLISH)
            properties.CorrelationData = message.correlation
        await client.publish(message.topic, message.payload, qos=message.qos,
                             retain=message.retain, properties=properties)

    async def _publish_state(self, client: aiomqtt.Client) -> None:
        period = 1.0 / self.rate_hz
        while True:
            for feed in self._feeds:
                self.simulation.sync_module(feed.module)
                snapshot = feed.module.snapshot()
                stamp = snapshot.pop("t")  # time alone is no change: compare the rest
                state = json.dumps(snapshot, separators=(",", ":"))
                if state != feed.last_state:
                    payload = json.dumps({"t": stamp, **snapshot}, separators=(",", ":"))
                    await client.publish(f"{feed.base}/state", payload.encode(), qos=1,
                                         retain=True)
                    _raise_if_cancelling()
                    feed.last_state = state
            self._show_dropped()
            await asyncio.sleep(period)

    def _event_listener(self, feed: _ModuleFeed) -> Callable[[ModuleEvent], None]:
        topic = f"{feed.base}/event"
        outbox = self.outbox

        def on_event(event: ModuleEvent) -> None:
            if len(outbox.events) >= outbox.limit:  # full: count it without building it
                outbox.event(_Outgoing(topic, b""))
                return
            body = {"t": event.time_ns / NS_PER_S, "kind": event.kind}
            if event.axis is not None:
                body["axis"] = event.axis
            body.update({k: v for k, v in event.data.items() if v is not None})
            outbox.event(_Outgoing(topic, json.dumps(body, separators=(",", ":")).encode()))

        return self.events_channel.guard(on_event, "publishing an event")

    # -- incoming -----------------------------------------------------------------------------

    async def _receive(self, client: aiomqtt.Client) -> None:
        prefix_parts = len(self.settings.prefix.split("/"))
        async for message in client.messages:
            parts = message.topic.value.split("/")[prefix_parts:]
            feed = self._feed(parts[0] if parts else "")
            if feed is None:
                continue
            if message.retain:  # a command left on the broker: never acted on again
                self.refused["retained"] += 1
                log.warning("MQTT: a retained message on %s ignored: commands are never taken "
                            "from retained messages (docs/mqtt.md, Security)", message.topic.value)
                continue
            payload = message.payload if isinstance(message.payload, bytes) else (
                str(message.payload).encode() if message.payload is not None else b"")
            try:
                if parts[1:] == ["request"]:
                    self._handle_request(feed, payload, message.properties)
                elif parts[1:2] == ["sim"]:
                    self._handle_sim(feed, parts[2:], payload)
            except Exception:  # one bad message must never end the session
                log.exception("MQTT message on %s failed", message.topic.value)
            await self._inbox_pace.turn()
            await asyncio.sleep(0)  # a flood waits in the bounded inbox; the hosts go first

    def _feed(self, address: str) -> _ModuleFeed | None:
        for feed in self._feeds:
            if str(feed.module.slot) == address:
                return feed
        return None

    def _handle_request(self, feed: _ModuleFeed, payload: bytes,
                        properties: Properties | None) -> None:
        response_topic = getattr(properties, "ResponseTopic", None) if properties else None
        correlation = getattr(properties, "CorrelationData", None) if properties else None
        topic = response_topic or f"{feed.base}/reply"
        as_json = payload[:1] == b"{" or len(payload) != FRAME_LENGTH
        route = _ReplyRoute(self, topic, correlation, as_json)
        route.endpoint = f"mqtt {feed.base}/request"  # how the trace names it
        if as_json:
            try:
                request = request_from_json(payload, feed.module.address)
            except RequestError as exc:
                self.enqueue(_Outgoing(topic, json.dumps({"error": str(exc)}).encode(),
                                       correlation=correlation))
                return
        else:
            try:
                request = decode_request(payload)
            except ChecksumError:
                refusal = feed.module.checksum_error_reply()
                if self.simulation.tracer is not None:
                    self.simulation.tracer.bad_checksum(payload, route, [(feed.module, refusal)])
                route.send(refusal)
                return
        if not self.allow_commands and request.opcode not in READ_ONLY_OPCODES:
            self.refused["commands"] += 1
            log.warning("MQTT: a command that changes the module refused on %s/request "
                        "(--mqtt-commands is off)", feed.base)
            self.enqueue(_Outgoing(topic, json.dumps({"error": COMMANDS_OFF}).encode(),
                                   correlation=correlation))
            return
        for _, reply in self.simulation.execute_on([feed.module], request, Interface.SERIAL,
                                                   route):
            route.send(reply)

    def _handle_sim(self, feed: _ModuleFeed, path: list[str], payload: bytes) -> None:
        try:
            if path[:1] and path[0] in FAULT_TOPICS:
                if not self.allow_faults:
                    raise FaultSpecError("faults over MQTT are off: start tmcl-server with "
                                         "--mqtt-faults to allow them")
                injector = FaultInjector.of(self.simulation)
                apply_fault_message(injector, feed.module, path, payload)
                self.enqueue(_Outgoing(f"{self.settings.prefix}/faults",
                                       json.dumps(injector.describe()).encode(), retain=True))
            else:
                apply_sim_message(feed.module, path, payload)
        except (WorldTopicError, FaultSpecError) as exc:
            self.enqueue(_Outgoing(f"{feed.base}/sim_error",
                                   json.dumps({"topic": "/".join(["sim", *path]),
                                               "error": str(exc)}).encode()))
        self.simulation.notify_changed()
