"""The seam between the TMCL firmware layer and an emulated motion-controller chip.

A *chip model* is the silicon: a register file behind SPI datagrams and the motion it makes.
It counts time in its own clock ticks and never reads a clock; the firmware layer above it
asks it to run up to a tick and is told when something notable happens on the way, so that
the simulator can jump from event to event.  Every chip (TMC4210, TMC429, TMC4361A) subclasses
:class:`ChipModel`; the chip-specific half of the firmware that drives one subclasses
:class:`ChipDriver`, whose optional members have their defaults here, in one place.

The pins a chip reads (reference switches, home, encoder) are driven by a :class:`Board`:
the module's input stage and the mechanics of the world (``axes/board.py``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable
from enum import IntEnum
from typing import TYPE_CHECKING, Protocol, Self

from tmcl_spec.numbers import NS_PER_S

#: How far ahead the firmware looks for the next event (a driver's :attr:`ChipDriver.
#: lookahead_ns` by default); also bounds how many steps pass between two reads of a 24-bit
#: position register (4 s at 1 Mpps is well below 2**23).
LOOKAHEAD_NS = 4 * NS_PER_S


class Stop(IntEnum):
    """Why :meth:`ChipModel.run` returned before its end tick."""

    ARRIVED = 1  # positioning ended at the target
    STOPPED = 2  # the velocity became zero some other way
    MARK = 3  # the motor reached a position the board asked to be told about
    EVENT = 4  # a chip event the firmware reacts to (switch, latch, velocity reached, ...)


class StaleLookahead(RuntimeError):
    """A look-ahead copy no longer matches its chip (something wrote to the chip since the copy
    was made, e.g. another motor of a multi-motor chip): look ahead again."""


class Board(Protocol):
    """What a chip's inputs are wired to: the module's input stage and the mechanics."""

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        """Electrical levels of (left stop, right stop, home) with the motor at ``motor_position``."""
        ...

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        """The nearest motor position beyond ``motor_position`` in ``direction`` that matters."""
        ...


class ChipModel(ABC):
    """One emulated motion controller (or one motor of a multi-motor chip).

    Host access is :meth:`spi` only, as on the real board; the other members serve the
    simulator's time keeping and the world's pins.  A subclass implements every abstract
    method and sets the attributes (:attr:`motor_position` may be a property).
    """

    clock_hz: int
    #: Chip clock ticks fully processed (the chip's own unit of time).
    t: int

    if TYPE_CHECKING:  # read through the contract; a plain attribute or a property of the chip
        @property
        def motor_position(self) -> int:
            """Steps that reached the motor, as an unwrapped integer (what the mechanics follow)."""
            ...

    @abstractmethod
    def spi(self, frame: int) -> int:
        """Exchange one datagram (its width is the chip's: 32 bits TMC4210/TMC429, 40 TMC4361A)."""

    @abstractmethod
    def clone(self) -> Self:
        """An independent copy, to look ahead without disturbing this chip."""

    @abstractmethod
    def adopt(self, twin: Self) -> Self:
        """Continue with the state a :meth:`clone` reached; returns the chip to use from now on
        (the twin itself for a one-motor chip, this object for a motor of a shared chip).
        Raises :class:`StaleLookahead` if the twin no longer fits."""

    @abstractmethod
    def run(self, until: int, budget: int | None = None) -> Stop | None:
        """Advance to tick ``until``; return early (``t < until``) at a notable instant.

        ``budget`` bounds the work of one call (in the engine's own steps, e.g. ramp ticks
        it cannot take in closed form): when it runs out, return None with ``t < until``.
        The firmware's look-ahead passes one, so no setting can make a request's work
        unbounded; bringing the chip to the present passes none.
        """

    @abstractmethod
    def at_rest(self) -> bool:
        """True if nothing will change by itself until a datagram or a pin changes it."""

    @abstractmethod
    def ticks_at(self, t_ns: int) -> int:
        """Ticks that have happened by simulated time ``t_ns``."""

    @abstractmethod
    def ns_at(self, ticks: int) -> int:
        """Simulated time (ns, rounded up) of tick ``ticks``."""

    @abstractmethod
    def set_pins(self, left: bool, right: bool, home: bool) -> None:
        """Drive the switch inputs (electrical levels); edges act at once."""

    def steps_reach_motor(self) -> bool:
        """Whether every step the position counter counts moves the motor (then the counter
        and :attr:`motor_position` change together, and a mark at a motor position is a mark
        at a counter value).  A chip whose step output can be switched off says so."""
        return True


class MotorDriverLink(ABC):
    """The firmware's routines for a modelled motor driver IC (the TMC262 on the TMC429
    modules), reached by the chip driver: the current, microsteps, stallGuard2 and coolStep
    parameters act on the driver chip's registers and are read back from it.  Without one,
    :class:`axes.firmware.AxisFirmware` computes them itself (axes/stallguard.py).  The
    firmware reads the driver's readings in its periodic pass (axes/tasks.py, TMCL-LITE-1110
    SysControl.c line 104) and answers AP 206/180/208 from what that pass read."""

    #: Axis parameters whose writes go to the driver chip (:meth:`configure`).
    parameters: frozenset[int]

    @abstractmethod
    def configure(self, number: int | None = None) -> None:
        """Write the driver registers parameter ``number`` is part of (None: all of them)."""

    @abstractmethod
    def set_current(self, value: int) -> None:
        """The motor current now, 0..255 (AP 6, AP 7 or AP 183)."""

    @abstractmethod
    def switch_coolstep(self, on: bool) -> None:
        """The firmware's coolStep switch: SEMIN = AP 172 (on) or 0 (off)."""

    @abstractmethod
    def sample(self, chip: ChipModel | None = None) -> None:
        """Read the driver's stallGuard2 value, coolStep current and flags, as the firmware's
        pass does; :meth:`load`, :meth:`current_scale` and :meth:`flags` answer from it.
        ``chip``: read the driver of that copy of the axis's chip instead (a pass taken on a
        copy made before the chip went past its instant, axes/tasks.py T2)."""

    @abstractmethod
    def observe(self) -> None:
        """Let the driver catch up with the steps the motor made (at a load edge: its
        measurements so far read the load before it), reading nothing for the firmware."""

    @abstractmethod
    def load(self) -> int:
        """AP 206: the stallGuard2 value the last :meth:`sample` read."""

    @abstractmethod
    def stalled(self) -> bool:
        """The driver's stall output now (its stallGuard2 flag: the last measurement read 0)."""

    @abstractmethod
    def current_scale(self) -> int:
        """AP 180: the coolStep current scale (0..31) the last :meth:`sample` read (the
        current's own scale while coolStep is off)."""

    @abstractmethod
    def flags(self) -> int:
        """AP 208: the driver's status flags the last :meth:`sample` read."""


class ChipDriver(ABC):
    """The chip-specific half of the TMCL firmware for one axis: what it does with its chip.

    The generic half (:class:`axes.firmware.AxisFirmware`: parameters, reference search,
    stallGuard, encoder, current, events, time) calls these; a driver talks to :attr:`chip`
    through SPI datagrams only.  Speeds are in the axis's units (pps, or the chip's own in
    unit mode 0), positions are the 32-bit AP 1 / AP 0 values.  The members with a body are
    optional: their defaults are what a driver without that feature does.
    """

    #: The chip; the firmware replaces it by a look-ahead copy it has run forward.
    chip: ChipModel
    #: AP 1 as of the last :meth:`read_position`.
    position: int

    # -- optional, with their defaults -------------------------------------------------------

    #: Chip-specific axis parameters read from the chip at the present time, through
    #: :meth:`read_parameter` (the TMC42x drivers: AP 135, AP 138).
    live_parameters: frozenset[int] = frozenset()
    #: A modelled motor driver IC behind the chip driver (the TMC429 modules' TMC262): the
    #: current, microstep, stallGuard2 and coolStep parameters act on it.
    motor_driver: MotorDriverLink | None = None
    #: How far the firmware runs a look-ahead copy of the chip (:data:`LOOKAHEAD_NS` keeps
    #: 24-bit position registers unambiguous; a chip with a 32-bit position may look further).
    lookahead_ns: int = LOOKAHEAD_NS
    #: The width of AP 1 as the firmware reads it (two's complement): past
    #: ``2**(position_bits - 1) - 1`` it goes on at ``-2**(position_bits - 1)``, and the other
    #: way round.  A comparison with the position flips there without meeting its boundary,
    #: so loop skipping's forecast stops at the wrap too (axes/forecast.py, F3).  32: the
    #: whole TMCL value; a firmware that reads a narrower register as AP 1 says so.
    position_bits: int = 32

    #: Parameters whose writes :meth:`check_write` sees first (a value the chip cannot run).
    checked_parameters: frozenset[int] = frozenset()

    def check_write(self, number: int, value: int) -> None:
        """Refuse a write of one of :attr:`checked_parameters` the chip cannot follow
        (ValueError: status 4; ``axes.interface.NotAvailable``: status 6)."""
        return

    def horizon_ns(self) -> int:
        """How far the next look-ahead may run: :attr:`lookahead_ns`, or as far as the chip's
        present settings keep its position registers unambiguous (TMC42x)."""
        return self.lookahead_ns

    def read_parameter(self, number: int) -> int:
        """The value of one of :attr:`live_parameters`, read from the chip."""
        raise ValueError(f"{type(self).__name__} reads no axis parameter {number} from its chip "
                         f"(it is not one of its live_parameters)")

    def set_positioning_mode(self) -> None:
        """AP 138 (ramp or soft positioning) changed during a move: apply it to the move in
        flight (TMC42x).  A chip without that choice has nothing to do."""
        return

    # -- required ------------------------------------------------------------------------------

    @abstractmethod
    def power_up(self) -> None:
        """Initialise the chip as the firmware does after reset."""

    @abstractmethod
    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one raw datagram (None reads); the chip's answer as signed 32 bit."""

    # -- readings at the chip's present ----------------------------------------------------------

    @abstractmethod
    def read_position(self) -> int:
        """Read the position from the chip (and keep it in :attr:`position`)."""

    @abstractmethod
    def moving(self) -> bool:
        """True while the motor moves (or a ramp is about to move it)."""

    @abstractmethod
    def actual_speed(self) -> int:
        """AP 3: signed speed now."""

    def readings_at(self, ticks: Iterable[int]) -> tuple[list[int], list[int]]:
        """AP 1 and AP 3 at each of a prefix of ``ticks`` (the chip's ticks, ascending, none
        before its present), exactly as :meth:`read_position` and :meth:`actual_speed` would
        read them from the chip brought to each, without bringing it there: where the
        chip's motion has a closed form (a standing velocity, or a ramp whose speed moves
        the same amount each ramp tick) and a read changes nothing but what it answers.
        The prefix stops at the first tick the driver cannot give exactly.  The positions
        count as read (:attr:`position` is the last one's).  A recorder's samples of a
        moving axis (AxisFirmware.samples_at); a driver without a closed form gives none
        (the caller runs the chip)."""
        return [], []

    def speed_on(self, chip: ChipModel) -> int:
        """AP 3 as the firmware would read it from ``chip``, a look-ahead copy of its own (to
        find when a speed crosses a value; the copy is not used afterwards).  A driver whose
        :meth:`actual_speed` keeps state of its own overrides this."""
        own = self.chip
        self.chip = chip
        try:
            return self.actual_speed()
        finally:
            self.chip = own

    def speed_turns(self, start: ChipModel) -> Callable[[ChipModel], bool] | None:
        """How far AP 3 moves one way from ``start`` (a look-ahead copy of its own chip, in
        velocity mode, nothing intervening): a test of a later copy of ``start``, true once
        the speed may have turned (moved one way, then the other) by that copy's tick, false
        before (so false, then true: loop skipping bisects a rotation's speed only where it
        is false, axes/forecast.py F4).  None, the default, is a linear ramp's answer: it
        only heads for the speed asked for, it never turns.  A chip whose ramps bend
        (S-shaped) says where they may."""
        return None

    def positioning_speed(self, start: ChipModel) -> tuple[Callable[[ChipModel], bool],
                                                           int] | None:
        """How far a positioning move's AP 3 moves one way from ``start`` (a look-ahead copy
        of its own chip in positioning mode, nothing intervening): (a test of a later copy of
        ``start`` as :meth:`speed_turns` gives, false, then true once the speed may have
        turned; the motor steps from ``start`` to where the chip's target is first met, up to
        which that test holds, loop skipping's end of the stretch: axes/forecast.py F8).
        None, the default: no promise (the speed rises and falls; it is stepped)."""
        return None

    @abstractmethod
    def levels(self) -> tuple[bool, bool, bool]:
        """Logical (left, right, home) switch levels as the chip reports them."""

    @abstractmethod
    def take_switch_stop(self) -> bool:
        """True once after a stop switch stopped the motor (the flag is cleared)."""

    @abstractmethod
    def mode_name(self) -> str:
        """Telemetry's name for the chip's mode: "position", "velocity", "hold", ..."""

    @abstractmethod
    def heading(self) -> int:
        """Direction of travel, or of the travel about to start (-1, 0, +1)."""

    # -- commands ----------------------------------------------------------------------------

    @abstractmethod
    def start_velocity(self, speed: int) -> None:
        """ROR/ROL: run at a signed speed with AP 5's acceleration."""

    @abstractmethod
    def start_positioning(self, target: int, top_speed: int) -> None:
        """MVP: ramp to ``target`` at up to ``top_speed``."""

    @abstractmethod
    def continue_move(self, target: int) -> None:
        """At a notable instant of a move to ``target`` (rolling targets on narrow chips)."""

    @abstractmethod
    def refill_mark(self, target: int) -> int | None:
        """A motor position the firmware must be woken at during a move (or None)."""

    @abstractmethod
    def ramp_stop(self) -> None:
        """MST: decelerate to standstill."""

    @abstractmethod
    def hard_stop(self) -> None:
        """Stop at once."""

    @abstractmethod
    def set_position(self, value: int) -> bool:
        """AP 1 write; True if a move in flight was turned into a ramped stop."""

    @abstractmethod
    def limits_changed(self, positioning: bool, velocity_command: int) -> None:
        """A speed, acceleration, ramp or unit parameter changed: re-plan what runs."""

    @abstractmethod
    def configure_stops(self, searching: bool) -> None:
        """Stop switches as the parameters say; a reference search drives through them."""
