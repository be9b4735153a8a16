"""What one dashboard port may cost the server, whatever its clients do (docs/robustness.md,
"The dashboard under load"): a connection limit with the longest-idle connection evicted at
it, and paces (requests, page messages, frames) that make a flood wait instead of taking the
event loop from the hosts.  No aiohttp here: :class:`ConnectionGate` wraps any asyncio
protocol factory."""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Any, cast

from tmcl_server.transports.admission import Pace

__all__ = ["ConnectionGate", "Pace"]

log = logging.getLogger("tmcl_server.dashboard.web")


class _GatedConnection(asyncio.Protocol):
    """Stands in front of the web server's own protocol: counts the connection, notes when its
    client last sent something, and lets the gate close it."""

    __slots__ = ("_gate", "_inner", "admitted", "last_heard", "transport")

    def __init__(self, gate: ConnectionGate, inner: asyncio.Protocol) -> None:
        self._gate = gate
        self._inner = inner
        self.transport: asyncio.Transport | None = None
        self.admitted = False
        self.last_heard = time.monotonic()

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        if not self._gate.admit(self):
            transport.close()
            return
        self.admitted = True
        self._inner.connection_made(transport)

    def data_received(self, data: bytes) -> None:
        if self.admitted:
            self.last_heard = time.monotonic()
            self._inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self._inner.eof_received() if self.admitted else None

    def pause_writing(self) -> None:
        if self.admitted:
            self._inner.pause_writing()

    def resume_writing(self) -> None:
        if self.admitted:
            self._inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        self._gate.release(self)
        if self.admitted:
            self.admitted = False
            self._inner.connection_lost(exc)
        self.transport = None


class ConnectionGate:
    """At most ``limit`` connections at once.  A new one past the limit closes the connection
    whose client has been silent longest, if that one has been silent at least ``idle_s`` (an
    idle keep-alive, an abandoned socket: idle connections never lock a live client out);
    otherwise the newcomer is closed at once (every connection is busy: a flood must not
    make the server trade one busy connection for another)."""

    def __init__(self, factory: Callable[[], Any], limit: int, name: str,
                 idle_s: float = 1.0) -> None:
        if limit < 1:
            raise ValueError(f"a connection limit must be at least 1, got {limit}")
        self._factory = factory
        self.limit = limit
        self.name = name
        self.idle_s = idle_s
        #: Newcomers closed at once because every connection was busy.
        self.refused = 0
        self.connections: set[_GatedConnection] = set()
        #: Connections closed to make room (for tests and the docs' figures).
        self.evicted = 0

    def __call__(self) -> asyncio.Protocol:
        return _GatedConnection(self, self._factory())

    def admit(self, connection: _GatedConnection) -> bool:
        if len(self.connections) >= self.limit:
            victim = min(self.connections, key=lambda c: c.last_heard)
            silent = time.monotonic() - victim.last_heard
            if silent < self.idle_s:
                self.refused += 1
                log.warning("%s: %d busy connections (the limit); a new one is closed at once",
                            self.name, len(self.connections))
                return False
            log.warning("%s: %d connections (the limit); closing the one silent for %.1f s",
                        self.name, len(self.connections), silent)
            self.evicted += 1
            self.connections.discard(victim)
            if victim.transport is not None:
                victim.transport.close()
        self.connections.add(connection)
        return True

    def release(self, connection: _GatedConnection) -> None:
        self.connections.discard(connection)

    def close_all(self) -> None:
        for connection in list(self.connections):
            if connection.transport is not None:
                connection.transport.abort()
