"""The contract between the module model and one motion axis.

Time is an integer count of nanoseconds of *simulated* time, passed in by the caller; an
axis never reads a clock.  That keeps every axis deterministic and lets the simulator jump
from event to event on a virtual clock.

Two halves, as abstract base classes: :class:`AxisControl` is what the module's firmware
needs of an axis (TMCL commands and time), :class:`AxisRig` what the test rig around it needs
(the world, faults of the mechanics, telemetry); :class:`Axis` is both, and is what a chip
core's axis class subclasses (``axes/cores.py``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, NamedTuple

from axes.world import DEFAULT_ENCODER_COUNTS_PER_REV
from tmcl_spec.modules import FirmwareClock
from tmcl_spec.parameters import ParamSpec

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


class AxisSample(NamedTuple):
    """The part of :class:`AxisStatus` a recorder samples, often (:meth:`AxisRig.sample`)."""

    position: int
    velocity: int
    current: int
    target: int
    position_reached: bool
    left_switch: bool
    right_switch: bool
    home_switch: bool


class NotAvailable(ValueError):
    """The firmware refuses a parameter write in its present state (the module answers
    status 6, "command not available due to current state")."""


#: A time no simulation reaches: "steady until something intervenes".
FOREVER = 1 << 62


class AxisControl(ABC):
    """One axis as the TMCL firmware sees it: commands in, axis parameters in and out, time."""

    index: int

    @abstractmethod
    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        """Run the motion up to simulated time ``t_ns``; return the events that happened."""

    @abstractmethod
    def next_event_ns(self) -> int | None:
        """Earliest future time at which something observable happens by itself, if any."""

    @abstractmethod
    def rotate(self, velocity: int) -> bool:
        """ROR/ROL: velocity mode with a signed target velocity (pps).  Returns whether anything
        changed: False when the axis already does exactly that (a program's loop that writes
        the same speed every pass changes nothing, docs/scheduling.md)."""

    @abstractmethod
    def stop(self) -> bool:
        """MST: velocity mode, target velocity 0 (a ramped stop).  Returns whether anything
        changed (False: already stopping in velocity mode, nothing to clear)."""

    @abstractmethod
    def move_to(self, target: int) -> None:
        """MVP: positioning mode towards an absolute target."""

    def conclude_move(self) -> None:
        """A command is about to start another move.  If the move in flight has reached its
        target already (AP 8 reads 1 while the chip still brakes inside the target step),
        its "target reached" is due now and the next :meth:`advance_to` returns it, so that
        it is not lost with the move.  The default: an axis that reports arrival at rest."""
        return

    @abstractmethod
    def emergency_stop(self) -> None:
        """Stop at once (heartbeat timeout, deviation, stall)."""

    @abstractmethod
    def get_parameter(self, number: int) -> int:
        """GAP: the value of an axis parameter (already validated against the table)."""

    @abstractmethod
    def set_parameter(self, number: int, value: int) -> bool:
        """SAP: write an axis parameter; raise ValueError if the firmware refuses the value.
        Returns whether anything changed (False: a setting written with the value it has)."""

    @abstractmethod
    def reference_search(self, action: int) -> int:
        """RFS START (0) / STOP (1) / STATUS (2); STATUS returns 0 when no search runs."""

    @abstractmethod
    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one raw datagram to the chip (None reads); the chip's answer."""

    def steady_until(self, number: int) -> int:
        """How long GAP ``number`` keeps answering what it answers now, if no command, world
        change or event of this axis intervenes: the answer holds for every time before the
        returned one (:data:`FOREVER`: until something intervenes; the present time or less:
        it may change at any moment).  Reading it changes nothing before then either.

        The interpreter skips the passes of a loop that only re-reads steady values
        (docs/scheduling.md); a core that cannot tell answers 0 and is stepped."""
        return 0

    def first_time_at(self, number: int, values: tuple[int, ...], read_ns: int) -> int:
        """For GAP ``number`` read at ``read_ns`` (a moving value that :meth:`steady_until`
        was asked about right after the read, such as the actual position): the first time
        it compares otherwise with one of ``values`` than it did then, or a time before
        which it surely does not; 0 when the core cannot tell.  A loop comparing a moving
        position with a threshold jumps to the pass where the comparison flips with it."""
        return 0

    def start_firmware_clock(self, clock: FirmwareClock, origin_ns: int, axes: int) -> None:
        """The module's firmware starts at ``origin_ns`` (power-up): its periodic pass over
        its ``axes`` axes runs as ``clock`` says (axes/tasks.py).  An axis that is no TMCL
        firmware's (the evaluation board's) has none: nothing happens."""
        return

    def reset_board(self) -> None:
        """Command 143 type 0 of the evaluation system: the board is detected again and its
        chip configured anew.  A TMCL module's axis has no such board: nothing happens."""
        return


class AxisRig(ABC):
    """One axis as the rig around it sees it: the world (world file, run-time API), faults of
    the mechanics and the wiring (tmcl_server/faults.py), and telemetry."""

    #: Counts per motor revolution of the encoder behind AP 209 where the world names none:
    #: the module's own (``ModuleType.encoder_counts_per_rev``: the sensOstep's 1024), set by
    #: the module after it builds its axes.
    builtin_encoder_counts: int = DEFAULT_ENCODER_COUNTS_PER_REV

    @property
    @abstractmethod
    def world(self) -> AxisWorld:
        """The switches, load zones, encoder and faults around this axis."""

    @abstractmethod
    def set_world(self, world: AxisWorld) -> None:
        """Replace the switches, load zones and encoder of this axis (edges happen now)."""

    @abstractmethod
    def set_switch(self, name: str, switch: Switch | None) -> None:
        """Place (or with None remove) the "left", "right" or "home" switch."""

    @abstractmethod
    def set_load(self, zones: list[LoadZone], free_load: int | None = None) -> None:
        """Replace the load zones (and the load outside them, unless None)."""

    @abstractmethod
    def set_encoder_slip(self, slip: float) -> None:
        """The fraction of the motion the encoder misses (0..1; ValueError outside)."""

    @abstractmethod
    def set_stuck(self, stuck: bool, load: int | None = None) -> None:
        """The motor stops following its steps (or follows them again); ``load``: what
        stallGuard2 reads meanwhile (None: the world's load)."""

    @abstractmethod
    def break_switch(self, name: str, level: bool | None) -> None:
        """Hold a switch input at an electrical level (None: repaired)."""

    @abstractmethod
    def place_mechanics(self, mechanical: int) -> None:
        """After a restart: the mechanics stand at ``mechanical`` (the counters start at 0)."""

    @abstractmethod
    def status(self) -> AxisStatus:
        """Everything telemetry shows about the axis, without side effects."""

    def sample(self) -> AxisSample:
        """What a recorder keeps of the axis at an instant (tmcl_server/record.py), without
        side effects: a part of :meth:`status`, which a core may compute for less."""
        s = self.status()
        return AxisSample(s.position, s.velocity, s.current, s.target, s.position_reached,
                          s.left_switch, s.right_switch, s.home_switch)

    def samples_at(self, first_ns: int, step_ns: int, count: int) -> list[AxisSample]:
        """:meth:`sample` at the first of ``count`` instants ``step_ns`` apart from
        ``first_ns`` on, as far as the core computes them without bringing the axis to each
        (a prefix, the same values; the axis left as bringing it to the last one leaves it,
        nothing due on the way).  By default none: the caller samples them one by one."""
        return []

    def resting(self) -> bool:
        """True when :meth:`sample` answers the same until something intervenes (a command,
        an event, a world change: what the module's epoch counts); False: no promise."""
        return False


class Axis(AxisControl, AxisRig):
    """The whole contract of an axis: what a chip core's axis class implements.

    A core's axis class is built as ``cls(index, parameters, world=..., clock_hz=...)``
    (:meth:`build_axes`, :func:`axes.cores.make_axis`): a subclass keeps that signature.
    """

    def __init__(self, index: int, parameters: Mapping[int, ParamSpec],
                 world: AxisWorld | None = None, clock_hz: int | None = None) -> None:
        """Axis ``index`` with the module's axis-parameter table, the world around it (None:
        an empty one) and its chip's clock (None: the chip's own default)."""
        self.index = index

    @classmethod
    def build_axes(cls, count: int, parameters: Mapping[int, ParamSpec],
                   clock_hz: int | None = None) -> list[Axis]:
        """A module's ``count`` axes on this core: one chip per axis.  A chip that drives
        several motors overrides this to build them in groups sharing a chip."""
        return [cls(index, parameters, clock_hz=clock_hz) for index in range(count)]
