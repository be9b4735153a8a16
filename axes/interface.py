"""The contract between the module model and one motion axis.

Time is an integer count of nanoseconds of *simulated* time, passed in by the caller; an
axis never reads a clock.  That keeps every axis deterministic and lets the simulator jump
from event to event on a virtual clock.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from axes.world import AxisWorld, LoadZone, Switch


class AxisEventKind(Enum):
    TARGET_REACHED = "target_reached"
    LEFT_SWITCH = "left_switch"
    RIGHT_SWITCH = "right_switch"
    HOME_SWITCH = "home_switch"
    STALL = "stall"
    DEVIATION = "deviation"
    REFERENCE_SEARCH_DONE = "reference_search_done"
    #: The motor current switched between run (active=True) and standby (active=False).
    CURRENT_CHANGED = "current_changed"


@dataclass(frozen=True, slots=True)
class AxisEvent:
    time_ns: int
    axis: int
    kind: AxisEventKind
    #: New level for switch events (True = active); None for the others.
    active: bool | None = None


@dataclass(frozen=True, slots=True)
class AxisStatus:
    """A non-destructive look at an axis (telemetry): reading it clears no flags."""

    position: int
    target: int
    velocity: int
    #: "position" (MVP, ramp to a target) or "velocity" (ROR/ROL/MST), or a finer name the
    #: motion engine uses (for example the TMC4210 ramp mode).
    mode: str
    position_reached: bool
    home_switch: bool = False
    left_switch: bool = False
    right_switch: bool = False
    load: int = 0
    error_flags: int = 0
    #: Motor current now (AP 6 while moving, AP 7 in standby), 0..255.
    current: int = 0
    standby: bool = False
    encoder_position: int = 0
    #: Non-zero while a reference search runs (its phase).
    reference_search: int = 0
    #: Where the mechanics really are (differs from ``position`` when the motor slips).
    mechanical_position: int = 0


class Axis(Protocol):
    """One axis as the TMCL firmware sees it: commands in, axis parameters in and out."""

    index: int

    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        """Run the motion up to simulated time ``t_ns``; return the events that happened."""
        ...

    def next_event_ns(self) -> int | None:
        """Earliest future time at which something observable happens by itself, if any."""
        ...

    def rotate(self, velocity: int) -> None:
        """ROR/ROL: velocity mode with a signed target velocity (pps)."""
        ...

    def stop(self) -> None:
        """MST: velocity mode, target velocity 0 (a ramped stop)."""
        ...

    def move_to(self, target: int) -> None:
        """MVP: positioning mode towards an absolute target."""
        ...

    def emergency_stop(self) -> None:
        """Stop at once (heartbeat timeout, deviation, stall)."""
        ...

    def get_parameter(self, number: int) -> int:
        """GAP: the value of an axis parameter (already validated against the table)."""
        ...

    def set_parameter(self, number: int, value: int) -> None:
        """SAP: write an axis parameter; raise ValueError if the firmware refuses the value."""
        ...

    def reference_search(self, action: int) -> int:
        """RFS START (0) / STOP (1) / STATUS (2); STATUS returns 0 when no search runs."""
        ...

    def status(self) -> AxisStatus:
        """Everything telemetry shows about the axis, without side effects."""
        ...

    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one raw datagram to the chip (None reads); the chip's answer."""
        ...

    # -- the world around the axis (world file, run-time API) ---------------------------------

    @property
    def world(self) -> AxisWorld:
        ...

    def set_world(self, world: AxisWorld) -> None:
        """Replace the switches, load zones and encoder of this axis (edges happen now)."""
        ...

    def set_switch(self, name: str, switch: Switch | None) -> None:
        """Place (or with None remove) the "left", "right" or "home" switch."""
        ...

    def set_load(self, zones: list[LoadZone], free_load: int | None = None) -> None:
        ...

    def set_encoder_slip(self, slip: float) -> None:
        ...

    # -- faults of the mechanics and the wiring (tmcl_server/faults.py) -----------------------

    def set_stuck(self, stuck: bool, load: int | None = None) -> None:
        """The motor stops following its steps (or follows them again); ``load``: what
        stallGuard2 reads meanwhile (None: the world's load)."""
        ...

    def break_switch(self, name: str, level: bool | None) -> None:
        """Hold a switch input at an electrical level (None: repaired)."""
        ...

    def place_mechanics(self, mechanical: int) -> None:
        """After a restart: the mechanics stand at ``mechanical`` (the counters start at 0)."""
        ...
