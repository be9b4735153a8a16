"""The telegram trace (``tmcl-server --trace``): every request, reply, event and dropped frame.

A :class:`Tracer` attached to a :class:`~tmcl_server.simulation.Simulation` is called from the
few places that already branch on what happens to a frame (the router, the byte-stream
session, the CAN node); with no tracer those places test one attribute against None and go
on, so tracing off costs nothing measurable.  Each line carries the wall time, the simulated
time, the endpoint (``tcp 127.0.0.1:40512``, ``pty /tmp/ttyTMCL0``, ``can can0 id 001``,
``mqtt tmcl/1/request``), the module address and the decoded text::

    01:01:02.084549   1.261011  tcp 127.0.0.1:40522  #1  cmd   SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK
    01:01:03.709114   2.885626  tcp 127.0.0.1:40562  #7  drop  no module has address 7: no reply

(columns narrowed here).  A request and its one reply share a ``cmd`` line; ``req`` and
``reply`` lines stand apart when something came between or several modules answered.

``--trace-format jsonl`` writes the same as one JSON object per line, with the fields split
out.  Cost on the wire: while a request runs the tracer only notes what happened (a tuple of
numbers and references); decoding and writing happen in batches at most 50 ms later, one
timer, one pass and one write per batch, so a request pays a few microseconds and the host
does not wait for the file (scripts/bench_wire.py measures it).
"""

from __future__ import annotations

import asyncio
import functools
import json
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TextIO

from tmcl_server.decode import (
    Vocabulary,
    describe_outcome,
    describe_program_record,
    describe_reply,
    describe_request,
    describe_version_string,
    opcode_name,
    status_name,
    vocabulary,
)
from tmcl_server.dispatch import Interface, ReplySink
from tmcl_server.protocol import FRAME_LENGTH, AnyReply, FrameAssembler, RawReply, Reply, Request, checksum
from tmcl_spec.commands import ALWAYS_REPLIED, Opcode
from tmcl_spec.numbers import NS_PER_S, to_int32
from tmcl_spec.parameters import GP

if TYPE_CHECKING:
    from tmcl_server.module import ModuleEvent, TMCLModule
    from tmcl_server.simulation import Routed, Simulation

FORMATS = ("text", "jsonl")
#: What a frame's endpoint is called when the transport gives it no name.
UNNAMED = "-"
#: With an event loop, happenings are decoded and written in batches: at most this late
#: (wall seconds) ...
FLUSH_DELAY_S = 0.05
#: ... or when this many wait.
MAX_PENDING = 512

_json_string = json.encoder.encode_basestring  # type: ignore[attr-defined]
#: One noted happening: (formatter, wall time, simulated ns, formatter arguments ...).
_Note = tuple[Any, ...]
#: What a formatter returns: kind, endpoint, module address, text, JSON fields (or None).
#: (kind, endpoint, address, text, JSON fields: a dict, members already in JSON, or None)
_Line = tuple[str, str, int, str, dict[str, Any] | str | None]
#: A noted happening as listeners get it (opaque: :meth:`Tracer.decode` turns it into lines).
TraceNote = _Note
#: A decoded line: wall time, simulated ns, kind, endpoint, module address, text.
TraceLine = tuple[float, int, str, str, int, str]


def endpoint_of(sink: object) -> str:
    """The name a transport gave the connection a request came from (``endpoint`` attribute)."""
    return getattr(sink, "endpoint", None) or UNNAMED


@functools.lru_cache(maxsize=4096)
def _request_text(opcode: int, type_: int, motor: int, value: int, words: Vocabulary) -> str:
    """Hosts poll the same few requests over and over: decode each once."""
    return describe_request(opcode, type_, motor, value, words)


_outcome_text = functools.lru_cache(maxsize=4096)(describe_outcome)


@functools.lru_cache(maxsize=4096)
def _exchange_text(request: Request, status: int, opcode: int, value: int, words: Vocabulary) -> str:
    """``SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK``: a poll loop repeats these."""
    return (f"{_request_text(request.opcode, request.type, request.motor, request.value, words)} "
            f"{_outcome_text(status, opcode, request.type, value)}")


def _json_value(value: Any) -> str:
    """JSON for the plain values trace fields hold, without json.dumps's per-call set-up."""
    if value is None:
        return "null"
    kind = type(value)
    if kind is int:
        return str(value)
    if kind is str:
        return _json_string(value)
    return json.dumps(value, ensure_ascii=False)


class _TracedSink:
    """Stands in for the sink a 138 request leaves with the module, so its events are traced."""

    __slots__ = ("_sink", "_tracer", "endpoint")

    def __init__(self, tracer: Tracer, sink: ReplySink, endpoint: str) -> None:
        self._tracer = tracer
        self._sink = sink
        self.endpoint = endpoint

    def send_unsolicited(self, reply: Reply) -> None:
        self._tracer.unsolicited(self.endpoint, reply)
        self._sink.send_unsolicited(reply)


class Tracer:
    """Writes trace lines for one simulation to a text stream (``text`` or ``jsonl``), and
    hands every batch of noted happenings to its :attr:`listeners` (the dashboard's wire view),
    which decode only what they show (:meth:`decode`)."""

    def __init__(self, stream: TextIO | None, fmt: str = "text",
                 wall: Callable[[], float] = time.time) -> None:
        if fmt not in FORMATS:
            raise ValueError(f"trace format must be one of {', '.join(FORMATS)}, not {fmt!r}")
        #: Where lines are written; None: only the listeners get the happenings.
        self.stream = stream
        self.jsonl = fmt == "jsonl"
        #: Called with every batch of notes, in order, when it is flushed.
        self.listeners: list[Callable[[list[TraceNote]], None]] = []
        self._wall = wall
        self._simulation: Simulation | None = None
        self._listeners: list[tuple[TMCLModule, Callable[[ModuleEvent], None]]] = []
        self._notes: list[_Note] = []
        self._loop: asyncio.AbstractEventLoop | None = None
        self._flush_scheduled = False
        #: The request being executed, noted together with its reply (one note, not two).
        self._stash: tuple[Any, ...] | None = None
        self._second = -1
        self._second_text = ""
        #: "endpoint  #address kind " column text, padded once per combination
        self._pads: dict[tuple[str, int, str], str] = {}

    # -- attaching ----------------------------------------------------------------------------

    def attach(self, simulation: Simulation, loop: asyncio.AbstractEventLoop | None = None) -> Tracer:
        """Trace ``simulation``; with a ``loop``, lines are decoded and written in batches."""
        self._simulation = simulation
        self._loop = loop
        simulation.tracer = self
        for module in simulation.modules:
            listener = self._listener(module)
            module.listeners.append(listener)
            self._listeners.append((module, listener))
        return self

    def detach(self) -> None:
        if self._simulation is not None and self._simulation.tracer is self:
            self._simulation.tracer = None
        for module, listener in self._listeners:
            if listener in module.listeners:
                module.listeners.remove(listener)
        self._listeners.clear()
        self.flush()

    def _listener(self, module: TMCLModule) -> Callable[[ModuleEvent], None]:
        return lambda event: self.event(module, event)

    # -- what the simulation and the transports report (hot path: note, do not format) --------

    def requested(self, request: Request, interface: Interface, targets: list[TMCLModule],
                  sink: ReplySink | None) -> ReplySink | None:
        """A request is about to run on ``targets``; returns the sink the modules should keep."""
        if interface is Interface.SERIAL:
            endpoint = getattr(sink, "endpoint", None) or UNNAMED
        else:
            endpoint = self._endpoint(sink, interface, request.address)
        # the modules' time: they were brought up to the clock when the request arrived
        now = targets[0].now_ns if targets else self._now()
        self._stash = (self._request_line, self._wall(), now, endpoint, request,
                       targets[0].type if targets else None, interface)
        if sink is not None and request.opcode == Opcode.TARGET_REACHED_EVENT:
            return _TracedSink(self, sink, endpoint)  # the module keeps it for the events
        return sink

    def _unstash(self) -> None:
        """Something happens while a request runs: its line goes first."""
        stash, self._stash = self._stash, None
        if stash is not None:
            self._note(stash)

    def replied(self, request: Request, interface: Interface, targets: list[TMCLModule],
                routed: list[Routed], sink: ReplySink | None) -> None:
        """A request ran: one line for it and its reply, or one per reply and why a target sent none."""
        stash = self._stash
        if stash is not None and len(routed) == 1 and len(targets) == 1:  # the usual case
            self._stash = None
            module, reply = routed[0]
            self._note((self._exchange, stash[1], stash[2], stash[3], request, stash[5], interface,
                        module.address, reply, (f" reply id {module.can_reply_id:03x}"
                                                if interface is Interface.CAN else module.reply_delay_s)))
            return
        if stash is None:  # noted already (an event came between)
            wall, now, endpoint = self._wall(), self._now(), self._endpoint(sink, interface, request.address)
        else:
            wall, now, endpoint = stash[1], stash[2], stash[3]
        self._unstash()
        for module, reply in routed:
            extra = (f" reply id {module.can_reply_id:03x}" if interface is Interface.CAN else
                     module.reply_delay_s)
            self._note((self._reply_line, wall, now, endpoint, module.address, module.type, request,
                        reply, extra))
        if len(routed) != len(targets):
            answered = {id(module) for module, _ in routed}
            for module in targets:
                if id(module) not in answered:
                    self._note((self._silence_line, wall, now, endpoint, module.address, module.type,
                                request, self._silence(module, request)))
        if len(routed) > 1:
            what = "CAN id" if interface is Interface.CAN else "address"
            self._note((self._plain_line, wall, now, "warn", endpoint, request.address,
                        f"{len(routed)} modules answered {what} {request.address}: on a real bus "
                        "their replies would collide", None))

    def foreign(self, frame: bytes, sink: ReplySink | None) -> None:
        """A serial frame no module answers to (RS-485: nobody replies, not even an error)."""
        self._note((self._plain_line, self._wall(), self._now(), "drop", endpoint_of(sink), frame[0],
                    f"no module has address {frame[0]}: no reply ({frame.hex(' ')})",
                    {"reason": "foreign address", "bytes": frame.hex()}))

    def bad_checksum(self, frame: bytes, sink: ReplySink | None, routed: list[Routed]) -> None:
        """A frame with a wrong checksum: TMCL answers it with status 1 (manual Table 4)."""
        endpoint = endpoint_of(sink)
        wall, now = self._wall(), self._now()
        self._note((self._plain_line, wall, now, "req", endpoint, frame[0],
                    f"wrong checksum {frame[8]:#04x} (should be {checksum(frame[:8]):#04x}): "
                    f"{frame.hex(' ')}", {"reason": "wrong checksum", "bytes": frame.hex()}))
        for module, reply in routed:
            if isinstance(reply, Reply):  # status 1, the one reply a bad checksum gets
                self._note((self._plain_line, wall, now, "reply", endpoint, module.address,
                            f"(wrong checksum) {describe_reply(reply)}", self._reply_fields(reply)))

    def torn_frame(self, endpoint: str, assembler: FrameAssembler, now_ns: int) -> None:
        """Bytes of an incomplete frame about to be dropped after the 5 ms pause."""
        if assembler.expired(now_ns):
            gap_ms = (now_ns - (assembler.last_byte_ns or now_ns)) / 1e6
            data = bytes(assembler.buffer)
            self._note((self._plain_line, self._wall(), self._now(), "drop", endpoint, data[0],
                        f"torn frame: {len(data)} of {FRAME_LENGTH} bytes, then a {gap_ms:.1f} ms "
                        f"pause (> 5 ms): dropped ({data.hex(' ')})",
                        {"reason": "torn frame", "bytes": data.hex()}))

    def can_ignored(self, bus: str, can_id: int, data: bytes, reason: str) -> None:
        """A CAN frame the modules did not act on (another node's id, wrong length, ...)."""
        self._note((self._plain_line, self._wall(), self._now(), "drop", f"can {bus}", can_id,
                    f"id {can_id:03x} [{len(data)}] {data.hex(' ')}: {reason}, no reply",
                    {"reason": reason, "can_id": can_id, "bytes": data.hex()}))

    def unsolicited(self, endpoint: str, reply: Reply) -> None:
        """A reply nobody asked for just now: a command 138 "target reached" event."""
        self._note((self._plain_line, self._wall(), self._now(), "event", endpoint, reply.module,
                    f"{opcode_name(reply.opcode)} {describe_reply(reply)}", self._reply_fields(reply)))

    def injected(self, endpoint: str, module: TMCLModule, request: Request | None, what: str,
                 fields: dict[str, Any]) -> None:
        """A fault was injected on purpose (tmcl_server/faults.py): a ``fault`` line."""
        self._note((self._fault_line, self._wall(), module.now_ns, endpoint, module.address, module.type,
                    request, what, fields))

    def event(self, module: TMCLModule, event: ModuleEvent) -> None:
        """Something happened inside a module (axis events, interrupts, program start/stop)."""
        parts = [event.kind]
        if event.axis is not None:
            parts.append(f"axis {event.axis}")
        data = {k: v for k, v in event.data.items() if v is not None}
        parts.extend(f"{key} {value}" for key, value in data.items())
        fields = {"event": event.kind, **({"axis": event.axis} if event.axis is not None else {}), **data}
        self._note((self._plain_line, self._wall(), event.time_ns, "event", UNNAMED, module.address,
                    " ".join(parts), fields))

    # -- formatting (after the reply went out) ------------------------------------------------

    def _exchange(self, endpoint: str, request: Request, kind: Any, interface: Interface, address: int,
                  reply: AnyReply, extra: str | float) -> list[_Line]:
        """The usual case, a request and its one reply: one ``cmd`` line for both."""
        if type(reply) is Reply and not (interface is Interface.SERIAL and extra):  # kept lean
            words = vocabulary(kind)
            text = _exchange_text(request, reply.status, reply.opcode, reply.value, words)
            if extra:  # CAN: the reply's id
                endpoint += extra  # type: ignore[operator]
            if not self.jsonl:
                return [("cmd", endpoint, address, text, None)]
            if interface is Interface.CAN:
                sent, answered = request.encode_can(), reply.encode_can()
            else:
                sent, answered = request.encode(), reply.encode()
            name = words.parameter_name(request.opcode, request.type, request.motor)
            parameter = f',"parameter":"{name}"' if name else ""  # names are plain identifiers
            members = (f',"opcode":{request.opcode},"type":{request.type},"motor":{request.motor},'
                       f'"value":{request.value},"bytes":"{sent.hex()}"{parameter},'
                       f'"status":{reply.status},"status_name":"{status_name(reply.status)}",'
                       f'"reply_value":{to_int32(reply.value)},"reply_bytes":"{answered.hex()}"')
            return [("cmd", endpoint, address, text, members)]
        (_, _, _, _, request_fields), = self._request_line(endpoint, request, kind, interface)
        (_, endpoint, address, text, reply_fields), = self._reply_line(endpoint, address, kind, request,
                                                                        reply, extra)
        if isinstance(request_fields, dict) and isinstance(reply_fields, dict):
            reply_fields.pop("opcode", None)  # the request's
            request_fields.update(reply_fields)
        return [("cmd", endpoint, address, text, request_fields)]

    def _request_line(self, endpoint: str, request: Request, kind: Any,
                      interface: Interface) -> list[_Line]:
        words = vocabulary(kind)
        text = _request_text(request.opcode, request.type, request.motor, request.value, words)
        fields = None
        if self.jsonl:
            data = request.encode_can() if interface is Interface.CAN else request.encode()
            fields = {"opcode": request.opcode, "type": request.type, "motor": request.motor,
                      "value": request.value, "bytes": data.hex()}
            name = words.parameter_name(request.opcode, request.type, request.motor)
            if name:
                fields["parameter"] = name
        return [("req", endpoint, request.address, text, fields)]

    def _reply_line(self, endpoint: str, address: int, kind: Any, request: Request,
                    reply: AnyReply, extra: str | float) -> list[_Line]:
        words = vocabulary(kind)
        subject = _request_text(request.opcode, request.type, request.motor, request.value, words)
        if isinstance(reply, RawReply):
            data = reply.data
            if request.opcode == Opcode.GET_FIRMWARE_VERSION:
                text = describe_version_string(data)
            else:
                text = describe_program_record(data, request.value, words)
            fields = {"reply_bytes": data.hex()} if self.jsonl else None
        else:
            text = _outcome_text(reply.status, reply.opcode, request.type, reply.value)
            fields = self._reply_fields(reply) if self.jsonl else None
        if isinstance(extra, str):  # CAN: the reply's id
            endpoint += extra
        elif extra:  # serial: the GP 75 pause before the reply
            text += f" (after the GP 75 pause of {extra * 1000:g} ms)"
        return [("reply", endpoint, address, f"{subject} {text}", fields)]

    def _silence_line(self, endpoint: str, address: int, kind: Any, request: Request,
                      why: str) -> list[_Line]:
        text = _request_text(request.opcode, request.type, request.motor, request.value, vocabulary(kind))
        return [("noreply", endpoint, address, f"{text}: {why}", {"reason": why})]

    def _fault_line(self, endpoint: str, address: int, kind: Any, request: Request | None, what: str,
                    fields: dict[str, Any]) -> list[_Line]:
        if request is None:
            return [("fault", endpoint, address, what, {"injected": True, **fields})]
        text = _request_text(request.opcode, request.type, request.motor, request.value, vocabulary(kind))
        if self.jsonl:
            fields = {"opcode": request.opcode, "type": request.type, "motor": request.motor,
                      "value": request.value, **fields}
        return [("fault", endpoint, address, f"{text}: {what}", {"injected": True, **fields})]

    @staticmethod
    def _plain_line(kind: str, endpoint: str, address: int, text: str,
                    fields: dict[str, Any] | None) -> list[_Line]:
        return [(kind, endpoint, address, text, fields)]

    @staticmethod
    def _silence(module: TMCLModule, request: Request) -> str:
        if request.opcode == Opcode.RESTORE_FACTORY_SETTINGS:
            return "the module restarts (command 137): no reply"
        if module.globals[0].get(GP.SUPPRESS_REPLY) and request.opcode not in ALWAYS_REPLIED:
            return "reply suppressed by GP 255"
        return "no reply"

    @staticmethod
    def _reply_fields(reply: Reply) -> dict[str, Any]:
        return {"status": reply.status, "status_name": status_name(reply.status), "opcode": reply.opcode,
                "reply_value": to_int32(reply.value), "reply_bytes": reply.encode().hex()}

    @staticmethod
    def _endpoint(sink: object, interface: Interface, address: int) -> str:
        if isinstance(sink, _TracedSink):
            return sink.endpoint
        endpoint = endpoint_of(sink)
        return f"{endpoint} id {address:03x}" if interface is Interface.CAN else endpoint

    def _now(self) -> int:
        return self._simulation.now_ns if self._simulation is not None else 0

    def _render(self, wall: float, sim_ns: int, lines: list[_Line]) -> str:
        """The lines of one note (they share its wall and simulated time)."""
        if self.jsonl:
            head = f'{{"wall":{wall:.6f},"sim":{sim_ns / NS_PER_S!r},'
            out = []
            for kind, endpoint, address, text, fields in lines:
                body = (f'{head}"endpoint":{_json_string(endpoint)},"module":{address},"kind":"{kind}",'
                        f'"text":{_json_string(text)}')
                if isinstance(fields, str):  # members already in JSON (the usual exchange)
                    body += fields
                elif fields:
                    body += "".join([f',"{key}":{_json_value(value)}' for key, value in fields.items()])
                out.append(body + "}")
            return "\n".join(out)
        second = int(wall)
        if second != self._second:
            self._second = second
            self._second_text = time.strftime("%H:%M:%S", time.localtime(second))
        head = (f"{self._second_text}.{int((wall - second) * 1e6):06d} "
                f"{sim_ns // NS_PER_S:5d}.{sim_ns // 1000 % 1_000_000:06d}  ")
        pads = self._pads
        out = []
        for kind, endpoint, address, text, _ in lines:
            where = pads.get((endpoint, address, kind))
            if where is None:
                if len(pads) > 4096:  # a long-running server sees many client ports come and go
                    pads.clear()
                where = pads[(endpoint, address, kind)] = f"{endpoint:<22}  #{address:<3} {kind:<7} "
            out.append(head + where + text)
        return "\n".join(out)

    def decode(self, note: TraceNote) -> list[TraceLine]:
        """The lines of one note a listener got (formatters use only what was noted, so a note
        decodes the same later)."""
        wall, sim_ns = note[1], note[2]
        return [(wall, sim_ns, kind, endpoint, address, text)
                for kind, endpoint, address, text, _ in note[0](*note[3:])]

    # -- writing ------------------------------------------------------------------------------

    def _note(self, note: _Note) -> None:
        if self._stash is not None:  # something happens while a request runs: the request first
            self._notes.append(self._stash)
            self._stash = None
        notes = self._notes
        notes.append(note)
        if self._loop is None or len(notes) >= MAX_PENDING:
            self.flush()
        elif not self._flush_scheduled:
            self._flush_scheduled = True
            self._loop.call_later(FLUSH_DELAY_S, self.flush)

    def flush(self) -> None:
        """Decode and write everything noted so far (a loop calls this FLUSH_DELAY_S after the
        first note of a batch: one timer, one decoding pass and one write per batch)."""
        self._flush_scheduled = False
        if not self._notes:
            return
        notes, self._notes = self._notes, []
        for listener in list(self.listeners):
            listener(notes)
        if self.stream is None:
            return
        lines = [self._render(note[1], note[2], note[0](*note[3:])) for note in notes]
        try:
            self.stream.write("\n".join(lines) + "\n")
            self.stream.flush()
        except (OSError, ValueError):  # a closed pipe must not stop the simulator
            pass
