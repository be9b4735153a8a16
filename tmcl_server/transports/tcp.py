"""Raw TMCL over TCP: 9-byte frames in, 9-byte replies out, many clients at once.

pytrinamic's ``socket_serial_tmcl`` interface (an Ethernet-to-serial converter) speaks
exactly this, so ``--port 127.0.0.1:2323`` reaches the simulator.  Like such a converter on
an RS-485 bus, TCP filters frames by address whatever the number of modules;
``HOST:PORT,mode=usb`` makes it one module's own port instead (docs/protocol.md).
"""

from __future__ import annotations

import asyncio
import errno
import logging
import socket
from functools import partial
from typing import Any, cast

from tmcl_server.endpoints import parse_host_port
from tmcl_server.platform import bytes_waiting, descriptor_limit
from tmcl_server.simulation import Simulation
from tmcl_server.transports.admission import Admission
from tmcl_server.transports.base import (
    LinkMode,
    StreamSession,
    Transport,
    TransportHost,
    link_mode,
    split_endpoint_options,
)

log = logging.getLogger(__name__)

DEFAULT_TCP = "127.0.0.1:2323"
#: A client that sends requests but does not read the replies: past this much unsent output
#: the server stops reading its requests until it reads again (TCP back-pressure), so its
#: replies cost bounded memory and none is dropped.
MAX_WRITE_BUFFER = 1 << 20
#: Clients one endpoint serves at once (``--max-connections``): far below a usual descriptor
#: limit (1024), far above what hosts open (docs/robustness.md).
DEFAULT_MAX_CONNECTIONS = 256


def listening_endpoints(server: asyncio.Server) -> list[str]:
    """``host:port`` of every socket a server listens on (the port a ``:0`` request got)."""
    endpoints = []
    for sock in server.sockets:
        host, port = sock.getsockname()[:2]
        endpoints.append(f"[{host}]:{port}" if ":" in host else f"{host}:{port}")
    return endpoints


def disable_nagle(transport: asyncio.BaseTransport) -> None:
    """Send small replies at once: a request/reply protocol must not wait for more data."""
    sock = transport.get_extra_info("socket")
    if sock is not None and sock.family in (socket.AF_INET, socket.AF_INET6):
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


#: Accept errors that mean "out of descriptors or memory": the loop retries later by itself.
_RESOURCE_ERRORS = (errno.EMFILE, errno.ENFILE, errno.ENOBUFS, errno.ENOMEM)


def quiet_accept_errors(loop: asyncio.AbstractEventLoop) -> None:
    """One short line for accept() failing at the descriptor limit, not a traceback per attempt
    (asyncio reports each one to the loop's exception handler, then waits a second)."""
    previous = loop.get_exception_handler()
    if getattr(previous, "quiet_accept_errors", False):
        return

    def handler(loop: asyncio.AbstractEventLoop, context: dict[str, Any]) -> None:
        exc = context.get("exception")
        if (isinstance(exc, OSError) and exc.errno in _RESOURCE_ERRORS
                and "accept" in str(context.get("message", ""))):
            log.error("cannot accept a TCP connection: %s; it waits in the backlog (raise the "
                      "descriptor limit, ulimit -n, or lower --max-connections)", exc.strerror)
        elif (isinstance(exc, ValueError)
              and getattr(getattr(context.get("handle"), "_callback", None), "__name__", "")
              == "_start_serving"):
            # asyncio schedules one retry per failed accept, and those still pending when the
            # listening socket closes fail on its closed descriptor: nothing is lost.
            log.debug("accept retry after close: %s", exc)
        elif previous is not None:
            previous(loop, context)
        else:
            loop.default_exception_handler(context)

    handler.quiet_accept_errors = True  # type: ignore[attr-defined]
    loop.set_exception_handler(handler)


class _TcpProtocol(asyncio.Protocol):
    __slots__ = ("_admission", "_mode", "_peer", "_session", "_simulation", "connected_at",
                 "established", "last_heard", "transport")

    def __init__(self, simulation: Simulation, admission: Admission, mode: LinkMode) -> None:
        self._simulation = simulation
        self._admission = admission
        self._mode = mode
        #: Admission's bookkeeping (transports/admission.py).
        self.connected_at = self.last_heard = 0.0
        self.established = False
        self.transport: asyncio.Transport | None = None
        self._session: StreamSession | None = None
        self._peer = "?"

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # not an isinstance check: uvloop's transports are not asyncio.Transport subclasses
        self.transport = cast(asyncio.Transport, transport)
        if not self._admission.admit(self):
            self.transport = None
            transport.close()
            return
        peer = transport.get_extra_info("peername")
        self._peer = f"{peer[0]}:{peer[1]}" if peer else "?"
        disable_nagle(transport)
        self.transport.set_write_buffer_limits(high=MAX_WRITE_BUFFER, low=MAX_WRITE_BUFFER // 4)
        sock = transport.get_extra_info("socket")
        self._session = StreamSession(self._simulation, self.transport.write, asyncio.get_running_loop(),
                                      self._mode, f"tcp {self._peer}",
                                      partial(bytes_waiting, sock.fileno()) if sock is not None else None)

    def shut(self) -> None:
        """The admission gave this slot to a newcomer (it was silent, or never valid)."""
        if self.transport is not None:
            self.transport.close()

    def data_received(self, data: bytes) -> None:
        session = self._session
        if session is None:  # closing
            return
        session.feed(data)
        if self.established:
            self.last_heard = self._admission.clock()
        elif session.heard_valid:  # its first frame with a right checksum
            self._admission.establish(self)

    def pause_writing(self) -> None:
        if self.transport is not None:
            self.transport.pause_reading()

    def resume_writing(self) -> None:
        if self.transport is not None and not self.transport.is_closing():
            if self._session is not None:
                self._session.reading_resumed()
            self.transport.resume_reading()

    def connection_lost(self, exc: Exception | None) -> None:
        if self._session is not None:
            self._session.close()
            self._session = None
            self._admission.release(self)
        self.transport = None


class TcpTransport(Transport):
    kind = "tcp"

    def __init__(self, simulation: Simulation, address: str = DEFAULT_TCP,
                 mode: LinkMode = LinkMode.RS485,
                 max_connections: int = DEFAULT_MAX_CONNECTIONS) -> None:
        if max_connections < 1:
            raise ValueError(f"max_connections must be at least 1, got {max_connections}")
        self.simulation = simulation
        self.host, self.port = parse_host_port(address)
        self.mode = mode
        #: Clients served at once; who gets a slot past it: transports/admission.py.
        self.max_connections = max_connections
        self._server: asyncio.Server | None = None
        self.connections = Admission(f"tcp {self.host}:{self.port} (--max-connections)",
                                     max_connections, log)

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> TcpTransport:
        """``HOST:PORT[,mode=rs485|usb]``; RS-485 addressing unless told otherwise."""
        address, options = split_endpoint_options(argument)
        return cls(host.simulation, address,
                   link_mode(host.simulation, options, f"--tcp {address}", LinkMode.RS485),
                   host.option("max_connections"))

    async def start(self) -> list[str]:
        loop = asyncio.get_running_loop()
        quiet_accept_errors(loop)
        self._server = await loop.create_server(
            lambda: _TcpProtocol(self.simulation, self.connections, self.mode),
            self.host, self.port, reuse_address=True)
        endpoints = listening_endpoints(self._server)
        self.connections.name = f"tcp {endpoints[0]} (--max-connections)"
        descriptors = descriptor_limit()
        if descriptors is not None and self.max_connections + 32 > descriptors:
            log.warning("tcp %s: the descriptor limit (%d) is below --max-connections %d: "
                        "clients beyond it wait unserved", endpoints[0], descriptors,
                        self.max_connections)
        return endpoints

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            for connection in list(self.connections):
                if connection.transport is not None:
                    connection.transport.abort()
            await self._server.wait_closed()
            self._server = None
