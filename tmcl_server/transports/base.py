"""What every transport is (:class:`Transport`), what the server gives it (:class:`TransportHost`),
and the pieces shared by the byte-stream transports (TCP, pty, serial port)."""

from __future__ import annotations

import asyncio
import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from enum import Enum
from typing import TYPE_CHECKING, Any, Protocol

from tmcl_server.delivery import Delivery
from tmcl_server.dispatch import ReplySink
from tmcl_server.protocol import FRAME_LENGTH, AnyReply, FrameAssembler, Reply
from tmcl_server.simulation import Routed, Simulation

if TYPE_CHECKING:
    from tmcl_server.transports.can.bus import SimulatedCanBus

log = logging.getLogger(__name__)


class TransportHost(Protocol):
    """What the server hands a transport it builds: the simulation, and shared resources."""

    simulation: Simulation

    def option(self, name: str) -> Any:
        """A server setting a transport may need (e.g. ``mqtt_rate``)."""

    def can_bus(self) -> SimulatedCanBus:
        """The simulated CAN bus the server owns (created, with the modules on it, on first use)."""


class Transport(ABC):
    """A listening endpoint.  ``kind`` is its key in the ready file (``tcp``, ``pty``, ...)."""

    kind: str

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> Transport:
        """The endpoint for one command-line argument (``127.0.0.1:2323``, a pty path, ...)."""
        return cls(host.simulation, argument)  # type: ignore[call-arg]

    @abstractmethod
    async def start(self) -> list[str]:
        """Open the endpoint; return the addresses hosts can use (for the ready file)."""

    @abstractmethod
    async def close(self) -> None:
        """Stop serving and release every resource (sockets, pty links)."""


class LinkMode(Enum):
    """How a byte-stream endpoint addresses the modules behind it (docs/protocol.md)."""

    #: The module's own USB port: one module, which answers whatever the address byte says.
    USB = "usb"
    #: An RS-485 bus: a module acts only on frames with its address (GP 66 / GP 87).
    RS485 = "rs485"


def split_endpoint_options(argument: str, known: Iterable[str] = ("mode",)) -> tuple[str, dict[str, str]]:
    """``PATH[,key=value]...`` -> (PATH, options); an unknown key is a ValueError."""
    base, names = argument, tuple(known)
    options: dict[str, str] = {}
    while True:
        head, sep, tail = base.rpartition(",")
        if not sep or "=" not in tail:
            return base, options
        key, _, value = tail.partition("=")
        if key not in names:
            raise ValueError(f"unknown option {key!r} in {argument!r} (known: {', '.join(names)})")
        options[key] = value
        base = head


def link_mode(simulation: Simulation, options: dict[str, str], endpoint: str,
              default: LinkMode | None = None) -> LinkMode:
    """The ``mode=`` option, else ``default``, else USB for one module and RS-485 for several."""
    text = options.get("mode")
    if text is None:
        if default is not None:
            return default
        return LinkMode.USB if len(simulation.modules) == 1 else LinkMode.RS485
    try:
        mode = LinkMode(text.lower().replace("-", ""))
    except ValueError:
        raise ValueError(f"{endpoint}: mode must be usb or rs485, got {text!r}") from None
    if mode is LinkMode.USB and len(simulation.modules) != 1:
        raise ValueError(f"{endpoint}: mode=usb is one module's own port, but the server has "
                         f"{len(simulation.modules)} modules; use mode=rs485")
    return mode


#: Takes one 9-byte frame and the session's reply sink; returns who answered what.
Router = Callable[[bytes, ReplySink], list[Routed]]


def frame_router(simulation: Simulation, mode: LinkMode) -> Router:
    """What a stream session calls with each frame: bus addressing, or the one module's port."""
    if mode is LinkMode.RS485:
        return simulation.handle_serial_frame
    module = simulation.modules[0]
    return lambda frame, sink: simulation.handle_frame_for(module, frame, sink)


class ByteSession(Protocol):
    """What a byte-stream endpoint (a pty, a serial port) feeds: TMCL frames or SLCAN lines."""

    def feed(self, data: bytes) -> None: ...

    def close(self) -> None: ...


class StreamSession:
    """One byte stream speaking 9-byte TMCL frames: a TCP client, a pty, a serial port.

    It owns the 5 ms resynchronisation of torn frames and the GP 75 reply delay, and it is
    the sink for replies that arrive later (command 138 events).

    The pause is a pause on the *line*, and a read tells only when the server got round to
    the bytes, not when they arrived: a server busy with a burst, another client or a program
    reads late.  So a partial frame is not judged when the next bytes are read but by a timer
    5 ms after its last byte: if by then (however late the busy loop runs it) no bytes wait
    in the kernel (``queued``), the line was silent and the fragment is dropped; otherwise the
    waiting bytes continue it.  A short pause of the host never tears a frame, however busy
    the server; a real pause on an idle server drops it within the loop's timer resolution.
    """

    __slots__ = ("_assembler", "_loop", "_queued", "_resync", "_route", "_write", "closed",
                 "endpoint", "heard_valid", "rs485", "simulation")

    def __init__(self, simulation: Simulation, write: Callable[[bytes], None],
                 loop: asyncio.AbstractEventLoop, mode: LinkMode = LinkMode.RS485,
                 endpoint: str = "", queued: Callable[[], int] | None = None) -> None:
        self.simulation = simulation
        #: How the trace names this stream (``tcp 127.0.0.1:40512``, ``pty /tmp/ttyTMCL0``).
        self.endpoint = endpoint
        self._write = write
        self._loop = loop
        self._assembler = FrameAssembler()
        self._route = frame_router(simulation, mode)
        #: How many bytes wait unread in the kernel (None: the transport cannot tell).
        self._queued = queued
        #: The timer that checks for a pause while a partial frame is held back.
        self._resync: asyncio.TimerHandle | None = None
        #: GP 75 (telegram pause) delays replies on RS-485 only.
        self.rs485 = mode is LinkMode.RS485
        self.closed = False
        #: A frame with a right checksum came (a listener's admission: transports/admission.py).
        self.heard_valid = False

    def feed(self, data: bytes) -> None:
        assembler = self._assembler
        if len(data) == FRAME_LENGTH and not assembler.buffer:  # one whole frame: usual case
            frames: Iterable[bytes] = (data,)
        else:
            frames = assembler.feed(data)
        for frame in frames:
            if not self.heard_valid and sum(frame[:8]) & 0xFF == frame[8]:
                self.heard_valid = True
            for module, reply in self._route(frame, self):
                delay = module.reply_delay_s if self.rs485 else 0.0
                if delay or self.closed or type(reply) is Delivery:
                    self._deliver(reply, delay)
                else:  # the common case, kept short: it runs for every request
                    try:
                        self._write(reply.encode())
                    except OSError:
                        self.closed = True
        if assembler.buffer:
            # The pause counts from when we are ready for more bytes again, not from when a
            # long burst began to be processed.
            assembler.last_byte_ns = time.monotonic_ns()
            if self._resync is None and not self.closed:
                self._resync = self._loop.call_later(assembler.gap_ns / 1e9, self._check_pause)

    def _check_pause(self) -> None:
        """The timer: drop the partial frame if the line has been silent for more than 5 ms."""
        self._resync = None
        assembler = self._assembler
        if self.closed or not assembler.buffer or assembler.last_byte_ns is None:
            return
        now = time.monotonic_ns()
        wait_ns = assembler.last_byte_ns + assembler.gap_ns - now
        if wait_ns >= 0 or self._waiting():
            # Too early (the loop's timers round to the millisecond, or bytes came since), or
            # bytes arrived while we were busy and wait to be read: they continue the frame.
            self._resync = self._loop.call_later(max(wait_ns, 0) / 1e9 + 0.0005, self._check_pause)
            return
        tracer = self.simulation.tracer
        if tracer is not None:
            tracer.torn_frame(self.endpoint, assembler, now)
        assembler.drop()

    def _waiting(self) -> bool:
        queued = self._queued
        if queued is None:
            return False
        try:
            return queued() > 0
        except (OSError, ValueError):
            return False

    def _deliver(self, reply: AnyReply | Delivery, delay_s: float) -> None:
        """A reply after the GP 75 pause, or one the faults altered (late, torn, ...)."""
        if not isinstance(reply, Delivery):
            self._send(reply.encode(), delay_s)
            return
        for pause, data in reply.stream_pieces():
            delay_s += pause
            self._send(data, delay_s)

    def _send(self, data: bytes, delay_s: float = 0.0) -> None:
        if self.closed:
            return
        if delay_s > 0:
            self._loop.call_later(delay_s, self._send, data)
            return
        self._write_now(data)

    def _write_now(self, data: bytes) -> None:
        if self.closed:
            return
        try:
            self._write(data)
        except OSError as exc:  # the peer vanished; nothing else is affected
            log.debug("write failed: %s", exc)
            self.closed = True

    def send_unsolicited(self, reply: Reply) -> None:
        self._send(reply.encode())

    def reading_resumed(self) -> None:
        """We stopped reading (the peer did not read its replies): that wait was ours, not
        a pause on the line, so it must not tear the frame in progress."""
        if self._assembler.buffer:
            self._assembler.last_byte_ns = time.monotonic_ns()

    def close(self) -> None:
        self.closed = True
        if self._resync is not None:
            self._resync.cancel()
            self._resync = None
