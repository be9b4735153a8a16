"""Clocks for tests of real-clock behaviour that must still be exact."""

from __future__ import annotations

from tmcl_server.clock import Clock


class ManualClock(Clock):
    """A real clock as far as the simulation can tell (not virtual), moved by the test."""

    def __init__(self) -> None:
        self.t = 0

    def now_ns(self) -> int:
        return self.t

    def wall_seconds(self, sim_ns: int) -> float:
        return sim_ns / 1e9
