"""What one dashboard port may cost the server, whatever its clients do (docs/robustness.md,
"Connection limits"): a connection limit with the admission rule every listener follows, a
deadline for request heads, and paces (requests, page messages, frames) that make a flood
wait instead of taking the event loop from the hosts.  No aiohttp here:
:class:`ConnectionGate` wraps any asyncio protocol factory."""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from typing import Any, cast

from tmcl_server.transports.admission import Admission, Pace

__all__ = ["ConnectionGate", "Pace"]

log = logging.getLogger("tmcl_server.dashboard.web")


#: A connection whose request head is not complete this long after it connected (or after
#: its last answer) is closed (nginx's ``client_header_timeout``, Apache's mod_reqtimeout;
#: issue 36, N6: sockets dribbling a header byte every 0.5 s kept the port busy for ever).
HEAD_TIMEOUT_S = 10.0


class _GatedConnection(asyncio.Protocol):
    """Stands in front of the web server's own protocol: holds the connection's slot in the
    gate's admission, and closes it if a request head takes longer than HEAD_TIMEOUT_S."""

    __slots__ = ("_deadline", "_gate", "_inner", "admitted", "connected_at", "established",
                 "last_heard", "transport")

    def __init__(self, gate: ConnectionGate, inner: asyncio.Protocol) -> None:
        self._gate = gate
        self._inner = inner
        self.transport: asyncio.Transport | None = None
        self.admitted = False
        #: Admission's bookkeeping: established by a complete request the guard let through;
        #: heard at each such request and each message of a page (not at every byte).
        self.connected_at = self.last_heard = 0.0
        self.established = False
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = cast(asyncio.Transport, transport)
        if not self._gate.admission.admit(self):
            transport.close()
            return
        self.admitted = True
        self._gate.by_transport[transport] = self
        self.expect_head()
        self._inner.connection_made(transport)

    def expect_head(self) -> None:
        """A request head must be complete within HEAD_TIMEOUT_S from now."""
        self.head_done()
        self._deadline = asyncio.get_running_loop().call_later(HEAD_TIMEOUT_S, self._too_slow)

    def head_done(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _too_slow(self) -> None:
        self._deadline = None
        self._gate.slow_heads += 1
        log.warning("%s: a request head took over %.0f s; connection closed (%d so far)",
                    self._gate.name, HEAD_TIMEOUT_S, self._gate.slow_heads)
        self.shut()

    def shut(self) -> None:
        if self.transport is not None:
            self.transport.close()

    def data_received(self, data: bytes) -> None:
        if self.admitted:
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
        self.head_done()
        if self.admitted:
            self.admitted = False
            self._gate.admission.release(self)
            if self.transport is not None:
                self._gate.by_transport.pop(self.transport, None)
            self._inner.connection_lost(exc)
        self.transport = None


class ConnectionGate:
    """At most ``limit`` connections at once, admitted by the rule every listener follows
    (:class:`~tmcl_server.transports.admission.Admission`): a connection is established once
    a complete request passed the guard, and heard at each request and page message; at the
    limit a newcomer takes the slot of a newcomer without a complete request for a second, or
    of an established connection silent for a minute, else it is refused.  So a flood of
    connections, busy or dribbling header bytes, never closes a page or a client that speaks."""

    def __init__(self, factory: Callable[[], Any], limit: int, name: str) -> None:
        self._factory = factory
        self.name = name
        self.admission = Admission(name, limit, log)
        #: The transport of each admitted connection (the guard finds its connection by it).
        self.by_transport: dict[Any, _GatedConnection] = {}
        #: Connections closed because a request head took over HEAD_TIMEOUT_S.
        self.slow_heads = 0

    @property
    def refused(self) -> int:
        return self.admission.refused

    @property
    def evicted(self) -> int:
        return self.admission.evicted

    def __call__(self) -> asyncio.Protocol:
        return _GatedConnection(self, self._factory())

    def request_complete(self, transport: Any) -> None:
        """The guard let a complete request through: no head deadline while it is handled,
        and its client keeps its slot."""
        connection = self.by_transport.get(transport)
        if connection is not None:
            connection.head_done()
            self.admission.establish(connection)

    def answered(self, transport: Any, upgraded: bool = False) -> None:
        """A plain request was answered: the next head has HEAD_TIMEOUT_S again (a page's
        WebSocket has no heads)."""
        connection = self.by_transport.get(transport)
        if connection is not None and not upgraded and connection.transport is not None \
                and not connection.transport.is_closing():
            connection.expect_head()

    def heard(self, transport: Any) -> None:
        """A page sent a message: it keeps its slot."""
        connection = self.by_transport.get(transport)
        if connection is not None:
            self.admission.establish(connection)

    def close_all(self) -> None:
        for connection in list(self.admission):
            if connection.transport is not None:  # type: ignore[attr-defined]
                connection.transport.abort()  # type: ignore[attr-defined]
