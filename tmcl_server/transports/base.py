"""What every transport is (:class:`Transport`), what the server gives it (:class:`TransportHost`),
and the pieces shared by the byte-stream transports (TCP, pty, serial port)."""

from __future__ import annotations

import asyncio
import logging
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any, Protocol

from tmcl_server.protocol import FRAME_LENGTH, FrameAssembler, Reply
from tmcl_server.simulation import Simulation

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


class ByteSession(Protocol):
    """What a byte-stream endpoint (a pty, a serial port) feeds: TMCL frames or SLCAN lines."""

    def feed(self, data: bytes) -> None: ...

    def close(self) -> None: ...


class StreamSession:
    """One byte stream speaking 9-byte TMCL frames: a TCP client, a pty, a serial port.

    It owns the 5 ms resynchronisation of torn frames and the GP 75 reply delay, and it is
    the sink for replies that arrive later (command 138 events).
    """

    __slots__ = ("_assembler", "_loop", "_write", "closed", "endpoint", "simulation")

    def __init__(self, simulation: Simulation, write: Callable[[bytes], None],
                 loop: asyncio.AbstractEventLoop, endpoint: str = "") -> None:
        self.simulation = simulation
        #: How the trace names this stream (``tcp 127.0.0.1:40512``, ``pty /tmp/ttyTMCL0``).
        self.endpoint = endpoint
        self._write = write
        self._loop = loop
        self._assembler = FrameAssembler()
        self.closed = False

    def feed(self, data: bytes) -> None:
        assembler = self._assembler
        now = time.monotonic_ns()
        if len(data) == FRAME_LENGTH and not assembler.buffer:  # one whole frame: usual case
            assembler.last_byte_ns = now
            frames: Iterable[bytes] = (data,)
        else:
            if self.simulation.tracer is not None:  # a torn frame may be about to be dropped
                self.simulation.tracer.torn_frame(self.endpoint, assembler, now)
            frames = assembler.feed(data, now)
        for frame in frames:
            for module, reply in self.simulation.handle_serial_frame(frame, self):
                delay = module.reply_delay_s
                if delay or self.closed:
                    self._send(reply.encode(), delay)
                else:  # the common case, kept short: it runs for every request
                    try:
                        self._write(reply.encode())
                    except OSError:
                        self.closed = True

    def _send(self, data: bytes, delay_s: float = 0.0) -> None:
        if self.closed:
            return
        if delay_s > 0:
            self._loop.call_later(delay_s, self._send, data)
            return
        try:
            self._write(data)
        except OSError as exc:  # the peer vanished; nothing else is affected
            log.debug("write failed: %s", exc)
            self.closed = True

    def send_unsolicited(self, reply: Reply) -> None:
        self._send(reply.encode())

    def close(self) -> None:
        self.closed = True
