"""What an axis will do if nothing intervenes: its next notable instant, how long a parameter
keeps its answer, and when a moving value first reaches a boundary.

The firmware (:class:`axes.firmware.AxisFirmware`) finds its next event by running a *copy*
of its chip forward (the look-ahead), and adopts the copy at that instant so each stretch of
motion is computed once.  The interpreter's loop skipping (interpreter/skipping.py, I3 and I5)
asks the same forecast how long a read keeps its answer (:meth:`AxisForecast.steady_until`)
and when a moving read first compares otherwise with a boundary
(:meth:`AxisForecast.first_time_at`).  Its answers are exact, by these invariants (cited
where the code relies on them):

F1. Between notable instants nothing intervenes in the chip.  The chip runs by itself to its
    next notable instant (a :class:`axes.core.Stop`: arrival, a switch edge, a mark, the
    horizon), where the firmware reacts (an event, which ends the interpreter's batch, I1);
    the look-ahead is that run, made on a copy; anything else (a command, a world change)
    invalidates it and a new one is made.
F2. The table says how each parameter moves (:class:`tmcl_spec.parameters.Motion`).  A
    SETTING or a PROGRAM value changes only by a command; an EVENTS value only at a notable
    instant (switch edges are chip marks); so either holds until something intervenes.  An
    AXIS value holds while the axis rests (the look-ahead finds no motion) and otherwise
    only where a forecast below says so; an ACCESS value holds only while reading it changes
    nothing.  A row that says nothing is refused when its module type is built, never taken
    as steady.
F3. A position moves one microstep at a time, so AP 1 meets every value between two of its
    readings; a copy of the chip with a mark at each boundary's motor position stops at the
    first step that reaches one (AP 1 and the motor position move together).
F4. A rotation's ramp only heads for the speed asked for, monotonically, until the next
    notable instant: the same speed at both ends of that stretch is the same speed all along
    it, and the first tick at which the speed compares otherwise with a boundary is found by
    bisecting a copy of the chip over the clock ticks.
F5. A crossing found is kept while the look-ahead it was found for is the current one (its
    identity): a new look-ahead is made after every change (F1).
F6. What the firmware's periodic pass keeps for reads (AP 180, a modelled driver's AP
    206/208) changes only at that pass (axes/tasks.py, T3): it holds until the next pass that
    may change it.  No read changes anything a later read sees, so a read left out (skipped,
    or answered from the look-ahead as AP 8 is) is never missed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

from axes.board import AxisBoard
from axes.core import ChipDriver, ChipModel, Stop
from axes.interface import FOREVER
from axes.tasks import FirmwareTasks
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP, Motion

#: At most this much engine work (ramp ticks not taken in closed form) per look-ahead: past
#: it the look-ahead stops short and the axis looks again from there when that time comes.
LOOKAHEAD_BUDGET = 2_000


@dataclass(slots=True)
class Lookahead:
    """A copy of the chip run to its next notable instant."""

    chip: ChipModel
    stop: Stop | None  # None: nothing happened up to the horizon
    time_ns: int


class ForecastedAxis(Protocol):
    """What the forecast needs of its axis (``axes.firmware.AxisFirmware``)."""

    driver: ChipDriver
    board: AxisBoard
    tasks: FirmwareTasks

    def present_ns(self) -> int:
        """The simulated time the axis was last brought to."""
        ...

    def sync(self) -> None:
        """Bring the chip up to the present and read its position."""
        ...

    def actual_speed(self) -> int:
        ...

    def target_position(self) -> int:
        """AP 0."""
        ...

    def in_velocity_mode(self) -> bool:
        """ROR, ROL or MST, no reference search: the speed only heads for the one asked for."""
        ...

    def error_flags(self) -> int:
        """AP 207 as a read would answer it now (and clear it)."""
        ...


class AxisForecast:
    """The look-ahead of one axis, and the forecasts loop skipping asks for (F1-F6)."""

    def __init__(self, axis: ForecastedAxis, motions: dict[int, Motion]) -> None:
        self._axis = axis
        #: How each parameter moves, by the firmware layer's number (the module's table).
        self._motions = motions
        #: The chip's next notable instant (None: nothing ahead), once computed since the last
        #: change (``known``).
        self.cached: Lookahead | None = None
        self.known = False
        #: The last crossing found: (the look-ahead it holds for, values, time) (F5).
        self._crossing: tuple[Lookahead, tuple[int, ...], int] | None = None

    def invalidate(self) -> None:
        """Something changed the chip or what it runs into (F1): look again when asked."""
        self.known = False

    def lookahead(self) -> Lookahead | None:
        """Run a copy of the chip to its next notable instant (or the horizon)."""
        if self.known:
            return self.cached
        driver = self._axis.driver
        chip = driver.chip
        twin = chip.clone()
        horizon_ns = max(self._axis.present_ns(), chip.ns_at(twin.t)) + driver.horizon_ns()
        stop = twin.run(twin.ticks_at(horizon_ns), LOOKAHEAD_BUDGET)
        at_rest = stop is None and twin.at_rest()
        result = None if at_rest else Lookahead(twin, stop, twin.ns_at(twin.t))
        self.cached = result
        self.known = True
        return result

    # == loop skipping's questions (interpreter/skipping.py I3, I5) ==============================

    def steady_until(self, number: int) -> int:
        """How long GAP ``number`` (the firmware's numbering) keeps its answer (F2)."""
        motion = self._motions.get(number)
        if motion is Motion.SETTING or motion is Motion.PROGRAM:  # (an Enum hashes slowly)
            return FOREVER  # only a command changes it
        tasks = self._axis.tasks
        if tasks.kept(number):
            return tasks.steady_until()  # F6
        if motion is Motion.ACCESS:
            # reading clears the error flags: steady only while there are none (F2)
            return FOREVER if number == AP.ERROR_FLAGS and not self._axis.error_flags() else 0
        ahead = self.lookahead()
        if ahead is None:
            return FOREVER  # at rest: what it reads changes only at an event or a command
        if motion is Motion.EVENTS:
            return FOREVER  # switch levels and the like change only at notable instants (F2)
        if number == AP.POSITION_REACHED:
            return self._first_time_at_position((self._axis.target_position(),), ahead)
        if number == AP.ACTUAL_SPEED and self._axis.in_velocity_mode():
            # F4: the same speed at both ends of the stretch means the same speed all along it
            axis = self._axis
            axis.sync()
            if axis.driver.speed_on(ahead.chip.clone()) == axis.actual_speed():
                return ahead.time_ns
        return 0  # a moving quantity

    def first_time_at(self, number: int, values: tuple[int, ...]) -> int:
        """The first time GAP ``number`` compares otherwise with one of ``values`` (F3, F4)."""
        ahead = self.lookahead()
        if number == AP.ACTUAL_POSITION:
            return FOREVER if ahead is None else self._first_time_at_position(values, ahead)
        if number == AP.ACTUAL_SPEED and self._axis.in_velocity_mode():
            return FOREVER if ahead is None else self._first_time_speed_crosses(values, ahead)
        return 0

    def short_of_target(self) -> bool:
        """AP 8 reads 0 now for certain, without bringing the chip up to now: the position
        first meets the target later than now (found once per look-ahead with a copy of the
        chip, as :meth:`steady_until` does).  A host or program polling AP 8 through a long
        move then costs a comparison a poll, not a run of the chip's ramp to every poll."""
        axis = self._axis
        ahead = self.lookahead()
        if ahead is None:
            return False  # at rest: the plain read is cheap
        return axis.present_ns() < self._first_time_at_position((axis.target_position(),),
                                                                ahead)

    def _first_time_speed_crosses(self, values: tuple[int, ...], ahead: Lookahead) -> int:
        """The first time AP 3 compares otherwise with one of ``values`` than now (reaches it,
        or passes it), or the next notable instant: the speed being monotonic there (F4), a
        copy of the chip is bisected over the clock ticks."""
        axis = self._axis
        driver = axis.driver
        axis.sync()
        speed = axis.actual_speed()
        if speed in values:
            return 0
        above = [speed > value for value in values]

        def compares_otherwise(chip: ChipModel) -> bool:
            now = driver.speed_on(chip)
            return any(now == value or (now > value) != side
                       for value, side in zip(values, above, strict=True))

        if not compares_otherwise(ahead.chip.clone()):
            return ahead.time_ns
        low, high = driver.chip.clone(), ahead.chip.t
        while high - low.t > 1:
            middle = (low.t + high) // 2
            probe = low.clone()
            probe.run(middle, LOOKAHEAD_BUDGET)
            if probe.t < middle:  # stopped short (its work budget): no promise beyond here
                return probe.ns_at(probe.t)
            if compares_otherwise(probe.clone()):
                high = middle
            else:
                low = probe
        return low.ns_at(high)

    def _first_time_at_position(self, values: tuple[int, ...], ahead: Lookahead) -> int:
        """The first time AP 1 equals one of ``values``, or the chip's next notable instant
        if it does not before: a copy of the chip runs with a mark at each value's motor
        position (F3).  Kept while the look-ahead it was found for holds (F5)."""
        cached = self._crossing
        if cached is not None and cached[0] is ahead and cached[1] == values:
            return cached[2]
        axis = self._axis
        axis.sync()
        chip = axis.driver.chip
        if not chip.steps_reach_motor():
            return 0  # AP 1 counts steps that do not move the motor: no marks to set
        here = axis.driver.position
        marks = [chip.motor_position + to_int32(value - here) for value in values]
        if chip.motor_position in marks:
            return 0
        twin = chip.clone()
        board = axis.board
        saved = board.firmware_marks
        board.firmware_marks = saved + marks
        until = twin.ticks_at(ahead.time_ns)
        try:  # it stops early at a mark (or, conservatively, at anything else)
            twin.run(until, LOOKAHEAD_BUDGET)
        finally:
            board.firmware_marks = saved
        result = twin.ns_at(twin.t) if twin.t < until else ahead.time_ns
        self._crossing = (ahead, values, result)
        return result
