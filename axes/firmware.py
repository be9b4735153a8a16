"""The TMCL firmware layer of one axis, whatever motion-controller chip is under it.

:class:`AxisFirmware` is what the TMCL commands and axis parameters mean for an axis (SAP/GAP,
ROR/MVP/MST, RFS, stall and deviation stops, the current, the events a host or a program
sees), over a *driver* (:class:`axes.core.ChipDriver`): the chip-specific half of the
firmware, which speaks the chip's SPI datagrams (``axes/chips/tmc42x/tmc4210_firmware.py``).
What it relies on lives in files of its own: the look-ahead and loop skipping's forecasts
(axes/forecast.py), the reference search (axes/reference_search.py), the encoder
(axes/encoder.py), stallGuard2 and coolStep (axes/stallguard.py), the periodic pass of the
firmware's main loop (axes/tasks.py: the current, coolStep's switch, the driver's readings,
the stall check, on the firmware's own clock), and the world and faults around it on its
:class:`axes.board.AxisBoard` (axes/rig.py).  Time: the axis keeps the
simulated time it was last advanced to; :meth:`advance_to` adopts the look-ahead's copy of
the chip at each event, so each stretch of motion is computed once.  Every modelling choice
is explained in docs/motion.md.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Mapping

from axes import stallguard
from axes.board import AxisBoard
from axes.core import ChipDriver, ChipModel, MotorDriverLink, StaleLookahead, Stop
from axes.encoder import Encoder
from axes.forecast import AxisForecast, Lookahead
from axes.interface import FOREVER, AxisEvent, AxisEventKind, AxisSample, AxisStatus
from axes.reference_search import ReferenceSearcher
from axes.rig import RiggedAxis
from axes.tasks import FirmwareTasks
from axes.world import AxisWorld
from tmcl_spec.modules import FirmwareClock
from tmcl_spec.numbers import to_signed
from tmcl_spec.parameters import AP, Motion, ParamSpec

ERROR_STALL = 1
ERROR_DEVIATION = 2

#: Builds the chip-specific half of the firmware for an axis: (parameters, board) -> driver.
DriverFactory = Callable[[Mapping[int, int], AxisBoard], ChipDriver]

#: What the firmware does for a parameter a module's table does not have: the value it acts
#: as if it had (a feature a module lacks is off).  The TMC429 modules, for example, have no
#: unit mode (AP 255): their speeds are the chip's own units, as with AP 255 = 0.
FIRMWARE_DEFAULTS: dict[int, int] = {
    AP.UNIT_MODE: 0, AP.VSTOP: 0, AP.SOFT_STOP: 0, AP.SWAP_SWITCHES: 0, AP.LEFT_POLARITY: 0,
    AP.RIGHT_POLARITY: 0, AP.RELATIVE_POSITIONING_OPTION: 0, AP.COOLSTEP_THRESHOLD_SPEED: 0,
    AP.SMARTENERGY_THRESHOLD_SPEED: 0, AP.FULLSTEPS: 200, AP.ENCODER_RESOLUTION: 512,
    AP.MAX_DEVIATION: 0, AP.LAST_REFERENCE: 0, AP.SWITCH_DISTANCE: 0, AP.STOP_ON_STALL: 0,
    AP.STALLGUARD_FILTER: 0, AP.STALLGUARD_THRESHOLD: 0, AP.SMARTENERGY_CURRENT_MINIMUM: 0,
    AP.SMARTENERGY_CURRENT_DOWN_STEP: 0, AP.SMARTENERGY_HYSTERESIS: 0,
    AP.SMARTENERGY_CURRENT_UP_STEP: 0, AP.SMARTENERGY_HYSTERESIS_START: 0,
    AP.RIGHT_DISABLE: 0, AP.LEFT_DISABLE: 0, AP.RAMP_WAIT: 0,
}
#: The TMC4361 modules' limit switch settings (bit 0 enabled, bit 1 inverted) -> the
#: disable and polarity parameters the firmware acts on.
_LIMIT_SWITCH_BITS = {AP.RIGHT_LIMIT_SWITCH: (AP.RIGHT_DISABLE, AP.RIGHT_POLARITY),
                      AP.LEFT_LIMIT_SWITCH: (AP.LEFT_DISABLE, AP.LEFT_POLARITY)}


#: A named tuple made from a plain one without its generated ``__new__`` (a recorder makes
#: one per axis and sample: half the cost).
_new_sample = tuple.__new__
_NO_EVENTS: list[AxisEvent] = []  # advance_to's answer when nothing happened (never appended to)

#: Parameters every TMCL module's table has (the others may be missing and count as off,
#: FIRMWARE_DEFAULTS): another firmware's table, e.g. the evaluation board's, is refused.
_REQUIRED_PARAMETERS = frozenset({AP.POWER_DOWN_DELAY, AP.MAX_CURRENT, AP.STANDBY_CURRENT,
                                  AP.RFS_MODE, AP.MICROSTEPS})
#: Parameters that shape the ramp or its limits: a change re-plans the motion in flight
#: (the driver), among them the TMC429 modules' chip settings (minimum speed, divisors).
_RAMP_PARAMETERS = frozenset({AP.MAX_SPEED, AP.MAX_ACCELERATION, AP.A1, AP.V1,
                              AP.MAX_DECELERATION, AP.D1, AP.VSTART, AP.VSTOP, AP.RAMP_WAIT,
                              AP.UNIT_MODE, AP.MINIMUM_SPEED, AP.PULSE_DIVISOR,
                              AP.RAMP_DIVISOR, AP.RAMP_TYPE, AP.BOW1, AP.BOW2, AP.BOW3, AP.BOW4,
                              AP.STOP_DECELERATION})
#: Parameters whose value depends on the motion (read from the chip at the present time).
_LIVE_PARAMETERS = frozenset({AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.ACTUAL_SPEED,
                              AP.POSITION_REACHED, AP.LEFT_SWITCH, AP.RIGHT_SWITCH,
                              AP.HOME_SWITCH, AP.LOAD, AP.ERROR_FLAGS, AP.ENCODER_POSITION,
                              AP.SMARTENERGY_ACTUAL_CURRENT, AP.MEASURED_SPEED,
                              AP.DRIVER_ERROR_FLAGS, AP.ABSOLUTE_ENCODER})
#: Parameters whose write is an action even with the value they have (a move, a position or
#: encoder set, a rotation, a ramp-mode stop): the others change nothing when written unchanged.
_ACTION_PARAMETERS = frozenset({AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.TARGET_SPEED,
                                AP.ENCODER_POSITION, AP.RAMP_MODE})
#: Parameters whose writes re-plan the stop switches.
_STOP_PARAMETERS = frozenset({AP.LEFT_DISABLE, AP.RIGHT_DISABLE, AP.SOFT_STOP, AP.SOFT_STOP_FLAG,
                              AP.REFERENCE_SWITCH_TOLERANCE, AP.VIRTUAL_STOP_LEFT,
                              AP.VIRTUAL_STOP_RIGHT, AP.VIRTUAL_STOP_ENABLE,
                              AP.VIRTUAL_STOP_MODE})


class AxisFirmware(RiggedAxis):
    """One TMCL axis: axis parameters in, datagrams to its chip (through the driver) out.

    A core's axis class subclasses it with the :class:`axes.interface.Axis` constructor and
    passes the factory of its driver."""

    def __init__(self, index: int, parameters: Mapping[int, ParamSpec], world: AxisWorld | None,
                 make_driver: DriverFactory) -> None:
        self.index = index
        #: The module's parameter numbers the firmware knows by another key (the TMCM-1111's
        #: numbering, ParamSpec.firmware_number); get/set_parameter translate them.
        self._keys: dict[int, int] = {n: spec.firmware_number for n, spec in parameters.items()
                                      if spec.firmware_number is not None}
        known = {self._keys.get(n, n) for n in parameters}
        missing = sorted(_REQUIRED_PARAMETERS - known)
        if missing:
            raise ValueError(f"a TMCL firmware axis needs a TMCL module's axis parameters "
                             f"(missing {missing}); is the chip core right for the module type?")
        self.board = AxisBoard(world)
        self._params = {**FIRMWARE_DEFAULTS,
                        **{self._keys.get(n, n): spec.default for n, spec in parameters.items()}}
        for bits in _LIMIT_SWITCH_BITS.keys() & known:
            self._derive_limit_switch(bits)
        self._input_stage_from_parameters()
        self.driver = make_driver(self._params, self.board)
        #: The modelled motor driver IC the chip driver reaches (the TMC262 of the TMC429
        #: modules): stallGuard2, coolStep and the current act on it.  Without one, they come
        #: from axes/stallguard.py (docs/motion.md, "stallGuard2 and coolStep").
        self.motor_driver: MotorDriverLink | None = self.driver.motor_driver
        #: Chip-specific parameters the driver reads from its chip (e.g. AP 135, AP 138).
        self._chip_live: frozenset[int] = frozenset(self.driver.live_parameters & known)
        #: Parameters whose writes the driver checks first (values its chip cannot run).
        self._checked: frozenset[int] = frozenset(self.driver.checked_parameters)
        motions = {self._keys.get(n, n): spec.motion for n, spec in parameters.items()
                   if spec.motion is not None}
        self._check_motions(motions)
        #: The look-ahead, and the forecasts loop skipping asks for (axes/forecast.py).
        self.forecast = AxisForecast(self, motions)
        # AP 210 is an encoder prescaler where the table has no AP 202 (motor full steps);
        # AP 212 counts microsteps with a prescaler (the TMC429 modules) and on the TMC4361
        # modules (whose own numbering has a DSTOP; the chip compares ENC_POS_DEV, in
        # microsteps); else encoder counts (the TMCM-6212).
        prescaler = AP.FULLSTEPS not in known
        self.encoder = Encoder(self.board, self._params, prescaler=prescaler,
                               deviation_in_microsteps=prescaler or AP.STOP_DECELERATION in known)
        self._now_ns = 0
        self._pending: list[AxisEvent] = []
        self._target = 0  # AP 0, 32 bit
        self._positioning = False
        self._awaiting_arrival = False
        self._velocity_command = 0
        #: The reference search (axes/reference_search.py).
        self.homing = ReferenceSearcher(self, self._params)
        self._errors = 0
        self._motion_origin = 0  # motor position where the motion last started
        #: The firmware's periodic pass: current, coolStep, the driver's readings, stall.
        self.tasks = FirmwareTasks(self, self._params)
        self._travel_direction = 1  # of the last motion (the filtered stallGuard2 reading)
        self.driver.power_up()
        self._levels = self.driver.levels()  # logical left, right, home

    @property
    def chip(self) -> ChipModel:
        """The emulated chip (tests and the lookahead look at it; the firmware uses the driver)."""
        return self.driver.chip

    @property
    def clock_hz(self) -> int:
        return self.driver.chip.clock_hz

    @property
    def _position(self) -> int:
        """AP 1, as of the last read from the chip."""
        return self.driver.position

    def _check_motions(self, motions: Mapping[int, Motion]) -> None:
        """The table's motion column and what the firmware does agree (F2 in axes/forecast.py):
        a row the firmware reads from the chip is not a setting, and a row it keeps changes
        only by a command or at one of its events.  Refused otherwise, at construction."""
        for number, motion in motions.items():
            live = number in _LIVE_PARAMETERS or number in self._chip_live
            # a row the firmware keeps changes by a command, or at one of its events (AP 196)
            kept = motion is Motion.SETTING or motion is Motion.EVENTS
            if motion is Motion.SETTING if live else not kept:
                raise ValueError(f"axis parameter {number}: the table says it {motion.value}, "
                                 f"but the firmware {'reads it from the chip' if live else 'keeps it'}")

    # == time ==================================================================================

    def _invalidate(self) -> None:
        self.forecast.known = False  # AxisForecast.invalidate, inlined: every command runs it

    def _lookahead(self) -> Lookahead | None:
        forecast = self.forecast  # AxisForecast.lookahead's cache, inlined: a hot path
        return forecast.cached if forecast.known else forecast.lookahead()

    # the forecast's view of the axis (axes.forecast.ForecastedAxis)

    def present_ns(self) -> int:
        return self._now_ns

    def target_position(self) -> int:
        return self._target

    def error_flags(self) -> int:
        return self._errors

    def start_firmware_clock(self, clock: FirmwareClock, origin_ns: int, axes: int) -> None:
        self.tasks.start(clock, origin_ns, self.index, axes)

    def next_event_ns(self) -> int | None:
        now = self._now_ns
        if self._pending:
            return now
        ahead = self._lookahead()
        due = None if ahead is None else ahead.time_ns if ahead.time_ns > now else now
        timer = self.tasks.due()  # T1 (axes/tasks.py): only what a host sees
        if timer is not None:
            if timer < now:
                timer = now
            if due is None or timer < due:
                due = timer
        return due

    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        tasks = self.tasks
        while True:
            ahead = self._lookahead()
            timer = tasks.due()
            if ahead is not None and (chip_at := ahead.time_ns) <= t_ns and (
                    timer is None or chip_at <= timer):
                lazy = tasks.lazy_pass(chip_at)
                if lazy is not None:  # T2: the pass runs before the chip goes past it
                    self._now_ns = max(self._now_ns, lazy)
                    self._run_pass(lazy)
                    continue
                try:
                    self.driver.chip = self.driver.chip.adopt(ahead.chip)
                except StaleLookahead:
                    self._invalidate()  # the chip changed under the copy: look again
                    continue
                self._invalidate()
                self._now_ns = max(self._now_ns, chip_at)
                self._react(ahead.stop)
            elif timer is not None and timer <= t_ns:
                self._now_ns = max(self._now_ns, timer)
                self.sync()
                tasks.run_due(self._now_ns)
            else:
                break
        if t_ns > self._now_ns:
            self._now_ns = t_ns
        if not self._pending:
            return _NO_EVENTS
        events, self._pending = self._pending, []
        return events

    def sync(self) -> None:
        """Bring the chip up to ``_now_ns`` and read the position (before any command); the
        firmware's passes on the way run at their instants (T2 in axes/tasks.py)."""
        tasks = self.tasks
        if tasks.next_pass_ns < self._now_ns:  # a pass lies behind (one comparison: GAP 1)
            while (at := tasks.lazy_pass(self._now_ns)) is not None:
                self._run_pass(at)
        self._run_chip(self._now_ns)
        self.driver.read_position()

    def _run_chip(self, t_ns: int) -> None:
        chip = self.driver.chip
        until = chip.ticks_at(t_ns)
        if chip.t < until:
            copy = self.forecast.copy_on_the_way(chip.t, until)
            if copy is not None:  # F9 (axes/forecast.py): the forecast ran this way already
                # (stale: another motor of its chip wrote to it since; then run the way)
                with contextlib.suppress(StaleLookahead):
                    chip = self.driver.chip = chip.adopt(copy)
        while chip.t < until:
            stop = chip.run(until)
            if stop is None:
                break
            self._react(stop)  # only reached if the lookahead was skipped
            chip = self.driver.chip

    def _run_pass(self, t_ns: int) -> None:
        """The firmware's pass at ``t_ns`` (axes/tasks.py), the chip brought there."""
        self._run_chip(t_ns)
        self.driver.read_position()
        self.tasks.run_pass(t_ns)

    def emit(self, kind: AxisEventKind, active: bool | None = None) -> None:
        self._pending.append(AxisEvent(self._now_ns, self.index, kind, active))

    def emit_at(self, time_ns: int, kind: AxisEventKind, active: bool | None = None) -> None:
        self._pending.append(AxisEvent(time_ns, self.index, kind, active))

    # == reacting to the chip ==================================================================

    def _react(self, stop: Stop | None) -> None:
        """Whatever the firmware does at a notable instant (it reacts within the same tick)."""
        self.driver.read_position()
        self.tasks.feed()  # a load edge: coolStep's measurements so far read the load before it
        self._check_levels()
        moving = self.driver.moving()
        switch_stopped = self.driver.take_switch_stop()
        if self._positioning and self._awaiting_arrival:
            self.driver.continue_move(self._target)
        if (stop in (Stop.ARRIVED, Stop.STOPPED) or switch_stopped) and not moving:
            self._came_to_rest()
            if not self._positioning and not self.homing.active:
                self._target = self._position  # MVP REL after a rotation starts from here
            self._conclude_move()  # arrived and standing: "target reached"
        self.homing.step()
        self.tasks.check_stall()
        self._check_deviation()
        self.update_marks()

    def _came_to_rest(self) -> None:
        self.tasks.came_to_rest(self._now_ns)

    def _check_levels(self) -> None:
        levels = self.driver.levels()
        for kind, old, new in zip(
                (AxisEventKind.LEFT_SWITCH, AxisEventKind.RIGHT_SWITCH, AxisEventKind.HOME_SWITCH),
                self._levels, levels, strict=True):
            if old != new:
                self.emit(kind, new)
        self._levels = levels

    def _motion_started(self) -> None:
        self._motion_origin = self.chip.motor_position
        self.tasks.motion_started(self._now_ns)  # the current follows at the next pass
        self._errors = 0

    # == motion ================================================================================

    def conclude_move(self) -> None:
        self.sync()
        self._conclude_move()

    def _conclude_move(self) -> None:
        """A command ends the move in flight.  If it had reached its target (AP 8 reads 1: a
        TMC4361A brakes inside the target step for a few hundred microseconds after XACTUAL
        = XTARGET, a TMC4210 for a few clocks), its "target reached" is announced now, as
        the firmware's poll of the chip's target flag would see it, not lost with the move."""
        if self._positioning and self._awaiting_arrival and self._position == self._target:
            self._awaiting_arrival = False
            if not self.homing.active:
                self.emit(AxisEventKind.TARGET_REACHED)

    def start_velocity(self, speed: int) -> None:
        self._conclude_move()
        self.driver.start_velocity(speed)
        self._positioning = False
        self._awaiting_arrival = False
        self._motion_started()

    def start_positioning(self, target: int, top_speed: int) -> None:
        self._conclude_move()
        self._target = target
        self.driver.start_positioning(target, top_speed)
        self._positioning = True
        self._awaiting_arrival = True
        self._motion_started()
        if self._position == self._target and not self.driver.moving():
            self._awaiting_arrival = False
            self._came_to_rest()
            if not self.homing.active:
                self.emit(AxisEventKind.TARGET_REACHED)

    def _rotating_at(self, velocity: int) -> bool:
        """Already doing what ROR ``velocity`` asks, with nothing for it to reset (the
        firmware's own records: a raw register write is noticed at the next real command)."""
        return (self._velocity_command == velocity and self._params[AP.TARGET_SPEED] == velocity
                and not self._positioning and not self.homing.active and self._errors == 0
                and self.tasks.rest_since is None)

    def rotate(self, velocity: int) -> bool:
        if self._rotating_at(velocity):
            return False
        self._command()
        self.homing.abort()
        self._velocity_command = self._params[AP.TARGET_SPEED] = velocity
        self.start_velocity(velocity)
        self._after_command()
        return True

    def stop(self) -> bool:
        if (self._velocity_command == 0 and self._params[AP.TARGET_SPEED] == 0
                and not self._positioning and not self.homing.active and self._errors == 0):
            return False  # already stopping (or stopped) in velocity mode: nothing to change
        self._command()
        self.homing.abort()
        self._ramp_stop()
        self._after_command()
        return True

    def _ramp_stop(self) -> None:
        """MST's stop (and RFS STOP's): velocity mode, target speed 0, errors cleared."""
        self._velocity_command = self._params[AP.TARGET_SPEED] = 0
        self._conclude_move()
        self.driver.ramp_stop()
        self._positioning = False
        self._awaiting_arrival = False
        self._errors = 0

    def emergency_stop(self) -> None:
        self._command()
        self.homing.abort()
        self.hard_stop()
        self._after_command()

    def hard_stop(self) -> None:
        """Stop within one chip tick, at once (switch, stall, deviation, heartbeat)."""
        self._conclude_move()
        self.driver.hard_stop()
        self._invalidate()  # a look-ahead made before (a timer's stall check) would move on
        self._positioning = False
        self._awaiting_arrival = False
        self._velocity_command = 0
        if self.tasks.rest_since is None:
            self._came_to_rest()
        self.update_marks()

    def move_to(self, target: int) -> None:
        self._command()
        self.homing.abort()
        self.start_positioning(to_signed(target, self.driver.position_bits),
                               self._params[AP.MAX_SPEED])
        self._after_command()

    def _command(self) -> None:
        """Every host command first brings the chip to the present."""
        self.sync()
        tasks = self.tasks
        tasks.feed()  # coolStep's measurements so far, before a setting may change
        tasks.touch()  # the next pass may decide otherwise
        self._invalidate()

    def _after_command(self) -> None:
        self.tasks.touch()  # a setting the current's pass depends on (AP 214) may be new
        self.tasks.check_stall()
        self.update_marks()
        self._invalidate()

    # == reference search (axes/reference_search.py) =============================================

    def reference_search(self, action: int) -> int:
        homing = self.homing
        if action == 2:
            self.sync()
            return homing.state
        self._command()
        if action == 1:
            if homing.active:  # stop() would find nothing to do once the search is gone
                homing.abort()
                self._ramp_stop()
                self._after_command()
            return 0
        search = homing.plan(self._params[AP.RFS_MODE])
        homing.abort()
        self._errors = 0
        homing.begin(search)
        self._after_command()
        return 0

    # the search's view of the axis (axes.reference_search.SearchingAxis)

    def switch_levels(self) -> tuple[bool, bool, bool]:
        return self._levels

    def actual_position(self) -> int:
        return self._position

    def arrived(self) -> bool:
        return not self._awaiting_arrival and self._position == self._target

    def configure_stops(self, searching: bool) -> None:
        self.driver.configure_stops(searching=searching)

    def zero_counters(self) -> None:
        self._set_position(0)
        self.encoder.set(0, self.chip.motor_position)

    # == stallGuard, encoder, current ==========================================================

    def mechanical(self) -> int:
        return self.board.mechanical(self.chip.motor_position)

    def _load(self) -> int:
        """AP 206: the stallGuard2 reading, after threshold (AP 174) and filter (AP 173): what
        the last pass read from a modelled driver (axes/tasks.py), else the reading now."""
        if self.motor_driver is not None:
            self.tasks.settle()
            return self.motor_driver.load()
        return self.generic_load()

    def generic_load(self) -> int:
        return stallguard.load_reading(self._params, self.board.world.load_at, self.mechanical(),
                                       self.driver.heading() or self._travel_direction)

    def actual_speed(self) -> int:
        return self.driver.actual_speed()

    def stall_stop(self) -> None:
        """AP 181: a stall stops the motor at once (axes/tasks.py decides when)."""
        self.homing.abort()
        self.hard_stop()
        self._errors |= ERROR_STALL
        self.emit(AxisEventKind.STALL)

    def full_steps_moved(self) -> int:
        return abs(self.chip.motor_position - self._motion_origin)

    def _check_deviation(self) -> None:
        limit = self._params[AP.MAX_DEVIATION]
        if limit and self.tasks.rest_since is None and self.encoder.deviation(
                self._position, self.chip.motor_position) > limit:
            self.homing.abort()
            self.hard_stop()
            self._errors |= ERROR_DEVIATION
            self.emit(AxisEventKind.DEVIATION)

    def update_marks(self) -> None:
        marks = []
        direction = self.driver.heading()
        if direction:
            self._travel_direction = direction
            mark = self.encoder.deviation_mark(self._position, self.chip.motor_position,
                                               direction)
            if mark is not None:
                marks.append(mark)
        if self._positioning and self._awaiting_arrival:
            mark = self.driver.refill_mark(self._target)
            if mark is not None:
                marks.append(mark)
        self.board.firmware_marks = marks

    @property
    def current(self) -> int:
        """The motor current now (0..255): AP 6 while moving (AP 183 below AP 182, lowered by
        coolStep at light load), AP 7 in standby; switched by the firmware's pass."""
        return self.tasks.current()

    def current_changed(self) -> None:
        """Run, slow-run or standby current switched, or AP 6/7/183 changed: a modelled
        driver follows."""
        if self.motor_driver is not None:
            self.motor_driver.set_current(self.tasks.current_setting())

    # == parameters ============================================================================

    def _set_position(self, value: int) -> None:
        """AP 1 write: the position counts from ``value`` now; a move in flight stops."""
        self._conclude_move()
        if self.driver.set_position(value):
            self._positioning = False
        self._target = value
        self._awaiting_arrival = False

    def get_parameter(self, number: int) -> int:
        if self._keys:
            number = self._keys.get(number, number)
        if number == AP.ACTUAL_POSITION:  # first: what a program polls most
            self.sync()
            return self.driver.position
        if number not in _LIVE_PARAMETERS:
            if number in self._chip_live:
                self.sync()
                return self.driver.read_parameter(number)
            return self._params[number]  # configuration: no need to bring the chip up to date
        if number == AP.POSITION_REACHED and self.forecast.short_of_target():
            return 0
        self.sync()
        if number == AP.TARGET_POSITION:
            return self._target
        if number == AP.ACTUAL_SPEED:
            return self.actual_speed()
        if number == AP.POSITION_REACHED:
            return int(self._position == self._target)
        if number in (AP.LEFT_SWITCH, AP.RIGHT_SWITCH, AP.HOME_SWITCH):
            left, right, home = self.driver.levels()
            return int({AP.LEFT_SWITCH: left, AP.RIGHT_SWITCH: right, AP.HOME_SWITCH: home}[number])
        if number == AP.LOAD:
            return self._load()
        if number == AP.ERROR_FLAGS:
            flags, self._errors = self._errors, 0
            return flags
        if number == AP.ENCODER_POSITION:
            return self.encoder.position(self.chip.motor_position)
        if number == AP.SMARTENERGY_ACTUAL_CURRENT:
            return self.tasks.actual_scale()
        if number == AP.MEASURED_SPEED:  # the driver's step-rate measurement: a magnitude
            return abs(self.actual_speed())
        if number == AP.DRIVER_ERROR_FLAGS and self.motor_driver is not None:
            self.tasks.settle()
            return self.motor_driver.flags()
        if number == AP.ABSOLUTE_ENCODER:
            return self.encoder.absolute(self.chip.motor_position)
        return self._params[number]

    # == what stays as it is (loop skipping, axes/forecast.py) ===================================

    def steady_until(self, number: int) -> int:
        if self._keys:
            number = self._keys.get(number, number)
        return self.forecast.steady_until(number)

    def first_time_at(self, number: int, values: tuple[int, ...], read_ns: int) -> int:
        if self._keys:
            number = self._keys.get(number, number)
        return self.forecast.first_time_at(number, values, read_ns)

    def in_velocity_mode(self) -> bool:
        """Velocity mode (ROR, ROL, MST) with no reference search: the speed only ever moves
        towards the speed asked for, monotonically, until the next notable instant."""
        return not self._positioning and not self.homing.active

    def set_parameter(self, number: int, value: int) -> bool:
        if self._keys:
            number = self._keys.get(number, number)
        if number in self._checked:
            self.driver.check_write(number, value)  # ValueError: the module's status 4 (or 6)
        if number == AP.TARGET_SPEED and self._rotating_at(value):
            return False
        if number not in _ACTION_PARAMETERS and self._params.get(number) == value:
            return False  # a setting written with the value it has: as on the chip, no change
        self._command()
        if number == AP.TARGET_POSITION:
            self.homing.abort()
            self.start_positioning(to_signed(value, self.driver.position_bits),
                                   self._params[AP.MAX_SPEED])
        elif number == AP.ACTUAL_POSITION:
            self._set_position(to_signed(value, self.driver.position_bits))
        elif number == AP.TARGET_SPEED:
            self.homing.abort()
            self._velocity_command = value
            self.start_velocity(value)
            self._params[number] = value
        elif number == AP.ENCODER_POSITION:
            self.encoder.set(value, self.chip.motor_position)
        else:
            self._params[number] = value
            self._parameter_side_effects(number)
        self._after_command()
        return True

    def _derive_limit_switch(self, number: int) -> None:
        """A TMC4361 module's limit switch setting (bit 0 enabled, bit 1 inverted) as the
        disable and polarity parameters the firmware acts on."""
        disable, polarity = _LIMIT_SWITCH_BITS[number]
        bits = self._params[number]
        self._params[disable] = int(not bits & 1)
        self._params[polarity] = bits >> 1 & 1

    def _parameter_side_effects(self, number: int) -> None:
        if number in _LIMIT_SWITCH_BITS:
            self._derive_limit_switch(number)
            self.driver.configure_stops(searching=self.homing.active)
            number = _LIMIT_SWITCH_BITS[number][1]  # and the polarity, below
        if self.motor_driver is not None and number in self.motor_driver.parameters:
            self.motor_driver.configure(number)
        follow = _SIDE_EFFECTS.get(number)
        if follow is not None:
            follow(self)

    def _ramp_written(self) -> None:
        if not self.homing.active:
            self.driver.limits_changed(self._positioning, self._velocity_command)

    def _stops_written(self) -> None:
        self.driver.configure_stops(searching=self.homing.active)

    def _input_stage_written(self) -> None:
        self._input_stage_from_parameters()
        self._pins_changed()

    def _microsteps_written(self) -> None:
        self._rebase_encoder()
        self.board.rescale(self.chip.motor_position, self._params[AP.MICROSTEPS])
        self._rebase_encoder()

    def _current_written(self) -> None:
        self.current_changed()
        if self.tasks.standby:
            self.emit(AxisEventKind.CURRENT_CHANGED, False)

    def _semin_written(self) -> None:
        """SAP 172 writes the driver's SEMIN at once, SAP 182 = 0 zeroes it (TMCL-LITE-1110
        Commands.c lines 661-663, 698-702); the next pass switches by the speed."""
        self.tasks.switch_coolstep(self._params[AP.SMARTENERGY_HYSTERESIS_START] > 0)

    def _coolstep_speed_written(self) -> None:
        if self._params[AP.SMARTENERGY_THRESHOLD_SPEED] == 0:
            self.tasks.switch_coolstep(False)

    def _input_stage_from_parameters(self) -> None:
        """The module's input stage: switches swapped and inverted as the parameters say."""
        self.board.swap = bool(self._params[AP.SWAP_SWITCHES])
        self.board.invert_left = bool(self._params[AP.LEFT_POLARITY])
        self.board.invert_right = bool(self._params[AP.RIGHT_POLARITY])

    def _ramp_mode_written(self) -> None:
        """AP 138 (TMC429 modules): 2 (velocity) stops a move on a ramp, as MST does; 0/1
        choose ramp or soft positioning, at once for a move in flight, else for the next."""
        if self._params[AP.RAMP_MODE] == 2:
            if self._positioning and not self.homing.active:
                self._conclude_move()
                self.driver.ramp_stop()
                self._positioning = False
                self._awaiting_arrival = False
            return
        if self._positioning:
            self.driver.set_positioning_mode()

    def _pins_changed(self) -> None:
        self.chip.set_pins(*self.board.pins(self.chip.motor_position))
        self._check_levels()
        self.homing.step()

    # == the rig's hooks (axes/rig.py: the world and the faults around the axis) ==================

    def _motor_position(self) -> int:
        return self.chip.motor_position

    def _rig_begin(self) -> None:
        self._command()
        self.tasks.settle()  # a pass left for a read saw the world as it was

    def _rig_end(self) -> None:
        self._after_command()  # a new load or stuck mechanics may stall the motor now

    def _encoder_placed(self, mechanical: int) -> None:
        self.encoder.placed(mechanical)

    def _rebase_encoder(self) -> None:
        self.encoder.rebase(self.chip.motor_position)

    @property
    def builtin_encoder_counts(self) -> int:
        """Counts per turn of the module's own encoder (set by the module from its type)."""
        return self.encoder.builtin_counts

    @builtin_encoder_counts.setter
    def builtin_encoder_counts(self, counts: int) -> None:
        self.encoder.builtin_counts = counts

    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one raw datagram to the chip (None reads).

        Returns the chip's whole 32-bit answer as a signed 32-bit number: the status byte in
        bits 31..24 and the (zero-extended) register data in bits 23..0.  Writes bypass the
        firmware, as on the real module: the firmware only notices through what it reads.
        """
        self._command()
        answer = self.driver.register_access(address, value)
        self._after_command()
        return answer

    def sample(self) -> AxisSample:
        """:meth:`status`'s fields a recorder keeps, without the load, the encoder and the
        mode (three quarters of status's cost, paid at every sample of every axis)."""
        self.sync()
        left, right, home = self._levels
        position, target = self._position, self._target
        return _new_sample(AxisSample, (position, self.actual_speed(), self.current, target,
                                        position == target, left, right, home))

    def samples_at(self, first_ns: int, step_ns: int, count: int) -> list[AxisSample]:
        """:meth:`sample` at the first of ``count`` instants ``step_ns`` apart from
        ``first_ns`` on (none before the present), as many as lie before anything else on
        the way: no event or timer of the axis is due up to them (:meth:`advance_to` would
        only move the present), and the firmware's passes before them are left out (T2).
        Each is read in closed form where the driver has one (:meth:`ChipDriver.readings_at`:
        a standing velocity, a linear slew), else by :meth:`sample` at its instant (braking
        along a curve, say), without the module's and the recorder's round for each.  The
        axis ends at the last one as advance_to leaves it (the chip behind, brought there by
        the next reading: the law's state at an instant is the same however the run to it is
        cut) and with its passes and the driver's last reading where sampling each in turn
        leaves them.  A prefix, perhaps empty: the caller samples the rest the plain way."""
        tasks = self.tasks
        if self._pending or tasks.stall_watch:  # a stall check's instant moves with the present
            return []
        ahead = self._lookahead()
        horizon = FOREVER if ahead is None else ahead.time_ns
        timer = tasks.due()
        if timer is not None and timer < horizon:
            horizon = timer
        last = min(horizon - 1, tasks.left_out_until(), first_ns + (count - 1) * step_ns)
        if last < first_ns:
            return []
        left, right, home = self._levels
        target = self._target
        samples = []
        instant = first_ns
        while True:
            ticks_at = self.driver.chip.ticks_at
            positions, speeds = self.driver.readings_at(  # lazily: it may stop at the first
                map(ticks_at, range(instant, last + 1, step_ns)))
            for position, speed in zip(positions, speeds, strict=True):
                if tasks.next_pass_ns < instant:
                    tasks.lazy_pass(instant)  # leaves them out (left_out_until)
                samples.append(_new_sample(AxisSample, (position, speed, self.current, target,
                                                        position == target, left, right, home)))
                instant += step_ns
            if instant > last:
                break
            # no closed form there (braking along the curve, say): the sample the plain way,
            # the axis brought to its instant (nothing is due before the horizon: advance_to
            # would only move the present), and on with the closed form from there
            self._now_ns = instant
            samples.append(self.sample())
            instant += step_ns
        if samples and instant - step_ns > self._now_ns:
            self._now_ns = instant - step_ns
        return samples

    def resting(self) -> bool:
        """The chip rests (the look-ahead finds no motion, F2) with nothing pending, and the
        firmware's passes are all left out (T2; not while coolStep winds the current back
        after a stop, pass by pass): what :meth:`sample` reads changes only at an event (the
        current switching, T1) or by a command or a world change."""
        return (not self._pending and self._lookahead() is None
                and self.tasks.left_out_until() == FOREVER)

    def status(self) -> AxisStatus:
        """A snapshot for telemetry (MQTT bridge, tests); clears nothing."""
        self.sync()
        left, right, home = self._levels
        return AxisStatus(
            position=self._position, target=self._target, velocity=self.actual_speed(),
            mode=self.driver.mode_name(),
            position_reached=self._position == self._target,
            home_switch=home, left_switch=left, right_switch=right, load=self._load(),
            error_flags=self._errors, current=self.current, standby=self.tasks.standby,
            encoder_position=self.encoder.position(self.chip.motor_position),
            reference_search=self.homing.state,
            mechanical_position=self.mechanical(),
        )


#: What the firmware does after a parameter is written, besides storing it (a motor driver's
#: own parameters are configured first, AxisFirmware._parameter_side_effects).
_SIDE_EFFECTS: dict[int, Callable[[AxisFirmware], None]] = {
    **dict.fromkeys(_RAMP_PARAMETERS, AxisFirmware._ramp_written),
    **dict.fromkeys(_STOP_PARAMETERS, AxisFirmware._stops_written),
    AP.RAMP_MODE: AxisFirmware._ramp_mode_written,
    **dict.fromkeys((AP.SWAP_SWITCHES, AP.LEFT_POLARITY, AP.RIGHT_POLARITY),
                    AxisFirmware._input_stage_written),
    AP.MICROSTEPS: AxisFirmware._microsteps_written,
    **dict.fromkeys((AP.MAX_CURRENT, AP.STANDBY_CURRENT, AP.SMARTENERGY_SLOW_RUN_CURRENT),
                    AxisFirmware._current_written),
    AP.SMARTENERGY_HYSTERESIS_START: AxisFirmware._semin_written,
    AP.SMARTENERGY_THRESHOLD_SPEED: AxisFirmware._coolstep_speed_written,
}
