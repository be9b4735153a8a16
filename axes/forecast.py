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
    readings, except where it wraps: past the top of its range (the driver's
    ``position_bits``) it goes on at the bottom, and the other way round.  A comparison with
    it therefore flips only where it meets the boundary or where it wraps (COMP compares the
    wrapped values: ``GAP 1; COMP 0`` turns from greater to less at the wrap); a copy of the
    chip with a mark at each boundary's motor position and at both ends of the wrap stops at
    the first step that reaches one (AP 1 and the motor position move together).
F4. A rotation's speed is monotonic only as far as its driver says
    (:meth:`axes.core.ChipDriver.speed_turns`): a linear ramp heads for the speed asked for;
    an S-shaped one first takes back the acceleration of the other slope, so a rotation
    asked for more speed while braking dips first, and one asked for less while
    accelerating overshoots.  Over a stretch where it is monotonic, the same speed at both
    ends is the same speed all along (the end's own tick may change it at once, a stop
    switch met there: the speed a clock before the end is compared too), and the first
    tick at which the speed compares otherwise with a boundary is found by bisecting a copy
    of the chip over the clock ticks; past the point where it may turn there is no promise
    (the driver's test is false, then true, so the same bisection finds whichever comes
    first).
F5. A crossing found is kept while the look-ahead it was found for is the current one (its
    identity): a new look-ahead is made after every change (F1).  A crossing found from an
    earlier instant of the same look-ahead is still the first one after any later instant
    it does not precede (and one it precedes promises nothing).  So is a speed's answer
    (F4, F8): up to it the speed compared alike and did not turn, so from a later read
    before it, nothing changes before it either.
F6. What the firmware's periodic pass keeps for reads (AP 180, a modelled driver's AP
    206/208) changes only at that pass (axes/tasks.py, T3): it holds until the next pass that
    may change it.  No read changes anything a later read sees, so a read left out (skipped,
    or answered from the look-ahead as AP 8 is) is never missed.
F7. A crossing is searched from the read's own instant.  Loop skipping asks
    :meth:`AxisForecast.steady_until` right after each read of its pass, and only after the
    whole pass :meth:`AxisForecast.first_time_at`, when a later command of the same pass (a
    ``GAP 8`` after the ``GAP 1``) may have brought the axis further: a crossing in between
    would be missed and the axis overshoot.  So a moving read keeps a copy of the chip at
    its instant (:class:`Reading`), under the look-ahead it was made in, and the search
    starts from that copy; without one (or under another look-ahead) there is no promise.
F8. A positioning move's speed rises and falls, but its driver may say over which stretches
    it moves one way (:meth:`axes.core.ChipDriver.positioning_speed`): a test as F4's (false,
    then true once the speed may have turned) that holds up to where the position first
    meets the chip's target (a copy of the chip with a mark there, F3, ends the stretch;
    past it the move may overshoot and come back).  On a TMC42x ramp or soft move with no
    stop switch in play the speed is below the positioning curve's target (towards the
    target's side) and a ramp tick only raises it, until it reaches the curve; from then on
    it only falls, for the curve falls with the distance (shared/spec/tmc4210.md §4.8,
    ``MotorLaw.ramp_tick``): one bisection for the rise, then one for the fall.  On a
    TMC4361A trapezoid move towards its target the speed heads for VMAX and falls once the
    final approach begins (``TMC4361A.positioning_turns``; a rest, where a move may start
    again at VSTART, is a STOPPED instant, which ends every run).  A driver that says
    nothing (S-shaped ramps, which may first take back their acceleration) makes no
    promise: stepped.
F9. A copy made under the current look-ahead from the chip or a read's copy (F7), run with
    no marks but the board's own to a clock before the look-ahead's end, is the chip itself
    at that clock (F1: the same run, and the engines are exact however a run is cut).  So
    the chip, brought to that clock or past it, goes on from a clone of the copy (a
    stretch's clock before its end, a search's last copy short of a flip: where a skipped
    program wakes) instead of running the same way again.  (Copies at a few points of the
    look-ahead's own run were tried: their clones cost more than they saved, for a run
    along a brake the engine remembered is cheap.)
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

from axes.board import AxisBoard
from axes.core import ChipDriver, ChipModel, Stop
from axes.interface import FOREVER
from axes.tasks import FirmwareTasks
from tmcl_spec.parameters import AP, Motion

#: At most this much engine work (ramp ticks not taken in closed form) per look-ahead: past
#: it the look-ahead stops short and the axis looks again from there when that time comes.
LOOKAHEAD_BUDGET = 2_000
#: Copies on the chip's way kept per look-ahead (F9): a search keeps its last one or two.
WAY_KEPT = 8
#: Moving reads kept per axis (F7): a pass reads one axis a few times; an older read's
#: crossing is not forecast (no promise), which only costs speed.
READINGS_KEPT = 8


@dataclass(slots=True)
class Lookahead:
    """A copy of the chip run to its next notable instant."""

    chip: ChipModel
    stop: Stop | None  # None: nothing happened up to the horizon
    time_ns: int


class StretchEnd(NamedTuple):
    """Where a run of a copy of the chip stopped: its instant, the copy there, and whether
    that last tick was a plain one (nothing notable: the speed did not change at once)."""

    time_ns: int
    chip: ChipModel
    plain: bool


@dataclass(slots=True)
class Reading:
    """A moving read, kept so that its crossing is searched from its instant (F7)."""

    number: int
    time_ns: int
    ahead: Lookahead
    chip: ChipModel  # a copy of the chip at the read
    position: int  # AP 1 at the read


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
    """The look-ahead of one axis, and the forecasts loop skipping asks for (F1-F9)."""

    def __init__(self, axis: ForecastedAxis, motions: dict[int, Motion]) -> None:
        self._axis = axis
        #: How each parameter moves, by the firmware layer's number (the module's table).
        self._motions = motions
        #: The chip's next notable instant (None: nothing ahead), once computed since the last
        #: change (``known``).
        self.cached: Lookahead | None = None
        self.known = False
        #: The last crossing found: (the look-ahead it holds for, values, the instant it was
        #: searched from, time) (F5).
        self._crossing: tuple[Lookahead, tuple[int, ...], int, int] | None = None
        #: The last moving reads loop skipping asked about, oldest first (F7).
        self._readings: list[Reading] = []
        #: The last target meeting found for a positioning move's speed: (the look-ahead, the
        #: motor position marked, the read it was searched from, (instant, chip)) (F5, F8).
        self._met: tuple[Lookahead, int, int, StretchEnd] | None = None
        #: The last speed crossing found: (the look-ahead, values, the read's instant, time):
        #: the same answer for a later read it does not precede (F5).
        self._speed_crossing: tuple[Lookahead, tuple[int, ...], int, int] | None = None
        #: A stretch's end (a copy of the chip there) and a copy a clock before it: the same
        #: end comes back from the caches above for every read of a look-ahead (F5)
        self._before_end: tuple[ChipModel, ChipModel] | None = None
        #: Copies on the chip's way under the look-ahead ``_way_of`` (F9): the searches'
        #: copies short of their answers.
        self._way: list[ChipModel] = []
        self._way_of: Lookahead | None = None

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
        self._way, self._way_of = [], result
        return result

    def copy_on_the_way(self, since: int, until: int) -> ChipModel | None:
        """A clone of the furthest copy kept on the chip's way (F9) after clock ``since`` and
        no later than ``until``, under the current look-ahead; else None."""
        if not self.known or self._way_of is not self.cached:
            return None
        best = None
        for copy in self._way:
            if since < copy.t <= until and (best is None or copy.t > best.t):
                best = copy
        return None if best is None else best.clone()

    def _on_the_way_to(self, copy: ChipModel, ahead: Lookahead) -> None:
        """Keep ``copy`` (F9: made under ``ahead``, the current look-ahead, short of its
        end); the oldest kept goes when there are more than WAY_KEPT."""
        if ahead is self._way_of and copy.t < ahead.chip.t:
            way = self._way
            if len(way) >= WAY_KEPT:
                del way[0]
            way.append(copy)

    # == loop skipping's questions (interpreter/skipping.py I3, I5) ==============================

    def steady_until(self, number: int) -> int:
        """How long GAP ``number`` (the firmware's numbering), just read, keeps its answer (F2);
        a moving position or speed is kept for :meth:`first_time_at` (F7)."""
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
            axis = self._axis
            axis.sync()
            # F4: the same speed at both ends of a monotonic stretch is the same all along it
            if axis.driver.speed_on(ahead.chip.clone()) == axis.actual_speed():
                turns = axis.driver.speed_turns(axis.driver.chip)
                if (turns is None or not turns(ahead.chip)) and self._same_speed_before_end(ahead):
                    return ahead.time_ns
            self._keep_reading(number, ahead)
        elif number == AP.ACTUAL_POSITION or number == AP.ACTUAL_SPEED:
            self._keep_reading(number, ahead)  # (a positioning move's speed: F8)
        return 0  # a moving quantity

    def _same_speed_before_end(self, ahead: Lookahead) -> bool:
        """F4 for the stretch up to the look-ahead's end, whose own tick may change the speed
        at once (a stop switch met there: the rotation reads 0 at both ends, and not in
        between): the speed a clock before the end is the one read too.  A horizon's tick
        is a plain one."""
        axis = self._axis
        chip = axis.driver.chip
        if ahead.stop is None or ahead.chip.t - 1 <= chip.t:
            return True
        before = self._clock_before(chip, ahead.chip)
        if before.t != ahead.chip.t - 1:
            return False  # (stopped short: no promise)
        self._on_the_way_to(before, ahead)  # F9
        return axis.driver.speed_on(before.clone()) == axis.actual_speed()

    def _keep_reading(self, number: int, ahead: Lookahead) -> None:
        """Keep a copy of the chip at this read, if it is at the read's instant (F7)."""
        axis = self._axis
        chip = axis.driver.chip
        now = axis.present_ns()
        if chip.t != chip.ticks_at(now):
            return  # not brought to the read: its crossing gets no promise
        readings = self._readings
        if len(readings) >= READINGS_KEPT:
            del readings[0]
        readings.append(Reading(number, now, ahead, chip.clone(), axis.driver.position))

    def _reading(self, number: int, time_ns: int, ahead: Lookahead) -> Reading | None:
        """The kept read of GAP ``number`` at ``time_ns`` under ``ahead`` (F7), if any."""
        for reading in reversed(self._readings):
            if reading.number == number and reading.time_ns == time_ns:
                return reading if reading.ahead is ahead else None
        return None

    def first_time_at(self, number: int, values: tuple[int, ...], read_ns: int) -> int:
        """The first time GAP ``number``, read at ``read_ns`` (a moving read loop skipping
        asked :meth:`steady_until` about), compares otherwise with one of ``values`` than it
        did then (F3, F4, F7); 0: no promise."""
        ahead = self.lookahead()
        if ahead is None:
            return 0  # at rest now, moving at the read: something happened in between
        reading = self._reading(number, read_ns, ahead)
        if reading is None:
            return 0
        if number == AP.ACTUAL_POSITION:
            half = 1 << (self._axis.driver.position_bits - 1)
            return self._first_time_at_position((*values, -half, half - 1), ahead,
                                                reading)  # F3
        if number != AP.ACTUAL_SPEED:
            return 0
        cached = self._speed_crossing
        if (cached is not None and cached[0] is ahead and cached[1] == values
                and cached[2] <= read_ns < cached[3]):
            return cached[3]  # F5: it compares alike from the earlier read up to then
        result = self._first_time_speed_changes(values, reading, ahead)
        self._speed_crossing = (ahead, values, read_ns, result)
        return result

    def _first_time_speed_changes(self, values: tuple[int, ...], reading: Reading,
                                  ahead: Lookahead) -> int:
        """:meth:`first_time_at` for AP 3: a rotation's (F4), a positioning move's (F8)."""
        driver = self._axis.driver
        if self._axis.in_velocity_mode():
            return self._first_time_speed_crosses(values, reading.chip,
                                                  driver.speed_turns(reading.chip),
                                                  StretchEnd(ahead.time_ns, ahead.chip,
                                                             ahead.stop is None), ahead)  # F4
        plan = driver.positioning_speed(reading.chip)
        if plan is None:
            return 0
        turns, steps = plan
        start = reading.chip
        if not start.steps_reach_motor():
            return 0  # the target's meeting cannot be marked
        # F8: monotonic between the turns the driver's test finds, up to the target's meeting
        return self._first_time_speed_crosses(values, start, turns,
                                              self._meeting(start, steps, reading, ahead),
                                              ahead)

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

    def _first_time_speed_crosses(self, values: tuple[int, ...], start: ChipModel,
                                  turns: Callable[[ChipModel], bool] | None,
                                  end: StretchEnd, ahead: Lookahead) -> int:
        """The first time AP 3 compares otherwise with one of ``values`` than on ``start`` (a
        copy of the chip at the read: reaches one, or passes it), or where the speed may
        turn (``turns``, the driver's test: F4, F8), or ``end`` (an instant and a copy of the
        chip there, which the speed is monotonic up to if it does not turn before: the next
        notable instant, or a positioning move's meeting with its target): over a stretch
        where it is monotonic, a copy of the chip is bisected over the clock ticks (one
        bisection finds whichever comes first: both tests are false, then true).  The last
        copy short of the answer is kept for the chip's own run there (F9)."""
        driver = self._axis.driver
        speed = driver.speed_on(start.clone())
        if speed in values:
            return 0
        above = [speed > value for value in values]
        if turns is not None and turns(start):
            return 0  # no promise at all (a positioning ramp, a start from rest)

        def compares_otherwise(chip: ChipModel) -> bool:
            if turns is not None and turns(chip):
                return True  # no promise past a turn
            now = driver.speed_on(chip.clone())
            return any(now == value or (now > value) != side
                       for value, side in zip(values, above, strict=True))

        end_ns, end_chip, plain = end
        high = end_chip.t
        low = start
        if not compares_otherwise(end_chip):
            # the end's own tick may change the speed at once (an arrival at VSTOP or above,
            # a stop switch): alike there says nothing of the clock before it; a plain tick
            # (a look-ahead's horizon or work budget) goes on the same way
            if plain or high - start.t <= 1:
                return end_ns
            before = self._clock_before(start, end_chip)
            if not compares_otherwise(before):
                self._on_the_way_to(before, ahead)  # F9: the program wakes past it
                if before.t == high - 1:
                    return end_ns
                # stopped short (its work budget): alike up to there, the stretch being
                # monotonic; the next look starts there (the copy is kept)
                return before.ns_at(before.t + 1)
            high = before.t  # it flips before the end (or where the copy stopped): search there
        # the end itself often flips (a speed polled to 0 at arrival); where it has turned by
        # then, the turn is usually earlier (the top speed reached): no use looking there
        elif not plain and high - start.t > 2 and (turns is None or not turns(end_chip)):
            before = self._clock_before(start, end_chip)
            if compares_otherwise(before):
                high = before.t  # (stopped short of the end, and already otherwise there)
            elif before.t == high - 1:
                self._on_the_way_to(before, ahead)  # F9
                return before.ns_at(high)  # both tests are false, then true: the end flips
            else:
                low = before  # stopped short: alike up to there, the search starts there
        low = low.clone()
        while high - low.t > 1:
            middle = (low.t + high) // 2
            probe = low.clone()
            probe.run(middle, LOOKAHEAD_BUDGET)
            if probe.t < middle:  # stopped short (its work budget): judged where it stopped
                if probe.t <= low.t:
                    return low.ns_at(low.t + 1)  # no further promise than the tick after low
                middle = probe.t  # (returning its instant unjudged could be late)
            if compares_otherwise(probe):
                high = middle
            else:
                low = probe
        self._on_the_way_to(low, ahead)  # F9: the clock before the answer
        return low.ns_at(high)

    def _first_time_at_position(self, values: tuple[int, ...], ahead: Lookahead,
                                reading: Reading | None = None) -> int:
        """The first time AP 1 equals one of ``values``, or the chip's next notable instant
        if it does not before: a copy of the chip, at ``reading`` or else brought to the
        present, runs with a mark at each value's motor position (F3).  Kept while the
        look-ahead it was found for holds, for the instants it does not precede (F5)."""
        axis = self._axis
        since = axis.present_ns() if reading is None else reading.time_ns
        cached = self._crossing
        if (cached is not None and cached[0] is ahead and cached[1] == values
                and cached[2] <= since):
            return cached[3]
        if reading is None:
            axis.sync()
            start, here = axis.driver.chip, axis.driver.position
        else:
            start, here = reading.chip, reading.position
        if not start.steps_reach_motor():
            return 0  # AP 1 counts steps that do not move the motor: no marks to set
        bits = axis.driver.position_bits
        half, span = 1 << (bits - 1), 1 << bits
        motor = start.motor_position
        # the nearest motor position at which AP 1 reads each value (a look-ahead moves less
        # than half the range); a value outside AP 1's range is never read
        marks = [motor + (value - here + half) % span - half for value in values
                 if -half <= value < half]
        if motor in marks:
            return 0
        result = self._run_to_marks(start, marks, ahead)[0]
        self._crossing = (ahead, values, since, result)
        return result

    def _clock_before(self, start: ChipModel, end: ChipModel) -> ChipModel:
        """A copy of ``start`` run to the clock before ``end`` (a later copy of the same run),
        or as far as its work budget took it (``t`` short of that); kept for the same
        ``end``: every chip from ``start`` on to that end passes the same clocks, so a later
        look from no later than the copy goes on from it instead of from its own start."""
        kept = self._before_end
        if kept is not None and kept[0] is end and start.t <= kept[1].t:
            if kept[1].t == end.t - 1:
                return kept[1]
            start = kept[1]  # (stopped short last time: on from there)
        before = start.clone()
        before.run(end.t - 1, LOOKAHEAD_BUDGET)
        self._before_end = (end, before)
        return before

    def _meeting(self, start: ChipModel, steps: int, reading: Reading,
                 ahead: Lookahead) -> StretchEnd:
        """Where the motor, at ``start`` (a copy at ``reading``), first meets the motor
        position ``steps`` further (F8's end of a stretch), and a copy of the chip there;
        kept for the later reads of the same look-ahead it does not precede (F5), as a move
        polled through its look-ahead asks once per flip."""
        mark = start.motor_position + steps
        cached = self._met
        if (cached is not None and cached[0] is ahead and cached[1] == mark
                and cached[2] <= reading.time_ns and start.t <= cached[3][1].t):
            return cached[3]
        met = self._run_to_marks(start, [mark], ahead)
        self._met = (ahead, mark, reading.time_ns, met)
        return met

    def _run_to_marks(self, start: ChipModel, marks: list[int],
                      ahead: Lookahead) -> StretchEnd:
        """A copy of ``start`` run with a mark at each of the motor positions ``marks`` up to
        the look-ahead's end: the instant it stopped, at the first step that reached one or
        conservatively at anything else (its work budget), or the look-ahead's end; the copy
        there; whether it stopped at a plain tick (its budget, or the end of a look-ahead
        that did)."""
        twin = start.clone()
        board = self._axis.board
        saved = board.firmware_marks
        board.firmware_marks = saved + marks
        until = twin.ticks_at(ahead.time_ns)
        try:  # it stops early at a mark (or, conservatively, at anything else)
            stop = twin.run(until, LOOKAHEAD_BUDGET)
        finally:
            board.firmware_marks = saved
        return StretchEnd(twin.ns_at(twin.t) if twin.t < until else ahead.time_ns, twin,
                          stop is None)
