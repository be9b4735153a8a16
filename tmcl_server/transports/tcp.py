"""Raw TMCL over TCP: 9-byte frames in, 9-byte replies out, many clients at once.

pytrinamic's ``socket_serial_tmcl`` interface (an Ethernet-to-serial converter) speaks
exactly this, so ``--port 127.0.0.1:2323`` reaches the simulator.  Like such a converter on
an RS-485 bus, TCP filters frames by address whatever the number of modules;
``HOST:PORT,mode=usb`` makes it one module's own port instead (docs/protocol.md).
"""

from __future__ import annotations

import asyncio
import logging
import socket
from functools import partial
from typing import cast

from tmcl_server.simulation import Simulation
from tmcl_server.transports.base import (
    LinkMode,
    StreamSession,
    Transport,
    TransportHost,
    bytes_waiting,
    link_mode,
    split_endpoint_options,
)

log = logging.getLogger(__name__)

DEFAULT_TCP = "127.0.0.1:2323"


def parse_host_port(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT``; IPv6 hosts go in brackets."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = default_host, text
    host = host.strip("[]") or default_host
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"bad port in {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port out of range in {text!r}")
    return host, number


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


class _TcpProtocol(asyncio.Protocol):
    def __init__(self, simulation: Simulation, connections: set[_TcpProtocol],
                 mode: LinkMode) -> None:
        self._simulation = simulation
        self._connections = connections
        self._mode = mode
        self.transport: asyncio.Transport | None = None
        self._session: StreamSession | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        # not an isinstance check: uvloop's transports are not asyncio.Transport subclasses
        self.transport = cast(asyncio.Transport, transport)
        disable_nagle(transport)
        peer = transport.get_extra_info("peername")
        sock = transport.get_extra_info("socket")
        self._session = StreamSession(self._simulation, transport.write, asyncio.get_running_loop(),
                                      self._mode, f"tcp {peer[0]}:{peer[1]}" if peer else "tcp",
                                      partial(bytes_waiting, sock.fileno()) if sock is not None else None)
        self._connections.add(self)

    def data_received(self, data: bytes) -> None:
        assert self._session is not None
        self._session.feed(data)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._session is not None:
            self._session.close()
        self._connections.discard(self)


class TcpTransport(Transport):
    kind = "tcp"

    def __init__(self, simulation: Simulation, address: str = DEFAULT_TCP,
                 mode: LinkMode = LinkMode.RS485) -> None:
        self.simulation = simulation
        self.host, self.port = parse_host_port(address)
        self.mode = mode
        self._server: asyncio.Server | None = None
        self.connections: set[_TcpProtocol] = set()

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> TcpTransport:
        """``HOST:PORT[,mode=rs485|usb]``; RS-485 addressing unless told otherwise."""
        address, options = split_endpoint_options(argument)
        return cls(host.simulation, address,
                   link_mode(host.simulation, options, f"--tcp {address}", LinkMode.RS485))

    async def start(self) -> list[str]:
        loop = asyncio.get_running_loop()
        self._server = await loop.create_server(
            lambda: _TcpProtocol(self.simulation, self.connections, self.mode), self.host,
            self.port, reuse_address=True)
        return listening_endpoints(self._server)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            for connection in list(self.connections):
                if connection.transport is not None:
                    connection.transport.abort()
            await self._server.wait_closed()
            self._server = None
