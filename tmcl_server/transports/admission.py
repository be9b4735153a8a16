"""Who gets a connection slot at a listener's limit, and who is refused (docs/robustness.md,
"Connection limits").  One rule for every listener (TCP, socketcand, the dashboard):

* A connection is a **newcomer** until its client has sent something valid (a TMCL frame
  with a right checksum, a socketcand command, a complete HTTP request); then it is
  **established**.
* Below the limit everyone is admitted.  At the limit a newcomer may take the slot of
  (1) the oldest newcomer connected at least :data:`NEWCOMER_GRACE_S` ago (it had its chance
  to say something valid, as OpenSSH's ``MaxStartups`` drops unauthenticated connections), or
  else (2) the established connection silent longest, if silent at least
  :data:`ESTABLISHED_IDLE_S`; otherwise the **newcomer is refused** (closed at once, as
  mosquitto does at ``max_connections``).  So an established host is never evicted for a
  newcomer while it speaks at least once a minute, however many connections arrive.
* Every refusal and eviction is counted, and logged through a rate-limited logger (one line
  per kind every 5 s, with the count held back: :mod:`tmcl_server.lograte`).

A listener's protocol objects implement :class:`Admitted`, and the listener asks
:meth:`Admission.admit` in ``connection_made``.  :class:`Pace` bounds the rate of queued
work (the dashboard's requests, the MQTT bridge's inbox).
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable
from typing import Protocol

#: A newcomer that has not said anything valid this long after connecting may lose its slot
#: to another newcomer at the limit (a host sends its first request within milliseconds).
NEWCOMER_GRACE_S = 1.0
#: An established connection silent this long may lose its slot to a newcomer at the limit
#: (a PLC keeping a silent connection for hours keeps it while the listener has room).
ESTABLISHED_IDLE_S = 60.0


class Admitted(Protocol):
    """What the admission needs of a connection."""

    #: When it connected, and when its client last sent something valid (the clock's time).
    connected_at: float
    last_heard: float
    #: Whether it has sent something valid yet.
    established: bool

    def shut(self) -> None:
        """Close the connection (its slot is already taken away)."""


class Admission:
    """The connections of one listener, at most ``limit`` at once (module docstring)."""

    def __init__(self, name: str, limit: int, log: logging.Logger,
                 newcomer_grace_s: float = NEWCOMER_GRACE_S,
                 idle_s: float = ESTABLISHED_IDLE_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if limit < 1:
            raise ValueError(f"a connection limit must be at least 1, got {limit}")
        self.name = name
        self.limit = limit
        self.log = log
        self.newcomer_grace_s = newcomer_grace_s
        self.idle_s = idle_s
        self.clock = clock
        #: Newcomers in the order they connected (oldest first), and the established ones.
        self._newcomers: dict[Admitted, None] = {}
        self._established: set[Admitted] = set()
        #: No established connection can have been silent idle_s before this time.
        self._no_idle_until = float("-inf")
        #: Newcomers refused at the limit, and connections closed to make room.
        self.refused = 0
        self.evicted = 0

    def __len__(self) -> int:
        return len(self._newcomers) + len(self._established)

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter([*self._newcomers, *self._established])

    def __contains__(self, connection: object) -> bool:
        return connection in self._newcomers or connection in self._established

    def admit(self, connection: Admitted) -> bool:
        """Whether ``connection`` (just made) gets a slot; False: the caller closes it."""
        now = self.clock()
        connection.connected_at = connection.last_heard = now
        connection.established = False
        if len(self) >= self.limit:
            victim = self._victim(now)
            if victim is None:
                self.refused += 1
                self.log.warning("%s: %d connections (the limit), each established and heard "
                                 "within %.0f s or connected under %.0f s ago: a new one is "
                                 "refused (%d refused so far)", self.name, len(self),
                                 self.idle_s, self.newcomer_grace_s, self.refused)
                return False
            self.evicted += 1
            silent = now - (victim.last_heard if victim.established else victim.connected_at)
            self.log.warning("%s: %d connections (the limit); closing one %s for %.1f s to make "
                             "room (%d closed so far)", self.name, len(self),
                             "silent" if victim.established else "without a valid request",
                             silent, self.evicted)
            self.release(victim)
            victim.shut()
        self._newcomers[connection] = None
        return True

    def _victim(self, now: float) -> Admitted | None:
        oldest = next(iter(self._newcomers), None)
        if oldest is not None and now - oldest.connected_at >= self.newcomer_grace_s:
            return oldest
        if not self._established or now < self._no_idle_until:
            return None
        quietest = min(self._established, key=lambda c: c.last_heard)
        if now - quietest.last_heard >= self.idle_s:
            return quietest
        self._no_idle_until = quietest.last_heard + self.idle_s
        return None

    def establish(self, connection: Admitted) -> None:
        """Its client sent something valid: it keeps its slot while it speaks."""
        if connection in self._newcomers:
            del self._newcomers[connection]
            self._established.add(connection)
        connection.established = True
        connection.last_heard = self.clock()

    def release(self, connection: Admitted) -> None:
        """The connection closed (or is being closed): its slot is free."""
        self._newcomers.pop(connection, None)
        self._established.discard(connection)


class Pace:
    """At most ``rate`` turns a second on average, ``burst`` at once (a generic cell rate
    algorithm): :meth:`delay` says how long the caller must wait for its turn and books it,
    so waiting callers go in the order they asked and the rate holds however many ask."""

    def __init__(self, rate: float, burst: int = 1, clock: Callable[[], float] = time.monotonic) -> None:
        self.interval = 1.0 / rate
        self.tolerance = (max(1, burst) - 1) * self.interval
        self._clock = clock
        #: When the next turn is due if nobody waits (the "theoretical arrival time").
        self._due = 0.0

    def delay(self, longest: float | None = None) -> float | None:
        """The wait for the next turn, booked; None (and nothing booked) if it would be longer
        than ``longest``."""
        now = self._clock()
        due = max(self._due, now)
        wait = max(0.0, due - self.tolerance - now)
        if longest is not None and wait > longest:
            return None
        self._due = due + self.interval
        return wait

    async def turn(self) -> None:
        wait = self.delay()
        if wait:
            await asyncio.sleep(wait)
