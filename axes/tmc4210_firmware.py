"""The TMC4210 core: the chip-specific half of the TMCL firmware, and the axis built on it.

:class:`TMC4210Driver` is what the module's microcontroller does with its TMC4210, and only
that: it talks to the chip through :meth:`TMC4210.spi` datagrams, converts speeds and
accelerations to register values (choosing PULSE_DIV/RAMP_DIV and computing PMUL/PDIV),
extends the chip's 24-bit position to 32 bits and feeds long moves to it in rolling pieces.
Everything a TMCL axis does whatever its chip (reference search, stallGuard, encoder, current,
events, time) is in :class:`axes.firmware.AxisFirmware`; :class:`TMC4210Axis` joins the two.
The modelling choices are explained in docs/motion.md.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

from axes.board import AxisBoard
from axes.firmware import AxisFirmware
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
from axes.world import AxisWorld
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP, ParamSpec
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS

log = logging.getLogger(__name__)

#: Telemetry's name for what the chip's ramp mode means to a TMCL host.
_MODE_NAMES = {RampMode.RAMP: "position", RampMode.SOFT: "position",
               RampMode.VELOCITY: "velocity", RampMode.HOLD: "hold"}
#: Rolling targets: a move farther than this is fed to the chip in pieces of this length.
ROLLING_SPAN = 1 << 22
ROLLING_REFRESH = 1 << 21
#: STEP pulse length 4 µs at 16 MHz and mot1r = 1 (the right switch belongs to the axis).
SMGP_FIRMWARE = MOT1R | (SMGP_POWER_ON & ~0xF00) | 3 << 8

STOP_FLAG = 1 << Irq.STOP
STOP_MASK = STOP_FLAG << 8
#: The datagram that reads X_ACTUAL, the one the firmware sends most.
_READ_X_ACTUAL = datagram(Reg.X_ACTUAL, read=True)


class TMC4210Driver:
    """The firmware's TMC4210 routines for one axis (an :class:`axes.core.ChipDriver`)."""

    def __init__(self, index: int, params: Mapping[int, int], board: AxisBoard,
                 clock_hz: int = DEFAULT_CLOCK_HZ) -> None:
        self.index = index
        #: The axis parameters (the firmware's dict, read here, never written).
        self.params = params
        self.chip = TMC4210(clock_hz, board)
        #: AP 1: the 32-bit position, as of the last read of X_ACTUAL.
        self.position = 0
        self._x_last = 0  # last X_ACTUAL read (24 bit)
        self._chip_target = 0  # the X_TARGET the chip has now (24 bit)
        self._pulse_div = 0
        self._ramp_div = 0
        self._searching = False

    # == chip access ===========================================================================

    def _write(self, reg: int, data: int) -> None:
        self.chip.spi(datagram(reg, data))

    def _read(self, reg: int) -> int:
        return self.chip.spi(datagram(reg, read=True)) & MASK24

    def power_up(self) -> None:
        """What the firmware does at power-up (spec §8.2): outputs on, right switch wired.

        The int_stop interrupt is enabled so that the firmware learns of hard switch stops.
        """
        self._write(Reg.IF_CONFIGURATION, EN_SD)
        self._write(Reg.SMGP, SMGP_FIRMWARE)
        self._write(Reg.INTERRUPT, STOP_MASK)
        self._write_ref_conf(RampMode.VELOCITY)
        self._apply_limits(self.params[AP.MAX_SPEED])

    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147: one raw datagram (None reads); the chip's whole 32-bit answer.

        The status byte is in bits 31..24 and the register data in bits 23..0, as a signed
        32-bit number.  Writes bypass the firmware, as on the real module.
        """
        answer = self.chip.spi(datagram(address, 0 if value is None else value, read=value is None))
        self.read_position()
        return to_int32(answer)

    # == readings ==============================================================================

    def read_position(self) -> int:
        x = self.chip.spi(_READ_X_ACTUAL) & MASK24
        self.position = to_int32(self.position + sdiff24(x, self._x_last))
        self._x_last = x
        return self.position

    def _v_actual(self) -> int:
        return signed(self._read(Reg.V_ACTUAL), 12)

    def moving(self) -> bool:
        return self._v_actual() != 0

    def actual_speed(self) -> int:
        """AP 3: the speed now, in the axis's units (pps, or the chip's units in unit mode 0)."""
        v = self._v_actual()
        return -self._to_speed(-v) if v < 0 else self._to_speed(v)

    def levels(self) -> tuple[bool, bool, bool]:
        """Logical (left, right, home) switch levels as the chip reports them."""
        switches = self._read(Reg.REFERENCE_SWITCHES)
        return bool(switches & 2), bool(switches & 1), bool(switches & 8)

    def take_switch_stop(self) -> bool:
        """Whether a stop switch stopped the motor since the last call (clears the flag)."""
        if not self._read(Reg.INTERRUPT) & STOP_FLAG:
            return False
        self._write(Reg.INTERRUPT, STOP_MASK | STOP_FLAG)  # clear it, keep the mask
        return True

    def _mode(self) -> RampMode:
        return RampMode(self._read(Reg.REF_CONF_RAMP_MODE) & 3)

    def mode_name(self) -> str:
        return _MODE_NAMES[self._mode()]

    def in_velocity_mode(self) -> bool:
        return self._mode() == RampMode.VELOCITY

    def heading(self) -> int:
        """Direction of travel, or of the travel about to start (-1, 0, +1)."""
        v = self._v_actual()
        if v:
            return 1 if v > 0 else -1
        mode = self._mode()
        if mode == RampMode.VELOCITY:
            ahead = signed(self._read(Reg.V_TARGET), 12)
        elif mode in (RampMode.RAMP, RampMode.SOFT):
            ahead = sdiff24(self._chip_target, self._x_last)
        else:
            return 0
        return (ahead > 0) - (ahead < 0)

    # == units =================================================================================

    @property
    def _pps_units(self) -> bool:
        return self.params[AP.UNIT_MODE] == 1

    def _to_register(self, speed: int) -> int:
        if self._pps_units:
            return velocity_register(speed, self._pulse_div, self.chip.clock_hz)
        return min(abs(speed), V_REGISTER_MAX)

    def _to_speed(self, v: int) -> int:
        if self._pps_units:
            return round(step_rate(v, self._pulse_div, self.chip.clock_hz))
        return v

    def _set_dividers(self, top_speed: int, acceleration: int) -> None:
        """Choose PULSE_DIV for ``top_speed`` and RAMP_DIV/A_MAX/PMUL/PDIV for the acceleration.

        A running motor keeps its speed across a PULSE_DIV change: the firmware parks the
        chip in hold mode and rewrites V_ACTUAL on the new scale (dropping the fraction bits).
        """
        clock_hz = self.chip.clock_hz
        if self._pps_units:
            pulse_div = choose_pulse_div(top_speed, clock_hz)
            if pulse_div > self._pulse_div and self._v_actual():
                # A finer scale mid-move would round the running speed (its fraction bits
                # are lost in the rescale) and can cost a step of overshoot: a lower limit
                # runs on the present, coarser scale until the motor is at rest.
                pulse_div = self._pulse_div
            if abs(top_speed) > max_step_rate(0, clock_hz):
                log.warning("axis %d: %d pps is beyond the TMC4210 at %d Hz; running at %d pps",
                            self.index, top_speed, clock_hz, round(max_step_rate(0, clock_hz)))
            ramp_div, a_max = choose_ramp_div(acceleration, pulse_div, clock_hz)
        else:
            pulse_div, ramp_div = self._pulse_div, self._ramp_div
            a_max = min(acceleration, V_REGISTER_MAX)
        if pulse_div != self._pulse_div or ramp_div != self._ramp_div:
            v_actual = signed(self._read(Reg.V_ACTUAL), 12)
            mode = self._read(Reg.REF_CONF_RAMP_MODE) & 3
            if v_actual and pulse_div != self._pulse_div:
                rescaled = round(v_actual * 2.0 ** (pulse_div - self._pulse_div))
                rescaled = max(-V_REGISTER_MAX, min(V_REGISTER_MAX, rescaled))
                self._write_ref_conf(RampMode.HOLD)
                self._write(Reg.V_ACTUAL, rescaled & 0xFFF)
                if mode == RampMode.VELOCITY:
                    v_target = signed(self._read(Reg.V_TARGET), 12)
                    scaled_target = round(v_target * 2.0 ** (pulse_div - self._pulse_div))
                    self._write(Reg.V_TARGET, max(-2047, min(2047, scaled_target)) & 0xFFF)
            self._write(Reg.DIVIDERS, pulse_div << 12 | ramp_div << 8)
            self._write_ref_conf(RampMode(mode))
            self._pulse_div, self._ramp_div = pulse_div, ramp_div
        self._write(Reg.A_MAX, a_max)
        pair = pmul_pdiv(a_max, ramp_div, pulse_div) if a_max else (128, 0)
        if pair is None:
            pair = (255, 0) if a_max > 1 else (128, 13)
        self._write(Reg.PMUL_PDIV, pair[0] << 8 | pair[1])
        # V_MIN must allow the abrupt stop at the speed the chip arrives with (units.stop_speed).
        v_min = max(self._to_register(self.params[AP.VSTOP]), stop_speed(a_max, *pair))
        self._write(Reg.V_MIN, min(v_min, V_REGISTER_MAX))

    def _top_speed(self, requested: int) -> int:
        """Dividers must cover the requested speed and the speed the motor has right now."""
        return max(abs(requested), abs(self.actual_speed()))

    def _apply_limits(self, top_speed: int) -> None:
        self._set_dividers(self._top_speed(top_speed), self.params[AP.MAX_ACCELERATION])
        self._write(Reg.V_MAX, self._to_register(top_speed))

    def limits_changed(self, positioning: bool, velocity_command: int) -> None:
        """AP 4, 5, 20 or 255 changed: re-plan the move (or the rotation) in flight."""
        if positioning:
            self._apply_limits(self.params[AP.MAX_SPEED])
        elif self._mode() == RampMode.VELOCITY:
            self._set_dividers(self._top_speed(velocity_command), self.params[AP.MAX_ACCELERATION])

    # == switches ==============================================================================

    def _write_ref_conf(self, mode: RampMode) -> None:
        conf = mode
        if self._searching or self.params[AP.LEFT_DISABLE]:
            conf |= DISABLE_STOP_L
        if self._searching or self.params[AP.RIGHT_DISABLE]:
            conf |= DISABLE_STOP_R
        if self.params[AP.SOFT_STOP]:
            conf |= SOFT_STOP
        self._write(Reg.REF_CONF_RAMP_MODE, conf)

    def configure_stops(self, searching: bool) -> None:
        """Stop switches as AP 12/13/26 say; a reference search drives through them."""
        self._searching = searching
        self._write_ref_conf(self._mode())

    # == motion ================================================================================

    def start_velocity(self, speed: int) -> None:
        self._set_dividers(self._top_speed(speed), self.params[AP.MAX_ACCELERATION])
        register = self._to_register(speed)
        self._write(Reg.V_MAX, register)
        self._write(Reg.V_TARGET, (register if speed >= 0 else -register) & 0xFFF)
        self._write_ref_conf(RampMode.VELOCITY)

    def start_positioning(self, target: int, top_speed: int) -> None:
        self._set_dividers(self._top_speed(top_speed), self.params[AP.MAX_ACCELERATION])
        self._write(Reg.V_MAX, self._to_register(top_speed))
        self._feed_target(target)
        self._write_ref_conf(RampMode.RAMP)

    def _feed_target(self, target: int) -> None:
        """Write X_TARGET; a move beyond the 24-bit range goes in rolling pieces."""
        remaining = target - self.position
        if abs(remaining) > ROLLING_SPAN:
            remaining = ROLLING_SPAN if remaining > 0 else -ROLLING_SPAN
        self._chip_target = (self._x_last + remaining) & MASK24
        self._write(Reg.X_TARGET, self._chip_target)

    def _chip_goal(self) -> int:
        """Where the chip is headed now, as a 32-bit position."""
        return to_int32(self.position + sdiff24(self._chip_target, self._x_last))

    def continue_move(self, target: int) -> None:
        """At a notable instant of a move to ``target``: hand the chip the next rolling piece."""
        if (self._chip_goal() != target
                and abs(sdiff24(self._chip_target, self._x_last)) <= ROLLING_REFRESH):
            self._feed_target(target)

    def refill_mark(self, target: int) -> int | None:
        """The motor position at which a long move to ``target`` needs its next piece."""
        ahead = sdiff24(self._chip_target, self._x_last)
        if abs(ahead) > ROLLING_REFRESH and target != to_int32(self.position + ahead):
            step = 1 if ahead > 0 else -1
            return self.chip.motor_position + ahead - step * ROLLING_REFRESH
        return None

    def ramp_stop(self) -> None:
        """MST: velocity mode, target speed 0."""
        self._write(Reg.V_TARGET, 0)
        self._write_ref_conf(RampMode.VELOCITY)

    def hard_stop(self) -> None:
        """Stop within one tick: hold mode, V_ACTUAL := 0, then velocity mode at speed 0."""
        self._write_ref_conf(RampMode.HOLD)
        self._write(Reg.V_ACTUAL, 0)
        self._write(Reg.V_TARGET, 0)
        self._write_ref_conf(RampMode.VELOCITY)

    def set_position(self, value: int) -> bool:
        """AP 1 write, following the datasheet: never rewrite X_ACTUAL in ramp/soft mode.

        Returns True if a move in flight was turned into a ramped stop.
        """
        mode = self._mode()
        positioning = mode in (RampMode.RAMP, RampMode.SOFT)
        if positioning:
            v_actual = signed(self._read(Reg.V_ACTUAL), 12)
            self._write(Reg.V_TARGET, v_actual & 0xFFF)
            self._write_ref_conf(RampMode.VELOCITY)
        x = value & MASK24
        self._write(Reg.X_ACTUAL, x)
        self._write(Reg.X_TARGET, x)
        self._x_last = self._chip_target = x
        self.position = value
        if not positioning:
            return False
        if self._v_actual() == 0:
            self._write_ref_conf(RampMode.RAMP)
            return False
        self._write(Reg.V_TARGET, 0)  # a move in flight ends with a ramped stop
        return True


class TMC4210Axis(AxisFirmware):
    """One TMCM-6212 axis on a TMC4210: the TMCL firmware layer over the TMC4210 driver."""

    def __init__(self, index: int, clock_hz: int = DEFAULT_CLOCK_HZ,
                 world: AxisWorld | None = None,
                 parameters: Mapping[int, ParamSpec] = AXIS_PARAMETERS) -> None:
        super().__init__(index, parameters, world,
                         lambda params, board: TMC4210Driver(index, params, board, clock_hz))
