"""The simulated CAN bus: a wire inside the simulator that modules and gateways share.

Every party attached to a :class:`SimulatedCanBus` sees every frame any *other* party sends,
as on a real wire (a CAN controller does not receive its own frames).  The parties are:

* the simulator's modules, together as one :class:`ModuleNode` (below),
* python-can buses (``--can INTERFACE:CHANNEL``, can_bridge.py),
* the virtual SLCAN adapter (``--slcan-pty``, slcan.py),
* every socketcand client (``--socketcand``, socketcand.py).

Frames are :class:`can.Message` objects and are delivered synchronously, in order, on the
server's event loop.  The server owns one bus (``--can-bus NAME`` names it) and hands it to
every CAN transport it builds.
"""

from __future__ import annotations

import asyncio
import logging
from collections import Counter, deque
from typing import Protocol

import can

from tmcl_server.delivery import Delivery
from tmcl_server.protocol import CAN_PAYLOAD_LENGTH, AnyReply, Reply, decode_can_request
from tmcl_server.simulation import Simulation
from tmcl_server.transports.can import DEFAULT_BUS_NAME, check_bus_name
from tmcl_spec.parameters import GP

log = logging.getLogger(__name__)

#: Data lengths of a TMCL request: 7, or 8 when the host appends a pad byte (pytrinamic does).
REQUEST_LENGTHS = (CAN_PAYLOAD_LENGTH, CAN_PAYLOAD_LENGTH + 1)
#: Why a frame is ignored, by its counter in ModuleNode.stats (the trace says this).
_IGNORED = {"error_frames": "an error frame", "remote": "a remote frame",
            "extended": "an extended (29-bit) id", "foreign": "no module has this CAN id",
            "bad_length": "not 7 or 8 data bytes"}


class CanParty(Protocol):
    """Something attached to the simulated bus."""

    def on_frame(self, frame: can.Message) -> None:
        """A frame another party sent.  Must not raise; the bus logs it if it does."""


class FrameTiming(Protocol):
    """Frames at a bit rate (``--wire-timing``: transports/wire.py's ``CanTiming``): what the
    bus calls instead of delivering a frame at once."""

    #: How long a module takes to answer (s), before its reply goes on the wire.
    processing_s: float

    def transmit(self, bus: SimulatedCanBus, frame: can.Message, sender: CanParty | None,
                 after_s: float = 0.0) -> None:
        """Deliver ``frame`` (``bus.deliver_now``) when its last bit would have gone."""
        ...

    def close(self) -> None:
        """Stop (the server closes)."""
        ...


class SimulatedCanBus:
    """One wire.  Not thread-safe: every party lives on the server's event loop."""

    def __init__(self, name: str = DEFAULT_BUS_NAME) -> None:
        self.name = name
        #: The simulator's modules on this bus (set by :func:`open_can_bus`).
        self.modules: ModuleNode | None = None
        self._parties: tuple[CanParty, ...] = ()
        self._pending: deque[tuple[can.Message, CanParty | None]] = deque()
        self._delivering = False
        #: ``--wire-timing``: frames take their time on the wire (transports/wire.py); None: instant.
        self.timing: FrameTiming | None = None
        #: Frames carried (``frames``) and party failures (``party_errors``).
        self.stats: Counter[str] = Counter()

    def attach(self, party: CanParty) -> None:
        if party not in self._parties:
            self._parties = (*self._parties, party)

    def detach(self, party: CanParty) -> None:
        self._parties = tuple(p for p in self._parties if p is not party)

    @property
    def parties(self) -> tuple[CanParty, ...]:
        return self._parties

    def send(self, frame: can.Message, sender: CanParty | None, after_s: float = 0.0) -> None:
        """Put ``frame`` on the wire: every party but the sender receives it.

        A frame sent while another is being delivered (a module's reply) waits for it, so
        every party hears the frames in the order they were sent, as on a wire.  ``after_s``:
        the sender starts sending that much later (a module's processing time, a late reply);
        with wire timing on, the frame arrives when its last bit would have.
        """
        if self.timing is not None:
            self.timing.transmit(self, frame, sender, after_s)
        elif after_s > 0:
            asyncio.get_running_loop().call_later(after_s, self.deliver_now, frame, sender)
        else:
            self.deliver_now(frame, sender)

    def deliver_now(self, frame: can.Message, sender: CanParty | None) -> None:
        """The frame's last bit has gone: every party but the sender receives it now."""
        self._pending.append((frame, sender))
        if self._delivering:
            return
        self._delivering = True
        try:
            while self._pending:
                self._deliver(*self._pending.popleft())
        finally:
            self._delivering = False

    def _deliver(self, frame: can.Message, sender: CanParty | None) -> None:
        self.stats["frames"] += 1
        for party in self._parties:  # a snapshot: parties may attach or detach meanwhile
            if party is sender:
                continue
            try:
                party.on_frame(frame)
            except Exception:  # one broken party must not silence the wire for the others
                self.stats["party_errors"] += 1
                log.exception("CAN party %r failed on frame %s", party, frame)


def can_reply_data(reply: AnyReply, request_length: int) -> bytes:
    """The reply payload, padded with 0 to mirror an 8-byte request (the version string is 8)."""
    data = reply.encode_can()
    if len(data) < request_length:
        data += bytes(request_length - len(data))
    return data


class _EventSink:
    """Where a module's 138 "target reached" event goes: onto the bus, as long as its request."""

    __slots__ = ("length", "node")

    def __init__(self, node: ModuleNode, length: int) -> None:
        self.node = node
        self.length = length

    def send_unsolicited(self, reply: Reply) -> None:
        self.node.send_event(reply, self.length)

    @property
    def endpoint(self) -> str:
        """How the trace names the requests that came this way."""
        return f"can {self.node.bus.name}"


class ModuleNode:
    """The simulator's modules on the bus: each one acts on frames with its CAN id (GP 71/83).

    The modules form one party, so a module never takes another module's reply for a request
    (it would on a real wire if its CAN id equalled a reply id, e.g. module 2 with GP 70 = 2).
    Frames that are not TMCL requests are ignored and counted in :attr:`stats`.
    """

    def __init__(self, bus: SimulatedCanBus, simulation: Simulation) -> None:
        self.bus = bus
        self.simulation = simulation
        self.stats: Counter[str] = Counter()
        self._sinks = {length: _EventSink(self, length) for length in REQUEST_LENGTHS}

    def on_frame(self, frame: can.Message) -> None:
        try:
            self._handle(frame)
        except Exception:  # never let one frame stop the bus
            self.stats["errors"] += 1
            log.exception("CAN frame %s failed", frame)

    def _handle(self, frame: can.Message) -> None:
        if frame.is_error_frame:
            return self._ignore(frame, "error_frames")
        if frame.is_remote_frame:
            return self._ignore(frame, "remote")
        if frame.is_extended_id:
            return self._ignore(frame, "extended")
        can_id = frame.arbitration_id
        if not self.simulation.accepts_can(can_id):
            return self._ignore(frame, "foreign")
        length = len(frame.data)
        if frame.is_fd or length not in REQUEST_LENGTHS:
            return self._ignore(frame, "bad_length")
        self.stats["requests"] += 1
        request = decode_can_request(can_id, frame.data)
        processing = self.bus.timing.processing_s if self.bus.timing is not None else 0.0
        for module, reply in self.simulation.handle_can_request(request, self._sinks[length]):
            if type(reply) is Delivery:
                self._deliver(module.can_reply_id, reply, length, processing)
            else:
                self._send(module.can_reply_id, can_reply_data(reply, length), processing)

    def _deliver(self, can_id: int, delivery: Delivery, length: int, processing_s: float) -> None:
        """A reply the faults altered.  A CAN frame cannot be torn (its pauses add up to a
        delay), and one with a bad checksum fails its CRC: nobody receives it."""
        if delivery.bad_checksum:
            self.stats["replies_lost"] += 1
            return
        frames = [can_reply_data(delivery.reply, length)] * delivery.copies
        if delivery.garbage:  # a frame of junk from the reply id first
            frames.insert(0, delivery.garbage[:8])
        delay = delivery.total_delay_s + processing_s
        if delay > 0 and self.bus.timing is None:  # one timer for all: they keep their order
            asyncio.get_running_loop().call_later(delay, self._send_all, can_id, frames, 0.0)
        else:
            self._send_all(can_id, frames, delay)

    def _send_all(self, can_id: int, frames: list[bytes], after_s: float) -> None:
        for data in frames:
            self._send(can_id, data, after_s)

    def _ignore(self, frame: can.Message, reason: str) -> None:
        """A frame the modules do not act on: counted, and traced when the trace is on."""
        self.stats[reason] += 1
        if self.simulation.tracer is not None:
            self.simulation.tracer.can_ignored(self.bus.name, frame.arbitration_id,
                                               bytes(frame.data), _IGNORED[reason])

    def send_event(self, reply: Reply, length: int) -> None:
        """A 138 event: the module is found by its CAN id, which the reply carries."""
        modules = self.simulation.modules
        reply_id = next((m.can_reply_id for m in modules if m.can_id == reply.module), None)
        if reply_id is None:  # its CAN id changed since: GP 70's factory default
            reply_id = modules[0].type.global_parameters[0][GP.CAN_REPLY_ID].default
        self._send(reply_id, can_reply_data(reply, length))

    def _send(self, can_id: int, data: bytes, after_s: float = 0.0) -> None:
        self.stats["replies"] += 1
        self.bus.send(can.Message(arbitration_id=can_id, is_extended_id=False, data=data), self, after_s)


def open_can_bus(simulation: Simulation, name: str = DEFAULT_BUS_NAME) -> SimulatedCanBus:
    """A new bus with the simulation's modules on it (the server owns one per simulation)."""
    check_bus_name(name)
    bus = SimulatedCanBus(name)
    bus.modules = ModuleNode(bus, simulation)
    bus.attach(bus.modules)
    return bus

