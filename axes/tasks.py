"""The firmware's own clock: the periodic pass its main loop makes over the axes.

Besides serving commands, Trinamic's TMCL firmware runs ``SystemControl`` from its main loop
(TMCL-LITE-1110 ``SysControl.c`` lines 45-139, the stepRocker's firmware; TMCL-LITE-1111
lines 191-293): once more than 10 ticks of its 1 ms system timer went by since the last pass
(line 57: every 11 ms), it serves one axis, the next in turn (lines 133-135), and for it

* switches the motor current: AP 7 once the motor stood still longer than AP 214 x 10 ms
  since the last pass that saw it move, else AP 183 below the AP 182 speed and AP 6 above
  (lines 61-81);
* switches coolStep on at or above AP 182 and off below it (lines 83-101);
* reads the motor driver's stallGuard2 value, coolStep current and flags, which GAP 206, 180
  and 208 then answer (line 104; Commands.c lines 829-834, 923-924);
* stops a motor faster than AP 181 whose driver signals a stall (lines 106-114).

What a module's firmware does of this is its profile's :class:`tmcl_spec.modules.FirmwareClock`
(the TMCM-1111's TMC4361 switches the current itself; the TMCM-6212 samples stallGuard every
millisecond).  The clock starts at power-up (``start``): the system timer and the pass's
``Delay`` are 0 then, so axis i of n has its passes at ``origin + 11 ms x (k n + i + 1)``;
the millisecond samples are at ``origin + k ms``.  Nothing a host or a program does moves
them.  The evidence, and where the sources were silent, is in docs/motion.md ("The
firmware's own clock").

Loop skipping (interpreter/skipping.py) stays exact because every instant here is known in
advance and no read changes anything (the invariants are cited where the code relies on them):

T1. A pass that can do something a host sees at its instant (an event: the current switching
    to standby or back; a stall stop while a stall may come) and every stall sample are the
    axis's events: :meth:`FirmwareTasks.due`, part of ``next_event_ns``, so a batch ends there.
T2. Every other pass changes only what the firmware keeps for reads (AP 180, the driver's
    readings, the coolStep switch, the current's level); it is run later, when the chip is
    next brought forward, but at its own instant with the chip as it was then
    (:meth:`FirmwareTasks.lazy_pass`): the chip never passes the instant of a pass that may
    switch something before the pass has run; of the passes that only read the driver, the
    last one before the chip moves on is kept with a copy of the chip from before it, and
    run on that copy when something reads what it read (:meth:`FirmwareTasks.settle`); the
    passes that cannot matter are left out.
T3. A read changes nothing: AP 180 (and a TMC262's AP 206/208) answer what the last pass read,
    the generic load reading is a function of the position, and the coolStep regulation is
    fed only at the passes, at the world's load edges and at commands, where feeding is
    additive (axes/stallguard.py, ``CoolStep``).  So a value read is the same whenever and
    however often it is read, and :meth:`FirmwareTasks.steady_until` says until when: the
    next pass that may change it.
"""

from __future__ import annotations

from typing import Protocol

from axes import stallguard
from axes.board import AxisBoard
from axes.core import ChipDriver, ChipModel, MotorDriverLink
from axes.interface import FOREVER, AxisEventKind
from axes.stallguard import CoolStep
from tmcl_spec.modules import FirmwareClock
from tmcl_spec.numbers import NS_PER_MS
from tmcl_spec.parameters import AP

#: How often the firmware samples stallGuard where its pass does not check the stall.
STALL_SAMPLE_NS = NS_PER_MS
#: AP 214 counts 10 ms.
POWER_DOWN_UNIT_NS = 10 * NS_PER_MS
#: What the pass keeps for reads: AP 180 always, the driver's readings where there is one.
_DRIVER_READINGS = frozenset({AP.SMARTENERGY_ACTUAL_CURRENT, AP.LOAD, AP.DRIVER_ERROR_FLAGS})


class TaskedAxis(Protocol):
    """What the tasks need of their axis (``axes.firmware.AxisFirmware``)."""

    driver: ChipDriver
    motor_driver: MotorDriverLink | None
    board: AxisBoard

    def present_ns(self) -> int:
        ...

    def actual_speed(self) -> int:
        ...

    def mechanical(self) -> int:
        """Where the mechanics are (world units)."""
        ...

    def generic_load(self) -> int:
        """AP 206 without a modelled driver: the reading at the position now (pure)."""
        ...

    def full_steps_moved(self) -> int:
        """Motor steps (microsteps) since the motion in progress began."""
        ...

    def current_changed(self) -> None:
        """The current in use changed: a modelled driver follows."""
        ...

    def emit_at(self, time_ns: int, kind: AxisEventKind, active: bool | None = None) -> None:
        ...

    def stall_stop(self) -> None:
        """Stop at once for a stall: error flag 1, a STALL event."""
        ...


class FirmwareTasks:
    """The firmware's periodic work for one axis, on the module's firmware clock."""

    def __init__(self, axis: TaskedAxis, params: dict[int, int]) -> None:
        self._axis = axis
        self._params = params
        self.profile = FirmwareClock()
        self._origin = 0
        self._period = self.profile.pass_ms * NS_PER_MS
        #: The next pass not yet run (or left out, T2).
        self.next_pass_ns = self._period
        #: In standby current (AP 7); else AP 6, or AP 183 while ``slow``.
        self.standby = False
        self.slow = False
        #: The last pass that saw the motor move (``StandbyTimer``); None: none since power-up
        #: (the firmware's INT_MAX: standby at the first pass).
        self._moved_at: int | None = None
        #: When the motor came to rest (None while it moves: the firmware's standstill), and
        #: when the motion in progress began (None at rest).
        self.rest_since: int | None = 0
        self._moving_since: int | None = None
        #: coolStep switched on (the driver's SEMIN = AP 172), and its regulation (no driver).
        self.coolstep_on = False
        self.coolstep = CoolStep()
        #: AP 180 as the last pass read it (0 before the first: a zeroed global).
        self._scale_read = 0
        #: A stall may come: a pass (or a sample) is an event (T1).
        self.stall_watch = False
        #: The last pass that only reads the driver, left for a read: its instant, and a copy
        #: of the chip from before the chip went past it (T2).
        self._deferred: tuple[int, ChipModel] | None = None
        #: Something changed since the last pass ran (a command, the motor stopping or
        #: starting, the current or coolStep switching): at rest, the next pass may decide
        #: otherwise than the last one; passes after it decide alike.
        self.dirty = True
        #: The current's next switch (:meth:`_current_due`) as last computed, while known.
        self._due: int | None = None
        self._due_known = False

    # == the clock =============================================================================

    def start(self, profile: FirmwareClock, origin_ns: int, slot: int, axes: int) -> None:
        """The firmware starts (power-up at ``origin_ns``): axis ``slot`` of ``axes``."""
        self.profile = profile
        self._origin = origin_ns
        step = profile.pass_ms * NS_PER_MS
        self._period = step * axes if profile.one_axis_per_pass else step
        self.next_pass_ns = origin_ns + step * ((slot if profile.one_axis_per_pass else 0) + 1)
        self._due_known = False

    def touch(self) -> None:
        """A command may have changed what the next pass decides (a setting, AP 214)."""
        self.dirty = True
        self._due_known = False

    def _pass_from(self, t_ns: int) -> int:
        """The first pass at or after ``t_ns`` (and not before the next one to run)."""
        first = self.next_pass_ns
        if t_ns <= first:
            return first
        return first + -(-(t_ns - first) // self._period) * self._period

    def _sample_after(self, t_ns: int) -> int:
        return self._origin + ((t_ns - self._origin) // STALL_SAMPLE_NS + 1) * STALL_SAMPLE_NS

    def due(self) -> int | None:
        """The next instant this axis's firmware does something a host sees (T1)."""
        due = self._due if self._due_known else self._current_due()
        if self.stall_watch:
            check = (self.next_pass_ns if self.profile.stall_in_pass
                     else self._sample_after(self._axis.present_ns()))
            if due is None or check < due:
                due = check
        return due

    def _current_due(self) -> int | None:
        """The pass that switches the current (to standby, or back to run), kept until
        something changes it."""
        profile = self.profile
        rest = self.rest_since
        due: int | None = None
        if not profile.current_in_pass:
            if rest is not None and not self.standby:
                due = rest + self._params[AP.POWER_DOWN_DELAY] * POWER_DOWN_UNIT_NS
        elif rest is None:
            if self.standby and self._moving_since is not None:  # back to the run current
                due = self._pass_from(self._moving_since)
        elif not self.standby:
            due = self._pass_from(rest)
            if self._moved_at is not None:
                delay = self._params[AP.POWER_DOWN_DELAY] * POWER_DOWN_UNIT_NS
                due = self._pass_from(max(due, self._moved_at + delay + 1))
        self._due, self._due_known = due, True
        return due

    def lazy_pass(self, until_ns: int) -> int | None:
        """The next pass before ``until_ns`` that must run at its instant before the chip
        moves on (T2), or None; the passes that need not run are left out."""
        first = self.next_pass_ns
        if first >= until_ns:
            return None
        axis = self._axis
        if self._switches() and (self.dirty or self.rest_since is None):
            return first  # each pass may switch coolStep or the current: all run, in turn
        last = first + (until_ns - 1 - first) // self._period * self._period
        self.next_pass_ns = last + self._period
        self._due_known = False
        if axis.motor_driver is not None:  # only the last one's readings can be read
            self._deferred = (last, axis.driver.chip.clone())
        return None

    def left_out_until(self) -> int:
        """The last instant up to which :meth:`lazy_pass` leaves every pass out (a reading's
        passes, T2): each pass must run where one may switch coolStep or the current, so up
        to the next pass's instant (lazy_pass runs none up to it); else every pass is left
        out, until a command or an event changes that."""
        if self._switches() and (self.dirty or self.rest_since is None):
            return self.next_pass_ns
        return FOREVER

    def settle(self) -> None:
        """Something reads what the last pass read from the driver: a pass left for it runs
        now on the copy of the chip made before the chip went past it (T2)."""
        deferred = self._deferred
        if deferred is None:
            return
        self._deferred = None
        at, twin = deferred
        until = twin.ticks_at(at)
        while twin.t < until and twin.run(until) is not None:
            pass  # a notable instant on the way (the firmware reacted to it on the chip)
        motor_driver = self._axis.motor_driver
        assert motor_driver is not None
        motor_driver.sample(twin)
        self._scale_read = motor_driver.current_scale()

    def _switches(self) -> bool:
        """A pass may switch coolStep or the current by the speed (else all passes of a
        stretch decide alike).  coolStep regulated by the firmware's own model is fed at
        every pass while it is on."""
        p, profile = self._params, self.profile
        if p[AP.SMARTENERGY_HYSTERESIS_START] and profile.coolstep_by_speed:
            return True
        if self.coolstep_on and self._axis.motor_driver is None:
            return True
        slow = p.get(AP.SMARTENERGY_SLOW_RUN_CURRENT)
        return (profile.current_in_pass and slow is not None
                and bool(p[AP.SMARTENERGY_THRESHOLD_SPEED]) and slow != p[AP.MAX_CURRENT])

    def _keeps_readings(self) -> bool:
        """What a pass reads depends on the motion: a driver's readings, coolStep's scale."""
        return self._axis.motor_driver is not None or self.coolstep_on

    # == the pass ==============================================================================

    def run_pass(self, t_ns: int) -> None:
        """This axis's pass at ``t_ns``, the chip brought there (SysControl.c lines 57-137)."""
        axis, p, profile = self._axis, self._params, self.profile
        self.next_pass_ns = t_ns + self._period
        self._deferred = None  # this one's readings are the last ones
        self.dirty = False
        self._due_known = False
        self.feed()
        speed = abs(axis.actual_speed())
        resting = self.rest_since is not None
        if profile.current_in_pass:
            if resting:
                if not self.standby and (self._moved_at is None or t_ns - self._moved_at
                                         > p[AP.POWER_DOWN_DELAY] * POWER_DOWN_UNIT_NS):
                    self._set_current(standby=True, slow=self.slow)
                    axis.emit_at(t_ns, AxisEventKind.CURRENT_CHANGED, False)
            else:
                slow = (AP.SMARTENERGY_SLOW_RUN_CURRENT in p
                        and speed < p[AP.SMARTENERGY_THRESHOLD_SPEED])
                self._moved_at = t_ns
                if self.standby:
                    self._set_current(standby=False, slow=slow)
                    axis.emit_at(t_ns, AxisEventKind.CURRENT_CHANGED, True)
                elif slow != self.slow:
                    self._set_current(standby=False, slow=slow)
        if profile.coolstep_by_speed:
            self.switch_coolstep(stallguard.switched_on(p, speed))
        motor_driver = axis.motor_driver
        if motor_driver is not None:
            motor_driver.sample()
            self._scale_read = motor_driver.current_scale()
        else:
            self._scale_read = self._scale_now()
        if profile.stall_in_pass and self.stall_watch:
            self.check_stall(act=True)

    def _set_current(self, standby: bool, slow: bool) -> None:
        self.standby, self.slow = standby, slow
        self.touch()
        self._axis.current_changed()

    def switch_coolstep(self, on: bool) -> None:
        """SEMIN = AP 172 or 0 (the pass by the speed; SAP 172 and AP 182 = 0 at once)."""
        if on == self.coolstep_on:
            return
        self.feed()  # the steps so far count with the switch as it was
        self.coolstep_on = on
        self.dirty = True
        axis = self._axis
        if axis.motor_driver is not None:
            axis.motor_driver.switch_coolstep(on)
        else:  # off: the full current; on: regulating from here, from the full current
            self.coolstep.feed(self._params, axis.mechanical(), 0, on=False)

    def feed(self) -> None:
        """coolStep's regulation up to now (additive: T3), where the firmware models it."""
        if not self.coolstep_on:
            return
        axis = self._axis
        if axis.motor_driver is None:
            self.coolstep.feed(self._params, axis.mechanical(), axis.generic_load(), on=True,
                               full=self.current_setting() >> stallguard.CURRENT_SCALE_SHIFT)
        else:
            axis.motor_driver.observe()

    # == the current ===========================================================================

    def motion_started(self, t_ns: int) -> None:
        """A command set the motor going at ``t_ns``."""
        self.touch()
        self.rest_since = None
        if self._moving_since is None:
            self._moving_since = t_ns
        if not self.profile.current_in_pass and self.standby:
            self._set_current(standby=False, slow=False)  # the controller's own, at once
            self._axis.emit_at(t_ns, AxisEventKind.CURRENT_CHANGED, True)

    def came_to_rest(self, t_ns: int) -> None:
        """The motor stopped at ``t_ns``: the last pass that saw it move is the standby
        timer's start (every pass in between saw it move)."""
        self.touch()
        self.rest_since = t_ns
        since, self._moving_since = self._moving_since, None
        if since is None or not self.profile.current_in_pass:
            return
        last = self._pass_from(t_ns) - self._period  # the last pass before t_ns
        if last >= since and (self._moved_at is None or last > self._moved_at):
            self._moved_at = last

    def standby_due(self, t_ns: int) -> None:
        """Where the controller switches the current (not the pass): the delay has run out."""
        if not self.profile.current_in_pass and not self.standby:
            rest = self.rest_since
            delay = self._params[AP.POWER_DOWN_DELAY] * POWER_DOWN_UNIT_NS
            if rest is not None and t_ns >= rest + delay:
                self._set_current(standby=True, slow=False)
                self._axis.emit_at(t_ns, AxisEventKind.CURRENT_CHANGED, False)

    def current_setting(self) -> int:
        """The current the firmware set (0..255): AP 7, AP 183 or AP 6."""
        p = self._params
        if self.standby:
            return p[AP.STANDBY_CURRENT]
        return p[AP.SMARTENERGY_SLOW_RUN_CURRENT] if self.slow else p[AP.MAX_CURRENT]

    def current(self) -> int:
        """The motor current now (telemetry), lowered by coolStep where it regulates."""
        setting = self.current_setting()
        motor_driver = self._axis.motor_driver
        if motor_driver is not None:
            self.settle()
            scale = motor_driver.current_scale() if self.coolstep_on else None
        else:
            scale = self._scale_now() if self.coolstep.scale is not None else None
        return stallguard.run_current(setting, scale)

    def _scale_now(self) -> int:
        """AP 180 as the driver would show it now: coolStep's scale while it regulates (within
        the current's scale), else the current's scale."""
        full = self.current_setting() >> stallguard.CURRENT_SCALE_SHIFT
        scale = self.coolstep.scale
        if scale is None:
            return full
        lowest = stallguard.minimum_scale(full, bool(self._params[AP.SMARTENERGY_CURRENT_MINIMUM]))
        return max(lowest, min(full, scale))

    # == what reads see (T3) ===================================================================

    def actual_scale(self) -> int:
        """AP 180: what the last pass read (the current's scale at once where nothing the
        motor does moves it: no driver, coolStep off)."""
        if self._keeps_readings() or self.coolstep.scale is not None:
            self.settle()
            return self._scale_read
        return self.current_setting() >> stallguard.CURRENT_SCALE_SHIFT

    def kept(self, number: int) -> bool:
        """Whether GAP ``number`` answers what the pass read (AP 180, a driver's readings)."""
        if number == AP.SMARTENERGY_ACTUAL_CURRENT:
            return True
        return self._axis.motor_driver is not None and number in _DRIVER_READINGS

    def steady_until(self) -> int:
        """How long what a pass keeps for reads holds: until the next pass that may change
        it (T3); with nothing the motor does behind it, until an event or a command."""
        if not self._keeps_readings() and self.coolstep.scale is None:
            return FOREVER
        if self._axis.motor_driver is None and self.rest_since is not None:
            return FOREVER  # at rest coolStep's scale stays; the current switches at events
        return self.next_pass_ns

    # == stallGuard ============================================================================

    def check_stall(self, act: bool | None = None) -> None:
        """AP 181: stop a motor faster than that whose stallGuard2 reads 0, and keep watching
        (T1) while one may come: a zero reading still too slow, or a load under the motor
        that reads 0 (a filtered reading still falling towards it).  ``act``: may stop now
        (None: unless the pass alone checks, as on the TMC429 modules)."""
        axis = self._axis
        if act is None:
            act = not self.profile.stall_in_pass
        threshold = self._params[AP.STOP_ON_STALL]
        watching = False
        if threshold and self.rest_since is None:
            stalled = self._stalled()
            if stalled and act and abs(axis.actual_speed()) > threshold:
                axis.stall_stop()
            elif stalled or stallguard.reading(axis.board.world.load_at(axis.mechanical()),
                                               self._params[AP.STALLGUARD_THRESHOLD]) == 0:
                watching = True
        self.stall_watch = watching

    def _stalled(self) -> bool:
        """stallGuard2 reads 0.  A modelled driver measures at full steps (four with the
        filter): until the motor made that many since it started, its flag is the last
        motion's, which the firmware ignores."""
        axis = self._axis
        motor_driver = axis.motor_driver
        if motor_driver is None:
            return axis.generic_load() == 0
        full_step = 1 << self._params[AP.MICROSTEPS]
        if self._params[AP.STALLGUARD_FILTER]:
            full_step *= stallguard.FILTER_FULL_STEPS
        return axis.full_steps_moved() >= full_step and motor_driver.stalled()

    def run_due(self, t_ns: int) -> None:
        """Whatever is due at ``t_ns`` (an event of T1; the chip brought there)."""
        if t_ns == self.next_pass_ns:
            self.run_pass(t_ns)
        self.standby_due(t_ns)
        if self.stall_watch and not self.profile.stall_in_pass:
            self.check_stall()
