"""Reference search (RFS, AP 193 modes 1..8 with +64/+128): its plan and its state machine.

:func:`reference_plan` turns a mode into the phases the firmware drives one after another;
:func:`reference_point` computes the zero point from the positions recorded on the way;
:class:`ReferenceSearcher` drives the phases on an axis (``axes.firmware.AxisFirmware``)
through the motion primitives of :class:`SearchingAxis`, reacting to the switch levels at
every notable instant.  The sequences where the manual's figures are missing are explained
in docs/motion.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

from axes.interface import AxisEventKind
from tmcl_spec.parameters import AP


@dataclass(slots=True)
class Phase:
    """One step of a reference search: drive until a switch reaches a level."""

    kind: str  # "seek" (fast, may reverse), "leave", "enter" (slow), "finish"
    switch: str  # "left", "right" or "home"
    direction: int
    record: str | None = None  # name under which to keep the position where it happened
    reverse_on: str | None = None  # seek only: limit switch that turns the search around


def _calibrate(switch: str, direction: int, tag: str) -> list[Phase]:
    """Back out of a switch slowly and re-enter it: its switching point without hysteresis.

    ``direction`` is the way the switch was entered; records ``tag1`` and ``tag2``.
    """
    return [Phase("leave", switch, -direction, f"{tag}1"), Phase("enter", switch, direction, f"{tag}2")]


def _middle(switch: str, direction: int) -> list[Phase]:
    """Both ends of a switch cam entered travelling ``direction``: its middle."""
    return [*_calibrate(switch, direction, "near"), Phase("leave", switch, direction, "back1"),
            Phase("enter", switch, -direction, "back2")]


def _seek(switch: str, direction: int, reverse_on: str | None = None) -> Phase:
    return Phase("seek", switch, direction, reverse_on=reverse_on)


#: The phases of each base mode, from the near limit switch, the far one and the direction
#: towards the near one (modes 1..4 with +64 mirror them: the right switch is the near one).
_PLANS: dict[int, Callable[[str, str, int], list[Phase]]] = {
    1: lambda near, far, down: [_seek(near, down), *_calibrate(near, down, "near")],
    2: lambda near, far, down: [_seek(far, -down), *_calibrate(far, -down, "other"),
                                _seek(near, down), *_calibrate(near, down, "near")],
    3: lambda near, far, down: [_seek(far, -down), *_calibrate(far, -down, "other"),
                                _seek(near, down), *_middle(near, down)],
    4: lambda near, far, down: [_seek(near, down), *_middle(near, down)],
    5: lambda near, far, down: [_seek("home", -1, "left"), *_calibrate("home", -1, "near")],
    6: lambda near, far, down: [_seek("home", 1, "right"), *_calibrate("home", 1, "near")],
    7: lambda near, far, down: [_seek("home", 1), *_middle("home", 1)],
    8: lambda near, far, down: [_seek("home", -1), *_middle("home", -1)],
}


def reference_plan(mode: int) -> tuple[list[Phase], bool]:
    """The phases of RFS for AP 193 ``mode``, and whether the home switch is inverted."""
    inverted = mode >= 128
    base = mode - 128 if inverted else mode
    if inverted and base <= 4:
        base += 4  # the manual's own examples spell "mode 5..8 + 128" as 129..132
    mirrored = 64 < base < 128
    base = base - 64 if mirrored else base
    near, far, down = ("right", "left", 1) if mirrored else ("left", "right", -1)
    plan = _PLANS.get(base)
    if plan is None:
        raise ValueError(f"reference search mode {mode} is not defined")
    return [*plan(near, far, down), Phase("finish", "", 0)], inverted


def reference_point(points: dict[str, int]) -> tuple[int, int | None]:
    """(zero point, end-switch distance or None) from the positions a search recorded.

    A calibrated edge is the mean of the two switching points (leaving and re-entering); the
    middle of a cam is the mean of both calibrated ends.  Means are floored.
    """
    tags = ("near", "back") if "back1" in points else ("near",)
    zero = sum(points[f"{tag}{n}"] for tag in tags for n in (1, 2)) // (2 * len(tags))
    if "other1" in points:
        other = (points["other1"] + points["other2"]) // 2
        return zero, abs(other - zero)
    return zero, None


@dataclass(slots=True)
class ReferenceSearch:
    phases: list[Phase]
    inverted_home: bool
    index: int = 0
    #: Positions recorded on the way, by the phases' ``record`` names.
    points: dict[str, int] = field(default_factory=dict)
    direction: int = 0
    reversed_once: bool = False

    @property
    def phase(self) -> Phase:
        return self.phases[self.index]


class SearchingAxis(Protocol):
    """What a reference search drives: the firmware's motion primitives and its records."""

    def switch_levels(self) -> tuple[bool, bool, bool]:
        """The logical left, right and home levels as of the last notable instant."""
        ...

    def actual_position(self) -> int:
        ...

    def start_velocity(self, speed: int) -> None:
        ...

    def hard_stop(self) -> None:
        ...

    def start_positioning(self, target: int, top_speed: int) -> None:
        ...

    def arrived(self) -> bool:
        """The last move has reached its target and stands."""
        ...

    def update_marks(self) -> None:
        ...

    def configure_stops(self, searching: bool) -> None:
        """The limit switches stop the motor as a search or as normal operation wants."""
        ...

    def zero_counters(self) -> None:
        """AP 1 and AP 209 count from 0 here."""
        ...

    def emit(self, kind: AxisEventKind) -> None:
        ...


class ReferenceSearcher:
    """The reference search of one axis: which phase runs (``state``: RFS STATUS)."""

    def __init__(self, axis: SearchingAxis, params: dict[int, int]) -> None:
        self._axis = axis
        #: The firmware's parameter values: the search speeds (AP 194/195) are read, its
        #: results (AP 196 switch distance, AP 197 last reference) written here.
        self._params = params
        self.search: ReferenceSearch | None = None
        #: RFS STATUS: 0 while no search runs, else the phase's number (1-based).
        self.state = 0

    @property
    def active(self) -> bool:
        return self.search is not None

    @staticmethod
    def plan(mode: int) -> ReferenceSearch:
        """A search for AP 193 ``mode`` (ValueError for a mode that is not defined)."""
        phases, inverted = reference_plan(mode)
        return ReferenceSearch(phases, inverted)

    def begin(self, search: ReferenceSearch) -> None:
        self.search = search
        self._axis.configure_stops(True)
        self._enter()

    def abort(self) -> None:
        if self.search is not None:
            self.search = None
            self.state = 0
            self._axis.configure_stops(False)

    def _level(self, search: ReferenceSearch, switch: str) -> bool:
        left, right, home = self._axis.switch_levels()
        if switch == "home":
            return home != search.inverted_home
        return left if switch == "left" else right

    def _enter(self) -> None:
        """Start the current phase, or finish phases whose condition already holds."""
        search = self.search
        axis = self._axis
        while search is not None:
            self.state = search.index + 1
            phase = search.phase
            if phase.kind == "finish":
                self._finish_move(search)
                return
            want_active = phase.kind != "leave"
            if self._level(search, phase.switch) == want_active:
                self._phase_done(search)
                search = self.search
                continue
            fast = phase.kind == "seek"
            speed = self._params[AP.RFS_SPEED if fast else AP.RFS_SWITCH_SPEED]
            search.direction = phase.direction
            if phase.reverse_on and self._level(search, phase.reverse_on):
                self._reverse(search)
            axis.start_velocity(search.direction * speed)
            return

    def _phase_done(self, search: ReferenceSearch) -> None:
        phase = search.phase
        if phase.record:
            search.points[phase.record] = self._axis.actual_position()
        self._axis.hard_stop()
        search.index += 1

    def step(self) -> None:
        """React to switch levels during a search (called at every notable instant)."""
        search = self.search
        if search is None:
            return
        axis = self._axis
        phase = search.phase
        if phase.kind == "finish":
            if axis.arrived():
                self._complete()
            return
        if (phase.reverse_on and not search.reversed_once
                and self._level(search, phase.reverse_on)):
            self._reverse(search)
            axis.hard_stop()
            axis.start_velocity(search.direction * self._params[AP.RFS_SPEED])
            axis.update_marks()
            return
        want_active = phase.kind != "leave"
        if self._level(search, phase.switch) == want_active:
            self._phase_done(search)
            self._enter()

    @staticmethod
    def _reverse(search: ReferenceSearch) -> None:
        """Modes 5/6 hit the limit switch: search the other way, and calibrate that way too."""
        search.reversed_once = True
        search.direction = -search.direction
        for phase in search.phases[search.index + 1:]:
            phase.direction = -phase.direction

    def _finish_move(self, search: ReferenceSearch) -> None:
        axis = self._axis
        zero, distance = reference_point(search.points)
        search.points["zero"] = zero
        if distance is not None:
            self._params[AP.SWITCH_DISTANCE] = distance
        axis.start_positioning(zero, self._params[AP.RFS_SWITCH_SPEED])
        if axis.arrived():
            self._complete()

    def _complete(self) -> None:
        axis = self._axis
        self._params[AP.LAST_REFERENCE] = axis.actual_position()
        self.search = None
        self.state = 0
        axis.configure_stops(False)
        axis.zero_counters()
        axis.emit(AxisEventKind.REFERENCE_SEARCH_DONE)
