"""Simulated time.

All models count integer nanoseconds of simulated time.  A clock maps that to the world:
:class:`RealClock` follows the wall clock (optionally sped up or slowed down with
``--speed``), :class:`VirtualClock` only moves when a test advances it, and then the
simulator jumps straight from one event to the next.
"""

from __future__ import annotations

import time

from tmcl_spec.numbers import NS_PER_S, seconds_to_ns

__all__ = ["Clock", "LockstepClock", "RealClock", "VirtualClock", "seconds_to_ns"]


class Clock:
    """Base class: ``now_ns()`` is the current simulated time."""

    virtual = False
    #: Simulated time each request takes before it runs (only a lockstep clock charges it).
    request_ns = 0

    def now_ns(self) -> int:
        raise NotImplementedError

    def wall_seconds(self, sim_ns: int) -> float:
        """How long, in real seconds, a span of simulated time takes on this clock."""
        raise NotImplementedError


class RealClock(Clock):
    """Simulated time = monotonic wall time since start, times ``speed``."""

    def __init__(self, speed: float = 1.0) -> None:
        if speed <= 0:
            raise ValueError("speed must be positive")
        self.speed = speed
        self._origin = time.monotonic_ns()

    def now_ns(self) -> int:
        elapsed = time.monotonic_ns() - self._origin
        return elapsed if self.speed == 1.0 else int(elapsed * self.speed)

    def wall_seconds(self, sim_ns: int) -> float:
        return sim_ns / NS_PER_S / self.speed


class VirtualClock(Clock):
    """Time stands still until :meth:`set` moves it forward (used by tests and benchmarks)."""

    virtual = True

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns

    def now_ns(self) -> int:
        return self._now

    def set(self, t_ns: int) -> None:
        if t_ns < self._now:
            raise ValueError("virtual time cannot go backwards")
        self._now = t_ns

    def wall_seconds(self, sim_ns: int) -> float:
        return 0.0


class LockstepClock(VirtualClock):
    """A virtual clock that the host moves by what it does (``clock="lockstep"``).

    Every request a module executes first lets ``request_ns`` of simulated time pass (its
    time on the wire), and the pytest plugin turns a host thread's ``time.sleep(s)`` into
    ``advance(s)``: unchanged poll-and-sleep host code finishes at once and sees the same
    replies on every run, whatever the machine's load (README, "Host tests that poll").
    """

    def __init__(self, request_ns: int = 1_000_000, start_ns: int = 0) -> None:
        super().__init__(start_ns)
        if request_ns < 0:
            raise ValueError("the time a request takes cannot be negative")
        self.request_ns = request_ns
