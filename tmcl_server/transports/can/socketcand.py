"""A socketcand server in front of the simulated bus: CAN over TCP with no kernel CAN.

Any python-can program joins with ``can.Bus(interface="socketcand", host=..., port=...,
channel=<bus name>)``.  The protocol (linux-can/socketcand, doc/protocol.md) is ASCII
elements ``< ... >``: the server greets ``< hi >``, ``< open NAME >`` selects the bus (BCM
mode), ``< rawmode >`` makes every frame on the bus arrive as ``< frame ID SECS.USECS DATA >``;
``< send ID DLC B0 .. >`` and ``< sendrtr ID DLC >`` transmit, ``< echo >`` echoes.  Each
client is its own party on the bus, so clients see each other's frames as on a wire.  Junk
between elements is skipped; a malformed command is ignored (as socketcand does) and counted.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import Counter
from enum import Enum
from typing import cast

import can

from tmcl_server.endpoints import parse_host_port
from tmcl_server.transports.admission import Admission
from tmcl_server.transports.base import Transport, TransportHost
from tmcl_server.transports.can.bus import SimulatedCanBus
from tmcl_server.transports.tcp import DEFAULT_MAX_CONNECTIONS, disable_nagle, listening_endpoints

log = logging.getLogger(__name__)

#: An element longer than this without its closing ``>`` is junk (socketcand's MAXLEN is 4096).
MAX_ELEMENT = 4096
#: Frames for a client are held this long after ``< rawmode >`` is acknowledged, so they do not
#: share a TCP segment with the ``< ok >``: python-can reads that answer with a single recv()
#: and compares it verbatim.  Nothing is lost: the held frames follow right after.
RAWMODE_GRACE_S = 0.02
#: A client that stops reading loses frames (like a full socket receive queue), not memory;
#: its own commands' answers (``< echo >``, ``< ok >``, errors) are not lost: past this much
#: unsent output the server stops reading its commands until it reads again (TCP back-pressure).
MAX_WRITE_BUFFER = 1 << 20

HI = b"< hi >"
OK = b"< ok >"
UNKNOWN_COMMAND = b"< error unknown command >"
CANNOT_OPEN = b"< error could not open bus >"


class Mode(Enum):
    NO_BUS = "no bus"
    BCM = "bcm"
    RAW = "raw"


def parse_send(tokens: list[str], remote: bool) -> can.Message | None:
    """``send ID DLC B0 ..`` or ``sendrtr ID DLC``; None if malformed.  8 id digits: extended."""
    if len(tokens) < 3:
        return None
    _, id_text, dlc_text, *data_text = tokens
    try:
        can_id, dlc = int(id_text, 16), int(dlc_text)
        data = bytes(int(b, 16) for b in data_text)
    except ValueError:
        return None
    extended = len(id_text) == 8
    if (can_id > (0x1FFF_FFFF if extended else 0x7FF) or not 0 <= dlc <= 8
            or len(data) != (0 if remote else dlc)):
        return None
    return can.Message(arbitration_id=can_id, is_extended_id=extended, is_remote_frame=remote,
                       dlc=dlc, data=data)


def format_frame(frame: can.Message, wall_time: float) -> bytes | None:
    """``< frame ID SECS.USECS DATA >`` as socketcand prints it (None: not sent in raw mode).

    socketcand leaves remote and error frames out of raw mode, and python-can's client
    could not parse them, so neither is forwarded.
    """
    if frame.is_remote_frame or frame.is_error_frame or frame.is_fd:
        return None
    can_id = f"{frame.arbitration_id:08X}" if frame.is_extended_id else f"{frame.arbitration_id:03X}"
    micros = int(wall_time * 1_000_000)
    return (f"< frame {can_id} {micros // 1_000_000}.{micros % 1_000_000:06d} "
            f"{frame.data.hex().upper()} >").encode("ascii")


class SocketcandClient(asyncio.Protocol):
    """One TCP client: its own state machine, its own party on the bus."""

    def __init__(self, server: SocketcandTransport) -> None:
        self.server = server
        #: Admission's bookkeeping (transports/admission.py): established by a valid command.
        self.connected_at = self.last_heard = 0.0
        self.established = False
        self._admitted = False
        self.bus: SimulatedCanBus = server.bus
        self.mode = Mode.NO_BUS
        self.transport: asyncio.Transport | None = None
        self._buffer = bytearray()
        self._held: list[bytes] | None = None
        #: The client does not read: its commands wait (in the kernel) until it does.
        self._output_full = False

    @property
    def stats(self) -> Counter[str]:
        return self.server.stats

    # -- connection ---------------------------------------------------------------------------

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        if not self.server.connections.admit(self):
            transport.close()
            return
        self._admitted = True
        # not an isinstance check: uvloop's transports are not asyncio.Transport subclasses
        self.transport = cast(asyncio.Transport, transport)
        disable_nagle(transport)
        self.transport.set_write_buffer_limits(high=MAX_WRITE_BUFFER, low=MAX_WRITE_BUFFER // 4)
        self.server.clients.add(self)
        self.stats["connections"] += 1
        self.transport.write(HI)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._admitted:
            self._admitted = False
            self.server.connections.release(self)
            self.bus.detach(self)
            self.server.clients.discard(self)
        self.transport = None

    def shut(self) -> None:
        """The admission gave this slot to a newcomer."""
        self.bus.detach(self)
        if self.transport is not None:
            self.transport.close()

    def _write(self, data: bytes) -> None:
        if self.transport is not None and not self.transport.is_closing():
            self.transport.write(data)

    def pause_writing(self) -> None:
        """Over MAX_WRITE_BUFFER unsent: stop taking commands whose answers would pile up."""
        self._output_full = True
        if self.transport is not None:
            self.transport.pause_reading()

    def resume_writing(self) -> None:
        self._output_full = False
        if self.transport is not None and not self.transport.is_closing():
            self.transport.resume_reading()
            self.data_received(b"")  # the commands left over when the output filled

    # -- client -> bus ------------------------------------------------------------------------

    def data_received(self, data: bytes) -> None:
        if not self._admitted:
            return
        if self.established:
            self.last_heard = self.server.connections.clock()
        buffer = self._buffer
        buffer += data
        while buffer and not self._output_full:
            start = buffer.find(b"<")
            if start < 0:
                self._junk(buffer)
                buffer.clear()
                break
            end = buffer.find(b">", start)
            if end < 0:
                if len(buffer) - start > MAX_ELEMENT:
                    self._junk(buffer)
                    buffer.clear()
                else:
                    self._junk(buffer[:start])
                    del buffer[:start]
                break
            start = buffer.rfind(b"<", start, end)  # "< junk < send .. >": resync on the last <
            self._junk(buffer[:start])
            element = buffer[start + 1:end].decode("ascii", errors="replace")
            del buffer[:end + 1]
            self._element(element.split())

    def _junk(self, data: bytes | bytearray) -> None:
        if data.strip():
            self.stats["junk_bytes"] += len(data)

    def _element(self, tokens: list[str]) -> None:
        command = tokens[0] if tokens else ""
        if self.mode is Mode.NO_BUS:
            self._no_bus(command, tokens)
        elif command in ("send", "sendrtr"):
            self._send(tokens, remote=command == "sendrtr")
        elif command == "echo" and len(tokens) == 1:
            self._write(b"< echo >")
        elif command == "rawmode" and len(tokens) == 1:
            self._write(OK)
            if self.mode is not Mode.RAW:
                self.mode = Mode.RAW
                self._held = []
                asyncio.get_running_loop().call_later(RAWMODE_GRACE_S, self._release_held)
        elif command == "bcmmode" and len(tokens) == 1:
            self.mode = Mode.BCM
            self._held = None
            self._write(OK)
        else:  # BCM jobs, filters, control and ISO-TP modes are not offered
            self.stats["unknown_commands"] += 1
            self._write(UNKNOWN_COMMAND)

    def _no_bus(self, command: str, tokens: list[str]) -> None:
        opening = command == "open" and len(tokens) == 2
        configuring = len(tokens) >= 2 and tokens[1] in ("B", "C")  # < NAME B|C settings.. >
        if opening or configuring:
            name = tokens[1] if opening else command
            if name == self.bus.name:  # a valid command: the client keeps its slot
                self.server.connections.establish(self)
            if name != self.bus.name:
                self.stats["refused"] += 1
                self._write(CANNOT_OPEN)
                assert self.transport is not None
                self.transport.close()
                return
            if opening:  # bit timing and control settings are accepted, not modelled
                self.mode = Mode.BCM
                self.bus.attach(self)
            self._write(OK)
        else:
            self.stats["unknown_commands"] += 1
            self._write(UNKNOWN_COMMAND)

    def _send(self, tokens: list[str], remote: bool) -> None:
        frame = parse_send(tokens, remote)
        if frame is None:
            self.stats["bad_commands"] += 1
            log.debug("socketcand: malformed %s", " ".join(tokens))
            return
        self.stats["sent"] += 1
        self.bus.send(frame, self)

    # -- bus -> client ------------------------------------------------------------------------

    def on_frame(self, frame: can.Message) -> None:
        if self.mode is not Mode.RAW or self.transport is None:
            return
        line = format_frame(frame, time.time())
        if line is None:
            return
        if self._held is not None:
            self._held.append(line)
        elif self.transport.get_write_buffer_size() > MAX_WRITE_BUFFER:
            self.stats["dropped"] += 1
        else:
            self.stats["forwarded"] += 1
            self.transport.write(line)

    def _release_held(self) -> None:
        held, self._held = self._held, None
        if held:
            self.stats["forwarded"] += len(held)
            self._write(b"".join(held))


class SocketcandTransport(Transport):
    kind = "socketcand"

    def __init__(self, bus: SimulatedCanBus, address: str,
                 max_connections: int = DEFAULT_MAX_CONNECTIONS) -> None:
        self.host, self.port = parse_host_port(address)
        self.bus = bus
        self.clients: set[SocketcandClient] = set()
        #: Who gets a slot at ``--max-connections`` (transports/admission.py; issue 36, N2).
        self.connections = Admission(f"socketcand {address} (--max-connections)",
                                     max_connections, log)
        self.stats: Counter[str] = Counter()
        self._server: asyncio.Server | None = None

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> SocketcandTransport:
        return cls(host.can_bus(), argument, host.option("max_connections"))

    async def start(self) -> list[str]:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(lambda: SocketcandClient(self), self.host,
                                                self.port, reuse_address=True)
        endpoints = listening_endpoints(self._server)
        self.connections.name = f"socketcand {endpoints[0]} (--max-connections)"
        return endpoints

    async def close(self) -> None:
        if self._server is None:
            return
        self._server.close()
        for client in list(self.clients):
            self.bus.detach(client)
            if client.transport is not None:
                client.transport.abort()
        await self._server.wait_closed()
        self._server = None
