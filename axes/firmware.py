"""The TMCM-6212 firmware for one axis, on top of an emulated TMC4210.

:class:`TMC4210Axis` implements :class:`axes.interface.Axis`.  It owns the chip and talks to
it only through :meth:`TMC4210.spi` datagrams, exactly like the module's microcontroller: it
converts axis parameters in pps/pps² to register values (choosing PULSE_DIV/RAMP_DIV and
computing PMUL/PDIV), extends the 24-bit position to 32 bits, runs the reference-search state
machine, watches encoder deviation and stallGuard load, and manages the motor current.

It also owns the :class:`AxisBoard`: the module's input stage (limit-switch swap and polarity)
and the mechanics (the world's switches, load zones and encoder) as the chip's pins see them.

Time: the axis keeps the simulated time it was last advanced to.  To find its next event it
runs a *copy* of the chip forward (:meth:`_lookahead`); :meth:`advance_to` then adopts that
copy at the event instant, so each stretch of motion is computed once.  Every modelling
choice is explained in docs/motion.md.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass

from axes.interface import AxisEvent, AxisEventKind, AxisStatus
from axes.tmc4210 import (
    DEFAULT_CLOCK_HZ,
    DISABLE_STOP_L,
    DISABLE_STOP_R,
    EN_SD,
    MASK24,
    MOT1R,
    SMGP_POWER_ON,
    SOFT_STOP,
    TMC4210,
    Irq,
    RampMode,
    Reg,
    Stop,
    datagram,
    sdiff24,
    signed,
)
from axes.units import (
    V_REGISTER_MAX,
    choose_pulse_div,
    choose_ramp_div,
    max_step_rate,
    pmul_pdiv,
    step_rate,
    stop_speed,
    velocity_register,
)
from axes.world import AxisWorld, LoadZone, Switch
from tmcl_spec.numbers import NS_PER_MS, NS_PER_S, to_int32
from tmcl_spec.parameters import AP, ParamSpec
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS

log = logging.getLogger(__name__)

#: Telemetry's name for what the chip's ramp mode means to a TMCL host.
_MODE_NAMES = {RampMode.RAMP: "position", RampMode.SOFT: "position",
               RampMode.VELOCITY: "velocity", RampMode.HOLD: "hold"}

#: How far ahead the firmware looks for the next event; also bounds how many steps pass
#: between two reads of the 24-bit X_ACTUAL (4 s at 1 Mpps is well below 2**23).
LOOKAHEAD_NS = 4 * NS_PER_S
#: Rolling targets: a move farther than this is fed to the chip in pieces of this length.
ROLLING_SPAN = 1 << 22
ROLLING_REFRESH = 1 << 21
#: How often the firmware samples stallGuard while it could stall but does not yet.
STALL_POLL_NS = NS_PER_MS
#: STEP pulse length 4 µs at 16 MHz and mot1r = 1 (the right switch belongs to the axis).
SMGP_FIRMWARE = MOT1R | (SMGP_POWER_ON & ~0xF00) | 3 << 8

STOP_FLAG = 1 << Irq.STOP
STOP_MASK = STOP_FLAG << 8

ERROR_STALL = 1
ERROR_DEVIATION = 2

# == the board: input stage + mechanics ========================================================


class AxisBoard:
    """What the chip's pins and STEP output are connected to, for one axis.

    Mechanical position (world units, 1/256 microsteps) = ``mech_base`` + (motor steps -
    ``steps_base``) * 2**(8 - microstep setting).  Switch levels are the world's electrical
    levels, swapped (AP 14) and XOR-ed with the polarity parameters (AP 24/25) by the
    module's input stage before they reach REF_L/REF_R; the home switch drives GP_IN.
    """

    def __init__(self, world: AxisWorld | None = None) -> None:
        self.world = world or AxisWorld()
        self.swap = False
        self.invert_left = False
        self.invert_right = False
        self.scale = 1
        self.mech_base = 0
        self.steps_base = 0
        #: Extra motor positions the firmware wants to be woken at (deviation, rolling target).
        self.firmware_marks: list[int] = []
        self._edges = self.world.edges()

    def set_world(self, world: AxisWorld) -> None:
        self.world = world
        self._edges = world.edges()

    def world_changed(self) -> None:
        self._edges = self.world.edges()

    def rescale(self, motor_position: int, microstep_setting: int) -> None:
        """A new microstep resolution: later steps move 2**(8 - setting) world units each."""
        self.mech_base = self.mechanical(motor_position)
        self.steps_base = motor_position
        self.scale = 1 << (8 - microstep_setting)

    def mechanical(self, motor_position: int) -> int:
        return self.mech_base + (motor_position - self.steps_base) * self.scale

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        mech = self.mechanical(motor_position)
        left = self.world.level("left", mech)
        right = self.world.level("right", mech)
        if self.swap:
            left, right = right, left
        return left != self.invert_left, right != self.invert_right, self.world.level("home", mech)

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        mech = self.mechanical(motor_position)
        best: int | None = None
        if direction > 0:
            for edge in self._edges:  # levels at p and p - 1 differ: first step with mech >= edge
                if edge > mech:
                    best = self.steps_base + -(-(edge - self.mech_base) // self.scale)
                    break
        else:
            for edge in reversed(self._edges):  # last step with mech <= edge - 1
                if edge - 1 < mech:
                    best = self.steps_base + (edge - 1 - self.mech_base) // self.scale
                    break
        for mark in self.firmware_marks:
            if (mark - motor_position) * direction > 0 and (
                    best is None or (mark - best) * direction < 0):
                best = mark
        return best


# == the reference search ======================================================================


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


def reference_plan(mode: int) -> tuple[list[Phase], bool]:
    """The phases of RFS for AP 193 ``mode``, and whether the home switch is inverted."""
    inverted = mode >= 128
    base = mode - 128 if inverted else mode
    if inverted and base <= 4:
        base += 4  # the manual's own examples spell "mode 5..8 + 128" as 129..132
    mirrored = 64 < base < 128
    base = base - 64 if mirrored else base
    near, far, down = ("right", "left", 1) if mirrored else ("left", "right", -1)
    seek_near = Phase("seek", near, down)
    seek_far = Phase("seek", far, -down)
    if base == 1:
        phases = [seek_near, *_calibrate(near, down, "near")]
    elif base == 2:
        phases = [seek_far, *_calibrate(far, -down, "other"), seek_near, *_calibrate(near, down, "near")]
    elif base == 3:
        phases = [seek_far, *_calibrate(far, -down, "other"), seek_near, *_middle(near, down)]
    elif base == 4:
        phases = [seek_near, *_middle(near, down)]
    elif base == 5:
        phases = [Phase("seek", "home", -1, reverse_on="left"), *_calibrate("home", -1, "near")]
    elif base == 6:
        phases = [Phase("seek", "home", 1, reverse_on="right"), *_calibrate("home", 1, "near")]
    elif base == 7:
        phases = [Phase("seek", "home", 1), *_middle("home", 1)]
    elif base == 8:
        phases = [Phase("seek", "home", -1), *_middle("home", -1)]
    else:
        raise ValueError(f"reference search mode {mode} is not defined")
    return [*phases, Phase("finish", "", 0)], inverted


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
    points: dict[str, int] | None = None
    direction: int = 0
    reversed_once: bool = False

    @property
    def phase(self) -> Phase:
        return self.phases[self.index]


# == the axis ==================================================================================


_UNKNOWN = object()  # lookahead not computed since the last change

#: Parameters whose value depends on the motion (read from the chip at the present time).
_LIVE_PARAMETERS = frozenset({AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.ACTUAL_SPEED,
                              AP.POSITION_REACHED, AP.LEFT_SWITCH, AP.RIGHT_SWITCH,
                              AP.HOME_SWITCH, AP.LOAD, AP.ERROR_FLAGS, AP.ENCODER_POSITION,
                              AP.SMARTENERGY_ACTUAL_CURRENT})


@dataclass(slots=True)
class _Lookahead:
    chip: TMC4210
    stop: Stop | None  # None: nothing happened up to the horizon
    time_ns: int


class TMC4210Axis:
    """One TMCM-6212 axis: TMCL axis parameters in, TMC4210 datagrams out."""

    def __init__(self, index: int, clock_hz: int = DEFAULT_CLOCK_HZ,
                 world: AxisWorld | None = None,
                 parameters: Mapping[int, ParamSpec] = AXIS_PARAMETERS) -> None:
        self.index = index
        self.board = AxisBoard(world)
        self.chip = TMC4210(clock_hz, self.board)
        self._params = {n: spec.default for n, spec in parameters.items()}
        self._now_ns = 0
        self._pending: list[AxisEvent] = []
        #: The chip's next notable instant; None = nothing ahead, _UNKNOWN = not computed.
        self._lookahead_cache: _Lookahead | object | None = _UNKNOWN
        # Firmware state
        self._x_last = 0  # last X_ACTUAL read (24 bit)
        self._position = 0  # AP 1, 32 bit
        self._target = 0  # AP 0, 32 bit
        self._chip_target = 0  # the X_TARGET the chip has now (24 bit)
        self._positioning = False
        self._awaiting_arrival = False
        self._velocity_command = 0
        self._pulse_div = 0
        self._ramp_div = 0
        self._rfs: ReferenceSearch | None = None
        self._rfs_state = 0
        self._errors = 0
        self._levels = (False, False, False)  # logical left, right, home
        self._standstill_since: int | None = 0
        self._standby = False
        self._encoder_offset = 0  # encoder counts added to what the mechanics give
        self._encoder_mech_base = 0  # mechanical position at which slip was last rebased
        self._stall_watch = False
        self._init_chip()

    # == chip access ===========================================================================

    def _spi_write(self, reg: int, data: int) -> None:
        self.chip.spi(datagram(reg, data))

    def _spi_read(self, reg: int) -> int:
        return self.chip.spi(datagram(reg, read=True)) & MASK24

    def _init_chip(self) -> None:
        """What the firmware does at power-up (spec §8.2): outputs on, right switch wired.

        The int_stop interrupt is enabled so that the firmware learns of hard switch stops.
        """
        self._spi_write(Reg.IF_CONFIGURATION, EN_SD)
        self._spi_write(Reg.SMGP, SMGP_FIRMWARE)
        self._spi_write(Reg.INTERRUPT, STOP_MASK)
        self._write_ref_conf(RampMode.VELOCITY)
        self._apply_limits(self._params[AP.MAX_SPEED])
        self._levels = self._read_levels()

    @property
    def clock_hz(self) -> int:
        return self.chip.clock_hz

    # == time ==================================================================================

    def _invalidate(self) -> None:
        self._lookahead_cache = _UNKNOWN

    def _lookahead(self) -> _Lookahead | None:
        """Run a copy of the chip to its next notable instant (or the horizon)."""
        if self._lookahead_cache is not _UNKNOWN:
            return self._lookahead_cache  # type: ignore[return-value]
        twin = self.chip.clone()
        horizon_ns = max(self._now_ns, self.chip.ns_at(twin.t)) + LOOKAHEAD_NS
        stop = twin.run(twin.ticks_at(horizon_ns))
        at_rest = stop is None and twin.at_rest()
        result = None if at_rest else _Lookahead(twin, stop, twin.ns_at(twin.t))
        self._lookahead_cache = result
        return result

    def _timer_due(self) -> int | None:
        """The firmware's own next deadline (standby current, stallGuard sampling)."""
        times = []
        if self._standstill_since is not None and not self._standby:
            times.append(self._standstill_since + self._params[AP.POWER_DOWN_DELAY] * 10 * NS_PER_MS)
        if self._stall_watch:
            times.append(self._now_ns + STALL_POLL_NS)
        return min(times) if times else None

    def next_event_ns(self) -> int | None:
        if self._pending:
            return self._now_ns
        times = []
        ahead = self._lookahead()
        if ahead is not None:
            times.append(max(ahead.time_ns, self._now_ns))
        timer = self._timer_due()
        if timer is not None:
            times.append(max(timer, self._now_ns))
        return min(times) if times else None

    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        while True:
            ahead = self._lookahead()
            timer = self._timer_due()
            chip_at = ahead.time_ns if ahead is not None else None
            if chip_at is not None and chip_at <= t_ns and (timer is None or chip_at <= timer):
                self.chip = ahead.chip
                self._invalidate()
                self._now_ns = max(self._now_ns, chip_at)
                self._react(ahead.stop)
            elif timer is not None and timer <= t_ns:
                self._now_ns = max(self._now_ns, timer)
                self._sync()
                self._on_timer()
            else:
                break
        self._now_ns = max(self._now_ns, t_ns)
        events, self._pending = self._pending, []
        return events

    def _sync(self) -> None:
        """Bring the chip up to ``_now_ns`` and read the position (before any command)."""
        until = self.chip.ticks_at(self._now_ns)
        while self.chip.t < until:
            stop = self.chip.run(until)
            if stop is None:
                break
            self._react(stop)  # only reached if the lookahead was skipped
        self._read_position()

    def _read_position(self) -> None:
        x = self._spi_read(Reg.X_ACTUAL)
        self._position = to_int32(self._position + sdiff24(x, self._x_last))
        self._x_last = x

    def _emit(self, kind: AxisEventKind, active: bool | None = None) -> None:
        self._pending.append(AxisEvent(self._now_ns, self.index, kind, active))

    # == reacting to the chip ==================================================================

    def _react(self, stop: Stop | None) -> None:
        """Whatever the firmware does at a notable instant (it reacts within the same tick)."""
        self._read_position()
        self._check_levels()
        moving = self._v_actual() != 0
        switch_stopped = bool(self._spi_read(Reg.INTERRUPT) & STOP_FLAG)
        if switch_stopped:
            self._spi_write(Reg.INTERRUPT, STOP_MASK | STOP_FLAG)  # clear it, keep the mask
        if self._positioning and self._awaiting_arrival and self._rolling_needed():
            self._feed_target()
        if (stop in (Stop.ARRIVED, Stop.STOPPED) or switch_stopped) and not moving:
            self._standstill_since = self._now_ns
            if not self._positioning and self._rfs is None:
                self._target = self._position  # MVP REL after a rotation starts from here
            if self._positioning and self._awaiting_arrival and self._position == self._target:
                self._awaiting_arrival = False
                if self._rfs is None:
                    self._emit(AxisEventKind.TARGET_REACHED)
        if self._rfs is not None:
            self._rfs_step()
        self._check_stall()
        self._check_deviation()
        self._update_marks()

    def _on_timer(self) -> None:
        if (self._standstill_since is not None and not self._standby and self._now_ns
                >= self._standstill_since + self._params[AP.POWER_DOWN_DELAY] * 10 * NS_PER_MS):
            self._standby = True
            self._emit(AxisEventKind.CURRENT_CHANGED, False)
        self._check_stall()

    def _v_actual(self) -> int:
        return signed(self._spi_read(Reg.V_ACTUAL), 12)

    def _read_levels(self) -> tuple[bool, bool, bool]:
        switches = self._spi_read(Reg.REFERENCE_SWITCHES)
        return bool(switches & 2), bool(switches & 1), bool(switches & 8)

    def _check_levels(self) -> None:
        levels = self._read_levels()
        for kind, old, new in zip(
                (AxisEventKind.LEFT_SWITCH, AxisEventKind.RIGHT_SWITCH, AxisEventKind.HOME_SWITCH),
                self._levels, levels, strict=True):
            if old != new:
                self._emit(kind, new)
        self._levels = levels

    def _motion_started(self) -> None:
        self._standstill_since = None
        if self._standby:
            self._standby = False
            self._emit(AxisEventKind.CURRENT_CHANGED, True)
        self._errors = 0

    # == unit conversion =======================================================================

    @property
    def _pps_units(self) -> bool:
        return self._params[AP.UNIT_MODE] == 1

    def _to_register(self, speed: int) -> int:
        if self._pps_units:
            return velocity_register(speed, self._pulse_div, self.clock_hz)
        return min(abs(speed), V_REGISTER_MAX)

    def _to_speed(self, v: int) -> int:
        if self._pps_units:
            return round(step_rate(v, self._pulse_div, self.clock_hz))
        return v

    def _set_dividers(self, top_speed: int, acceleration: int) -> None:
        """Choose PULSE_DIV for ``top_speed`` and RAMP_DIV/A_MAX/PMUL/PDIV for the acceleration.

        A running motor keeps its speed across a PULSE_DIV change: the firmware parks the
        chip in hold mode and rewrites V_ACTUAL on the new scale (dropping the fraction bits).
        """
        if self._pps_units:
            pulse_div = choose_pulse_div(top_speed, self.clock_hz)
            if pulse_div > self._pulse_div and self._v_actual():
                # A finer scale mid-move would round the running speed (its fraction bits
                # are lost in the rescale) and can cost a step of overshoot: a lower limit
                # runs on the present, coarser scale until the motor is at rest.
                pulse_div = self._pulse_div
            if abs(top_speed) > max_step_rate(0, self.clock_hz):
                log.warning("axis %d: %d pps is beyond the TMC4210 at %d Hz; running at %d pps",
                            self.index, top_speed, self.clock_hz,
                            round(max_step_rate(0, self.clock_hz)))
            ramp_div, a_max = choose_ramp_div(acceleration, pulse_div, self.clock_hz)
        else:
            pulse_div, ramp_div = self._pulse_div, self._ramp_div
            a_max = min(acceleration, V_REGISTER_MAX)
        if pulse_div != self._pulse_div or ramp_div != self._ramp_div:
            v_actual = signed(self._spi_read(Reg.V_ACTUAL), 12)
            mode = self._spi_read(Reg.REF_CONF_RAMP_MODE) & 3
            if v_actual and pulse_div != self._pulse_div:
                rescaled = round(v_actual * 2.0 ** (pulse_div - self._pulse_div))
                rescaled = max(-V_REGISTER_MAX, min(V_REGISTER_MAX, rescaled))
                self._write_ref_conf(RampMode.HOLD)
                self._spi_write(Reg.V_ACTUAL, rescaled & 0xFFF)
                if mode == RampMode.VELOCITY:
                    v_target = signed(self._spi_read(Reg.V_TARGET), 12)
                    scaled_target = round(v_target * 2.0 ** (pulse_div - self._pulse_div))
                    self._spi_write(Reg.V_TARGET, max(-2047, min(2047, scaled_target)) & 0xFFF)
            self._spi_write(Reg.DIVIDERS, pulse_div << 12 | ramp_div << 8)
            self._write_ref_conf(RampMode(mode))
            self._pulse_div, self._ramp_div = pulse_div, ramp_div
        self._spi_write(Reg.A_MAX, a_max)
        pair = pmul_pdiv(a_max, ramp_div, pulse_div) if a_max else (128, 0)
        if pair is None:
            pair = (255, 0) if a_max > 1 else (128, 13)
        self._spi_write(Reg.PMUL_PDIV, pair[0] << 8 | pair[1])
        # V_MIN must allow the abrupt stop at the speed the chip arrives with (units.stop_speed).
        v_min = max(self._to_register(self._params[AP.VSTOP]), stop_speed(a_max, *pair))
        self._spi_write(Reg.V_MIN, min(v_min, V_REGISTER_MAX))

    def _write_ref_conf(self, mode: RampMode) -> None:
        conf = mode
        searching = self._rfs is not None
        if searching or self._params[AP.LEFT_DISABLE]:
            conf |= DISABLE_STOP_L
        if searching or self._params[AP.RIGHT_DISABLE]:
            conf |= DISABLE_STOP_R
        if self._params[AP.SOFT_STOP]:
            conf |= SOFT_STOP
        self._spi_write(Reg.REF_CONF_RAMP_MODE, conf)

    def _chip_mode(self) -> RampMode:
        return RampMode(self._spi_read(Reg.REF_CONF_RAMP_MODE) & 3)

    def _apply_limits(self, top_speed: int) -> None:
        self._set_dividers(self._top_speed(top_speed), self._params[AP.MAX_ACCELERATION])
        self._spi_write(Reg.V_MAX, self._to_register(top_speed))

    # == motion ================================================================================

    def _top_speed(self, requested: int) -> int:
        """Dividers must cover the requested speed and the speed the motor has right now."""
        return max(abs(requested), abs(self._actual_speed()))

    def _start_velocity(self, speed: int) -> None:
        self._set_dividers(self._top_speed(speed), self._params[AP.MAX_ACCELERATION])
        register = self._to_register(speed)
        self._spi_write(Reg.V_MAX, register)
        self._spi_write(Reg.V_TARGET, (register if speed >= 0 else -register) & 0xFFF)
        self._write_ref_conf(RampMode.VELOCITY)
        self._positioning = False
        self._awaiting_arrival = False
        self._motion_started()

    def _start_positioning(self, target: int, top_speed: int) -> None:
        self._target = target
        self._set_dividers(self._top_speed(top_speed), self._params[AP.MAX_ACCELERATION])
        self._spi_write(Reg.V_MAX, self._to_register(top_speed))
        self._positioning = True
        self._awaiting_arrival = True
        self._feed_target()
        self._write_ref_conf(RampMode.RAMP)
        self._motion_started()
        if self._position == self._target and self._v_actual() == 0:
            self._awaiting_arrival = False
            self._standstill_since = self._now_ns
            if self._rfs is None:
                self._emit(AxisEventKind.TARGET_REACHED)

    def _feed_target(self) -> None:
        """Write X_TARGET; a move beyond the 24-bit range goes in rolling pieces."""
        remaining = self._target - self._position
        if abs(remaining) > ROLLING_SPAN:
            remaining = ROLLING_SPAN if remaining > 0 else -ROLLING_SPAN
        self._chip_target = (self._x_last + remaining) & MASK24
        self._spi_write(Reg.X_TARGET, self._chip_target)

    def _rolling_needed(self) -> bool:
        return (self._target != to_int32(self._position + sdiff24(self._chip_target, self._x_last))
                and abs(sdiff24(self._chip_target, self._x_last)) <= ROLLING_REFRESH)

    def rotate(self, velocity: int) -> None:
        self._command()
        self._abort_search()
        self._velocity_command = self._params[AP.TARGET_SPEED] = velocity
        self._start_velocity(velocity)
        self._after_command()

    def stop(self) -> None:
        self._command()
        self._abort_search()
        self._velocity_command = self._params[AP.TARGET_SPEED] = 0
        self._spi_write(Reg.V_TARGET, 0)
        self._write_ref_conf(RampMode.VELOCITY)
        self._positioning = False
        self._awaiting_arrival = False
        self._errors = 0
        self._after_command()

    def emergency_stop(self) -> None:
        self._command()
        self._abort_search()
        self._hard_stop()
        self._after_command()

    def _hard_stop(self) -> None:
        """Stop within one tick: hold mode, V_ACTUAL := 0, then velocity mode at speed 0."""
        self._write_ref_conf(RampMode.HOLD)
        self._spi_write(Reg.V_ACTUAL, 0)
        self._spi_write(Reg.V_TARGET, 0)
        self._write_ref_conf(RampMode.VELOCITY)
        self._positioning = False
        self._awaiting_arrival = False
        self._velocity_command = 0
        if self._standstill_since is None:
            self._standstill_since = self._now_ns
        self._update_marks()

    def move_to(self, target: int) -> None:
        self._command()
        self._abort_search()
        self._start_positioning(to_int32(target), self._params[AP.MAX_SPEED])
        self._after_command()

    def _command(self) -> None:
        """Every host command first brings the chip to the present."""
        self._sync()
        self._invalidate()

    def _after_command(self) -> None:
        self._check_stall()
        self._update_marks()
        self._invalidate()

    # == reference search ======================================================================

    def reference_search(self, action: int) -> int:
        if action == 2:
            self._sync()
            return self._rfs_state
        self._command()
        if action == 1:
            if self._rfs is not None:
                self._abort_search()
                self.stop()
            return 0
        plan, inverted = reference_plan(self._params[AP.RFS_MODE])
        self._abort_search()
        self._rfs = ReferenceSearch(plan, inverted, points={})
        self._errors = 0
        self._write_ref_conf(self._chip_mode())
        self._rfs_enter()
        self._after_command()
        return 0

    def _abort_search(self) -> None:
        if self._rfs is not None:
            self._rfs = None
            self._rfs_state = 0
            self._write_ref_conf(self._chip_mode())

    def _search_level(self, switch: str) -> bool:
        left, right, home = self._levels
        if switch == "home":
            return home != self._rfs.inverted_home
        return left if switch == "left" else right

    def _rfs_enter(self) -> None:
        """Start the current phase, or finish phases whose condition already holds."""
        search = self._rfs
        while search is not None:
            self._rfs_state = search.index + 1
            phase = search.phase
            if phase.kind == "finish":
                self._rfs_finish_move()
                return
            want_active = phase.kind != "leave"
            if self._search_level(phase.switch) == want_active:
                self._rfs_phase_done()
                search = self._rfs
                continue
            fast = phase.kind == "seek"
            speed = self._params[AP.RFS_SPEED if fast else AP.RFS_SWITCH_SPEED]
            search.direction = phase.direction
            if phase.reverse_on and self._search_level(phase.reverse_on):
                self._rfs_reverse()
            self._start_velocity(search.direction * speed)
            return

    def _rfs_phase_done(self) -> None:
        search = self._rfs
        phase = search.phase
        if phase.record:
            search.points[phase.record] = self._position
        self._hard_stop()
        search.index += 1

    def _rfs_step(self) -> None:
        """React to switch levels during a search (called at every notable instant)."""
        search = self._rfs
        phase = search.phase
        if phase.kind == "finish":
            if not self._awaiting_arrival and self._position == self._target:
                self._rfs_complete()
            return
        if phase.reverse_on and not search.reversed_once and self._search_level(phase.reverse_on):
            self._rfs_reverse()
            self._hard_stop()
            self._start_velocity(search.direction * self._params[AP.RFS_SPEED])
            self._update_marks()
            return
        want_active = phase.kind != "leave"
        if self._search_level(phase.switch) == want_active:
            self._rfs_phase_done()
            self._rfs_enter()

    def _rfs_reverse(self) -> None:
        """Modes 5/6 hit the limit switch: search the other way, and calibrate that way too."""
        search = self._rfs
        search.reversed_once = True
        search.direction = -search.direction
        for phase in search.phases[search.index + 1:]:
            phase.direction = -phase.direction

    def _rfs_finish_move(self) -> None:
        zero, distance = reference_point(self._rfs.points)
        self._rfs.points["zero"] = zero
        if distance is not None:
            self._params[AP.SWITCH_DISTANCE] = distance
        self._start_positioning(zero, self._params[AP.RFS_SWITCH_SPEED])
        if not self._awaiting_arrival:
            self._rfs_complete()

    def _rfs_complete(self) -> None:
        self._params[AP.LAST_REFERENCE] = self._position
        self._rfs = None
        self._rfs_state = 0
        self._set_position(0)
        self._set_encoder(0)
        self._write_ref_conf(self._chip_mode())
        self._emit(AxisEventKind.REFERENCE_SEARCH_DONE)

    # == stallGuard, encoder, current ==========================================================

    def _mechanical(self) -> int:
        return self.board.mechanical(self.chip.motor_position)

    def _load(self) -> int:
        return self.board.world.load_at(self._mechanical())

    def _actual_speed(self) -> int:
        v = self._v_actual()
        return -self._to_speed(-v) if v < 0 else self._to_speed(v)

    def _check_stall(self) -> None:
        threshold = self._params[AP.STOP_ON_STALL]
        watching = False
        if threshold and self._load() == 0 and self._standstill_since is None:
            if abs(self._actual_speed()) >= threshold:
                self._abort_search()
                self._hard_stop()
                self._errors |= ERROR_STALL
                self._emit(AxisEventKind.STALL)
            else:
                watching = True
        self._stall_watch = watching

    def _encoder_counts(self) -> int:
        world = self.board.world
        mech = self._mechanical()
        seen = (mech - self._encoder_mech_base) * (1.0 - world.encoder_slip)
        per_count = world.motor_fullsteps_per_rev * 256 / world.encoder_counts_per_rev
        return self._encoder_offset + int(seen // per_count)

    def _counts_per_microstep(self) -> float:
        resolution = self._params[AP.ENCODER_RESOLUTION]
        microsteps = self._params[AP.FULLSTEPS] << self._params[AP.MICROSTEPS]
        return resolution / microsteps if microsteps else 0.0

    def _encoder_position(self) -> int:
        ratio = self._counts_per_microstep()
        return to_int32(round(self._encoder_counts() / ratio)) if ratio else 0

    def _set_encoder(self, microsteps: int) -> None:
        counts = round(microsteps * self._counts_per_microstep())
        self._encoder_offset += counts - self._encoder_counts()

    def _rebase_encoder(self) -> None:
        """Keep the encoder reading continuous when slip or the mechanics mapping change."""
        self._encoder_offset = self._encoder_counts()
        self._encoder_mech_base = self._mechanical()

    def _deviation(self) -> float:
        """|AP 1 - AP 209| in encoder counts."""
        return abs(self._position - self._encoder_position()) * self._counts_per_microstep()

    def _check_deviation(self) -> None:
        limit = self._params[AP.MAX_DEVIATION]
        if limit and self._standstill_since is None and self._deviation() > limit:
            self._abort_search()
            self._hard_stop()
            self._errors |= ERROR_DEVIATION
            self._emit(AxisEventKind.DEVIATION)

    def _deviation_mark(self, direction: int) -> int | None:
        """Motor position where the deviation will first exceed AP 212 (slip > 0 only).

        The estimate is refined at the mark itself: if the limit is not yet exceeded there, a
        new mark at least one step further is set, so the event lands on the exact step.
        """
        limit = self._params[AP.MAX_DEVIATION]
        ratio = self._counts_per_microstep()
        world = self.board.world
        if not limit or not ratio or world.encoder_slip <= 0:
            return None
        per_count = world.motor_fullsteps_per_rev * 256 / world.encoder_counts_per_rev
        encoder_per_step = (1.0 - world.encoder_slip) * self.board.scale / per_count / ratio
        rate = direction * (1.0 - encoder_per_step)  # change of AP1 - AP209 per step
        if rate == 0:
            return None
        deviation = self._position - self._encoder_position()
        room = (limit / ratio - deviation) / rate if rate > 0 else (limit / ratio + deviation) / -rate
        return self.chip.motor_position + direction * max(1, int(room))

    def _update_marks(self) -> None:
        marks = []
        v = self._v_actual()
        direction = (v > 0) - (v < 0)
        if not direction and self._chip_mode() == RampMode.VELOCITY:
            target = signed(self._spi_read(Reg.V_TARGET), 12)
            direction = (target > 0) - (target < 0)
        elif not direction and self._chip_mode() in (RampMode.RAMP, RampMode.SOFT):
            dx = sdiff24(self._chip_target, self._x_last)
            direction = (dx > 0) - (dx < 0)
        for way in ((direction,) if direction else ()):
            mark = self._deviation_mark(way)
            if mark is not None:
                marks.append(mark)
        if self._positioning and self._awaiting_arrival:
            ahead = sdiff24(self._chip_target, self._x_last)
            if abs(ahead) > ROLLING_REFRESH and self._target != to_int32(self._position + ahead):
                step = 1 if ahead > 0 else -1
                marks.append(self.chip.motor_position + ahead - step * ROLLING_REFRESH)
        self.board.firmware_marks = marks

    @property
    def current(self) -> int:
        """The motor current now (0..255): AP 6 while moving, AP 7 after the power-down delay."""
        return self._params[AP.STANDBY_CURRENT if self._standby else AP.MAX_CURRENT]

    # == parameters ============================================================================

    def _set_position(self, value: int) -> None:
        """AP 1 write, following the datasheet: never rewrite X_ACTUAL in ramp/soft mode."""
        mode = self._chip_mode()
        if mode in (RampMode.RAMP, RampMode.SOFT):
            v_actual = signed(self._spi_read(Reg.V_ACTUAL), 12)
            self._spi_write(Reg.V_TARGET, v_actual & 0xFFF)
            self._write_ref_conf(RampMode.VELOCITY)
        x = value & MASK24
        self._spi_write(Reg.X_ACTUAL, x)
        self._spi_write(Reg.X_TARGET, x)
        self._x_last = self._chip_target = x
        self._position = value
        self._target = value
        if mode in (RampMode.RAMP, RampMode.SOFT) and self._v_actual() == 0:
            self._write_ref_conf(RampMode.RAMP)
        elif mode in (RampMode.RAMP, RampMode.SOFT):
            self._spi_write(Reg.V_TARGET, 0)  # a move in flight ends with a ramped stop
            self._positioning = False
        self._awaiting_arrival = False

    def get_parameter(self, number: int) -> int:
        if number not in _LIVE_PARAMETERS:
            return self._params[number]  # configuration: no need to bring the chip up to date
        self._sync()
        if number == AP.TARGET_POSITION:
            return self._target
        if number == AP.ACTUAL_POSITION:
            return self._position
        if number == AP.ACTUAL_SPEED:
            return self._actual_speed()
        if number == AP.POSITION_REACHED:
            return int(self._position == self._target)
        if number in (AP.LEFT_SWITCH, AP.RIGHT_SWITCH, AP.HOME_SWITCH):
            left, right, home = self._read_levels()
            return int({AP.LEFT_SWITCH: left, AP.RIGHT_SWITCH: right, AP.HOME_SWITCH: home}[number])
        if number == AP.LOAD:
            return self._load()
        if number == AP.ERROR_FLAGS:
            flags, self._errors = self._errors, 0
            return flags
        if number == AP.ENCODER_POSITION:
            return self._encoder_position()
        if number == AP.SMARTENERGY_ACTUAL_CURRENT:  # full scale 0..31 of the running current
            return self.current >> 3
        return self._params[number]

    def set_parameter(self, number: int, value: int) -> None:
        self._command()
        if number == AP.TARGET_POSITION:
            self._abort_search()
            self._start_positioning(to_int32(value), self._params[AP.MAX_SPEED])
        elif number == AP.ACTUAL_POSITION:
            self._set_position(to_int32(value))
        elif number == AP.TARGET_SPEED:
            self._abort_search()
            self._velocity_command = value
            self._start_velocity(value)
            self._params[number] = value
        elif number == AP.ENCODER_POSITION:
            self._set_encoder(value)
        else:
            self._params[number] = value
            self._parameter_side_effects(number)
        self._after_command()

    def _parameter_side_effects(self, number: int) -> None:
        if number in (AP.MAX_SPEED, AP.MAX_ACCELERATION, AP.VSTOP, AP.UNIT_MODE):
            if self._positioning and self._rfs is None:
                self._apply_limits(self._params[AP.MAX_SPEED])
            elif self._chip_mode() == RampMode.VELOCITY and self._rfs is None:
                self._set_dividers(self._top_speed(self._velocity_command),
                                   self._params[AP.MAX_ACCELERATION])
        elif number in (AP.LEFT_DISABLE, AP.RIGHT_DISABLE, AP.SOFT_STOP):
            self._write_ref_conf(self._chip_mode())
        elif number in (AP.SWAP_SWITCHES, AP.LEFT_POLARITY, AP.RIGHT_POLARITY):
            self.board.swap = bool(self._params[AP.SWAP_SWITCHES])
            self.board.invert_left = bool(self._params[AP.LEFT_POLARITY])
            self.board.invert_right = bool(self._params[AP.RIGHT_POLARITY])
            self._pins_changed()
        elif number == AP.MICROSTEPS:
            self._rebase_encoder()
            self.board.rescale(self.chip.motor_position, self._params[AP.MICROSTEPS])
            self._rebase_encoder()
        elif number in (AP.MAX_CURRENT, AP.STANDBY_CURRENT) and self._standby:
            self._emit(AxisEventKind.CURRENT_CHANGED, False)

    def _pins_changed(self) -> None:
        self.chip.set_pins(*self.board.pins(self.chip.motor_position))
        self._check_levels()
        if self._rfs is not None:
            self._rfs_step()

    # == the world =============================================================================

    @property
    def world(self) -> AxisWorld:
        return self.board.world

    def set_world(self, world: AxisWorld) -> None:
        """Replace the whole world of this axis (switch edges happen now)."""
        self._command()
        self._rebase_encoder()
        self.board.set_world(world)
        self._rebase_encoder()
        self._pins_changed()
        self._check_stall()
        self._after_command()

    def set_switch(self, name: str, switch: Switch | None) -> None:
        self._command()
        if switch is None:
            self.board.world.switches.pop(name, None)
        else:
            self.board.world.switches[name] = switch
        self.board.world_changed()
        self._pins_changed()
        self._after_command()

    def set_load(self, zones: list[LoadZone], free_load: int | None = None) -> None:
        self._command()
        self.board.world.load_zones = list(zones)
        if free_load is not None:
            self.board.world.free_load = free_load
        self.board.world_changed()
        self._check_stall()
        self._after_command()

    def set_encoder_slip(self, slip: float) -> None:
        if not 0.0 <= slip <= 1.0:
            raise ValueError("slip must be between 0 and 1")
        self._command()
        self._rebase_encoder()
        self.board.world.encoder_slip = slip
        self._after_command()

    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one raw datagram to the chip (None reads).

        Returns the chip's whole 32-bit answer as a signed 32-bit number: the status byte in
        bits 31..24 and the (zero-extended) register data in bits 23..0.  Writes bypass the
        firmware, as on the real module: the firmware only notices through what it reads.
        """
        self._command()
        answer = self.chip.spi(datagram(address, 0 if value is None else value, read=value is None))
        self._read_position()
        self._after_command()
        return to_int32(answer)

    def status(self) -> AxisStatus:
        """A snapshot for telemetry (MQTT bridge, tests); clears nothing."""
        self._sync()
        left, right, home = self._levels
        return AxisStatus(
            position=self._position, target=self._target, velocity=self._actual_speed(),
            mode=_MODE_NAMES[self._chip_mode()],
            position_reached=self._position == self._target,
            home_switch=home, left_switch=left, right_switch=right, load=self._load(),
            error_flags=self._errors, current=self.current, standby=self._standby,
            encoder_position=self._encoder_position(), reference_search=self._rfs_state,
            mechanical_position=self._mechanical(),
        )
