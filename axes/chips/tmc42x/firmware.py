"""The firmware's routines for one motor of a TMC42x chip (TMC4210 or TMC429), shared by both.

The TMC4210 is a one-motor cut of the TMC429 (``axes/chips/tmc42x/engine.py``): the sixteen axis registers
of a motor and their law (units, PULSE_DIV/RAMP_DIV, PMUL/PDIV, V_MIN, the 24-bit position)
are the same, so is what the firmware does with them.  :class:`TMC42xDriver` is that common
half of an :class:`axes.core.ChipDriver`; a chip's driver adds where its motor's registers
are (``motor << 4 | IDX`` on the TMC429, IDX on the TMC4210), how the chip is set up at
power-up and how its switch register is laid out (``axes/chips/tmc42x/tmc4210_firmware.py``,
``axes/chips/tmc42x/tmc429_firmware.py``).  It talks to the chip through SPI datagrams only.

Two unit systems, chosen by the module's parameter table (docs/motion.md, "Units"):

* pps (AP 255 = 1, the TMCM-6212's default): the firmware converts pps and pps² to register
  values and chooses PULSE_DIV and RAMP_DIV itself;
* register units (AP 255 = 0, and the TMC429 modules, which have no AP 255): speeds and
  accelerations are the chip's own values, PULSE_DIV and RAMP_DIV are AP 154 / AP 153 where
  the table has them (else they stay as they are), V_MIN is at least AP 130.

Either way V_MIN is raised to what the chip needs to stop on the target
(:func:`axes.chips.tmc42x.units.stop_speed`), and PMUL/PDIV follow A_MAX
(:func:`axes.chips.tmc42x.units.pmul_pdiv`).
"""

from __future__ import annotations

import logging
from abc import abstractmethod
from collections.abc import Callable, Iterable, Mapping
from math import isqrt
from typing import cast

from axes.board import AxisBoard
from axes.chips.tmc42x.engine import MotorEngine
from axes.chips.tmc42x.law import MotorLaw
from axes.chips.tmc42x.registers import (
    DISABLE_STOP_L,
    DISABLE_STOP_R,
    DISTANCE_LIMIT,
    HALF24,
    MASK24,
    MODE_VELOCITY,
    SOFT_STOP,
    Irq,
    RampMode,
    Reg,
    datagram,
    sdiff24,
    signed,
)
from axes.chips.tmc42x.units import (
    DIVIDER_MAX,
    V_REGISTER_MAX,
    choose_pulse_div,
    choose_ramp_div,
    max_step_rate,
    pmul_pdiv,
    step_rate,
    stop_speed,
    velocity_register,
)
from axes.core import ChipDriver, ChipModel
from tmcl_spec.numbers import INT32_MAX, INT32_MIN, NS_PER_S, to_int32, to_signed
from tmcl_spec.parameters import AP

log = logging.getLogger(__name__)

#: Telemetry's name for what the chip's ramp mode means to a TMCL host.
MODE_NAMES = {RampMode.RAMP: "position", RampMode.SOFT: "position",
              RampMode.VELOCITY: "velocity", RampMode.HOLD: "hold"}
#: Rolling targets: a move farther than this is fed to the chip in pieces of this length.
ROLLING_SPAN = 1 << 22
ROLLING_REFRESH = 1 << 21

#: Steps a look-ahead may let pass between two reads of X_ACTUAL: a quarter of the 24-bit
#: range, so the difference of two reads is never ambiguous (sdiff24 is, from 2**23 on).
HORIZON_STEPS = 1 << 22
#: The longest look-ahead (the TMC4361A core's: nothing in the firmware needs a shorter one).
HORIZON_MAX_NS = 60 * NS_PER_S

STOP_FLAG = 1 << Irq.STOP
STOP_MASK = STOP_FLAG << 8


def _never_turns(later: ChipModel) -> bool:
    """TMC42xDriver.positioning_speed's test where the speed only falls up to the target."""
    return False


class TMC42xDriver(ChipDriver):
    """The firmware's routines for one TMC42x motor (the common half of a ChipDriver).

    Subclasses pass the chip (a TMC42x :class:`MotorEngine`) and the motor, and implement
    :meth:`setup_chip` (global registers at power-up) and :meth:`levels` (the chip's switch
    register).
    """

    chip: MotorEngine

    #: Name of the chip in log messages.
    chip_name = "TMC42x"
    #: Chip-specific parameters the firmware reads from the chip (AxisFirmware asks
    #: :meth:`read_parameter` for them): actual acceleration, ramp mode.
    live_parameters = frozenset({AP.ACTUAL_ACCELERATION, AP.RAMP_MODE})

    def __init__(self, index: int, params: Mapping[int, int], board: AxisBoard, chip: MotorEngine,
                 motor: int = 0) -> None:
        self.index = index
        #: The axis parameters (the firmware's dict, read here, never written).
        self.params = params
        self.board = board
        self.chip = chip
        #: Which motor of the chip: its registers are at ``motor << 4 | IDX``.
        self.motor = motor
        self._base = motor << 4
        self._read_x_actual = datagram(self._base | Reg.X_ACTUAL, read=True)
        #: AP 1: the 32-bit position, as of the last read of X_ACTUAL.
        self.position = 0
        self._x_last = 0  # last X_ACTUAL read (24 bit)
        self._chip_target = 0  # the X_TARGET the chip has now (24 bit)
        self._pulse_div = 0
        self._ramp_div = 0
        self._searching = False
        self._dx_ref_tolerance = 0  # DX_REF_TOLERANCE as written (power-on 0)

    # == chip access ===========================================================================

    def _write(self, idx: int, data: int) -> None:
        """Write axis register ``idx`` of this driver's motor."""
        self.chip.spi(datagram(self._base | idx, data))

    def _read(self, idx: int) -> int:
        return self.chip.spi_data(datagram(self._base | idx, read=True))

    def _write_global(self, address: int, data: int) -> None:
        self.chip.spi(datagram(address, data))

    def _read_global(self, address: int) -> int:
        return self.chip.spi_data(datagram(address, read=True))

    @abstractmethod
    def setup_chip(self) -> None:
        """The chip's global registers as the firmware sets them at power-up."""

    def horizon_ns(self) -> int:
        """As far as HORIZON_STEPS at the fastest speed of the chip's PULSE_DIV (the look-ahead
        copy runs without writes: its divider stays): 8 s at PULSE_DIV 0 and 16 MHz, a minute
        from PULSE_DIV 3 on.  Fewer look-aheads per move (each costs a copy of the chip and the
        firmware's reaction), the same events."""
        chip = self.chip
        rate = max_step_rate(chip.pulse_div, chip.clock_hz)
        return min(HORIZON_MAX_NS, int(HORIZON_STEPS * NS_PER_S / rate))

    def power_up(self) -> None:
        """Set up the chip, enable the int_stop interrupt (the firmware learns of hard switch
        stops from it), configure the switches and the speed limits."""
        self.setup_chip()
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
        x = self.chip.spi_data(self._read_x_actual)
        # sdiff24(x, self._x_last) in line, and to_int32 only on a wrap: a program's GAP 1
        # comes here every time
        position = self.position + ((x - self._x_last + HALF24) & MASK24) - HALF24
        if not INT32_MIN <= position <= INT32_MAX:
            position = to_int32(position)
        self.position = position
        self._x_last = x
        return position

    def readings_at(self, ticks: Iterable[int]) -> tuple[list[int], list[int]]:
        """AP 1 and AP 3 at each of the first ``ticks`` the engine reaches at a standing
        velocity or across a full-A_MAX slew (:meth:`MotorEngine.readings`), read as
        :meth:`read_position` and :meth:`actual_speed` read them, where a read changes
        nothing else (:meth:`MotorEngine.reads_are_quiet`); the last position counts as
        read."""
        chip = self.chip
        if not chip.reads_are_quiet():
            return [], []
        xs, v_bits = chip.readings(ticks)
        if not xs:
            return [], []
        speeds = []
        bits = speed = -1
        for read in v_bits:  # (a ramp's speeds repeat: one conversion per distinct one)
            if read != bits:
                bits, speed = read, self._speed_of(signed(read, 12))
            speeds.append(speed)
        return self._counted(xs), speeds

    def _counted(self, xs: list[int]) -> list[int]:
        """AP 1 after each of the X_ACTUAL reads ``xs`` in turn (:meth:`read_position`'s
        32-bit count across 24-bit wraps), the last one kept as read."""
        position, last = self.position, self._x_last
        positions = []
        for x in xs:
            position += ((x - last + HALF24) & MASK24) - HALF24
            if not INT32_MIN <= position <= INT32_MAX:
                position = to_int32(position)
            positions.append(position)
            last = x
        self.position, self._x_last = position, last
        return positions

    def _v_actual(self) -> int:
        return signed(self._read(Reg.V_ACTUAL), 12)

    def moving(self) -> bool:
        return self._v_actual() != 0

    def actual_speed(self) -> int:
        """AP 3: the speed now, in the axis's units (pps, or the chip's units in unit mode 0)."""
        return self._speed_of(self._v_actual())

    def _speed_of(self, v: int) -> int:
        """AP 3 for the signed V_ACTUAL ``v`` (the conversion is of the magnitude)."""
        return -self._to_speed(-v) if v < 0 else self._to_speed(v)

    def positioning_speed(self, start: ChipModel) -> tuple[Callable[[ChipModel], bool],
                                                           int] | None:
        """A ramp or soft move's V_ACTUAL heads for the positioning curve (F8): while it is
        below the curve's target (towards the target's side) a ramp tick only raises it, and
        once it has reached it, it only falls, for the curve falls as the distance does, until
        the position first meets the target.  No promise with a stop switch in play (a hard
        stop or a soft one would take the speed elsewhere)."""
        motor = cast(MotorLaw, start)
        if motor.mode >= MODE_VELOCITY or motor._switch_in_play(1) or motor._switch_in_play(-1):
            return None
        distance = sdiff24(motor.x_target, motor.x_actual)
        if distance == 0:
            return None
        toward = 1 if distance > 0 else -1

        def at_curve(later: ChipModel) -> bool:
            law = cast(MotorLaw, later)
            return toward * law.v >= toward * (law._ramp_target()[0] << 8)

        if at_curve(start):
            return _never_turns, distance  # falls (rises, leftwards) until the target
        return at_curve, distance

    def levels(self) -> tuple[bool, bool, bool]:
        """Logical (left, right, home) switch levels as the chip reports them."""
        raise NotImplementedError

    def take_switch_stop(self) -> bool:
        """Whether a stop switch stopped the motor since the last call (clears the flag)."""
        if not self._read(Reg.INTERRUPT) & STOP_FLAG:
            return False
        self._write(Reg.INTERRUPT, STOP_MASK | STOP_FLAG)  # clear it, keep the mask
        return True

    def _mode(self) -> RampMode:
        return RampMode(self._read(Reg.REF_CONF_RAMP_MODE) & 3)

    def mode_name(self) -> str:
        return MODE_NAMES[self._mode()]

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

    def read_parameter(self, number: int) -> int:
        """A :attr:`live_parameters` value from the chip: AP 135 (|A_ACTUAL|), AP 138 (mode)."""
        if number == AP.ACTUAL_ACCELERATION:
            return abs(signed(self._read(Reg.A_ACTUAL), 12))
        return int(self._mode())

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

    def _register_dividers(self) -> tuple[int, int]:
        """Register units: PULSE_DIV and RAMP_DIV from AP 154 / AP 153 where the table has
        them (the TMC429 modules), else as they are."""
        pulse_div = self.params.get(AP.PULSE_DIVISOR)
        ramp_div = self.params.get(AP.RAMP_DIVISOR)
        return (self._pulse_div if pulse_div is None else min(pulse_div, DIVIDER_MAX),
                self._ramp_div if ramp_div is None else min(ramp_div, DIVIDER_MAX))

    def _set_dividers(self, top_speed: int, acceleration: int) -> None:
        """Choose PULSE_DIV for ``top_speed`` and RAMP_DIV/A_MAX/PMUL/PDIV for the acceleration.

        In pps units a running motor keeps its speed across a PULSE_DIV change: the firmware
        parks the chip in hold mode and rewrites V_ACTUAL on the new scale (dropping the
        fraction bits).  In register units the register values are the speeds: they stay.
        """
        if self._pps_units:
            pulse_div = self._pps_pulse_div(top_speed, acceleration)
            ramp_div, a_max = choose_ramp_div(acceleration, pulse_div, self.chip.clock_hz)
        else:
            pulse_div, ramp_div = self._register_dividers()
            a_max = min(acceleration, V_REGISTER_MAX)
        if pulse_div != self._pulse_div or ramp_div != self._ramp_div:
            self._write_dividers(pulse_div, ramp_div)
        self._write(Reg.A_MAX, a_max)
        pair = pmul_pdiv(a_max, ramp_div, pulse_div) if a_max else (128, 0)
        if pair is None:
            pair = (255, 0) if a_max > 1 else (128, 13)
        self._write(Reg.PMUL_PDIV, pair[0] << 8 | pair[1])
        # V_MIN must allow the abrupt stop at the speed the chip arrives with (units.stop_speed).
        # (``top_speed`` covers the speed the motor has now: _top_speed)
        v_top = self._to_register(top_speed)
        v_min = max(self._user_v_min(), stop_speed(a_max, *pair, v_top, ramp_div, pulse_div))
        self._write(Reg.V_MIN, min(v_min, V_REGISTER_MAX))

    def _pps_pulse_div(self, top_speed: int, acceleration: int) -> int:
        """PULSE_DIV for ``top_speed`` pps (pps units), or the present one where a running
        motor must keep it."""
        clock_hz = self.chip.clock_hz
        pulse_div = choose_pulse_div(top_speed, clock_hz)
        if pulse_div != self._pulse_div and self._v_actual() and (
                pulse_div > self._pulse_div
                or (self._mode() in (RampMode.RAMP, RampMode.SOFT)
                    and not self._coarser_is_safe(pulse_div, acceleration))):
            # A finer scale mid-move would round the running speed (its fraction bits
            # are lost in the rescale) and can cost a step of overshoot: a lower limit
            # runs on the present, coarser scale until the motor is at rest.  A move to
            # a target takes a coarser one (a higher limit) on the fly where the running
            # speed, rescaled, is under the new braking curve; above it (raised while
            # braking) it would overshoot by a few steps: the move keeps its scale.
            pulse_div = self._pulse_div
        if abs(top_speed) > max_step_rate(0, clock_hz):
            log.warning("axis %d: %d pps is beyond the %s at %d Hz; running at %d pps",
                        self.index, top_speed, self.chip_name, clock_hz,
                        round(max_step_rate(0, clock_hz)))
        return pulse_div

    def _write_dividers(self, pulse_div: int, ramp_div: int) -> None:
        """New PULSE_DIV and RAMP_DIV; in pps units a running motor's V_ACTUAL (and in
        velocity mode V_TARGET) rescaled to the new PULSE_DIV, written in hold mode."""
        v_actual = signed(self._read(Reg.V_ACTUAL), 12)
        mode = self._read(Reg.REF_CONF_RAMP_MODE) & 3
        if self._pps_units and v_actual and pulse_div != self._pulse_div:
            scale = 2.0 ** (pulse_div - self._pulse_div)
            rescaled = max(-V_REGISTER_MAX, min(V_REGISTER_MAX, round(v_actual * scale)))
            self._write_ref_conf(RampMode.HOLD)
            self._write(Reg.V_ACTUAL, rescaled & 0xFFF)
            if mode == RampMode.VELOCITY:
                scaled_target = round(signed(self._read(Reg.V_TARGET), 12) * scale)
                self._write(Reg.V_TARGET, max(-2047, min(2047, scaled_target)) & 0xFFF)
        self._write(Reg.DIVIDERS, pulse_div << 12 | ramp_div << 8)
        self._write_ref_conf(RampMode(mode))
        self._pulse_div, self._ramp_div = pulse_div, ramp_div

    def _coarser_is_safe(self, pulse_div: int, acceleration: int) -> bool:
        """Whether a move in flight may go on at the coarser ``pulse_div`` (a higher AP 4 than
        the present scale reaches): the running speed, rescaled, must be at or under the new
        braking curve one ramp period ahead of where the motor is, heading for the target.
        Then the chip brakes in time as on any move; above it (a speed raised while braking)
        it would pass the target by a few steps, so the move keeps its scale: its speed is the
        curve's anyway, below the old limit (docs/motion.md, "On the fly")."""
        v_actual = signed(self._read(Reg.V_ACTUAL), 12)
        ahead = sdiff24(self._chip_target, self._x_last)
        if ahead == 0 or (ahead > 0) != (v_actual > 0):
            return False  # at the target or moving away from it: braking
        ramp_div, a_max = choose_ramp_div(acceleration, pulse_div, self.chip.clock_hz)
        pair = pmul_pdiv(a_max, ramp_div, pulse_div) if a_max else None
        if pair is None:
            return False
        pmul, pdiv = pair
        speed = round(abs(v_actual) * 2.0 ** (pulse_div - self._pulse_div))
        pulses = 1 << (ramp_div - pulse_div) if ramp_div > pulse_div else 1
        distance = min(abs(ahead) - -(-speed * pulses // 2048), DISTANCE_LIMIT)
        if distance <= 0:
            return False
        if self._mode() == RampMode.SOFT:
            return speed <= (pmul * distance) >> (3 + pdiv)
        return speed <= isqrt((pmul * distance << 8) >> pdiv)

    def _user_v_min(self) -> int:
        """The V_MIN the parameters ask for: AP 20 (VSTOP, in the axis's units) or AP 130
        (minimum speed, register units), whichever the table has."""
        return max(self._to_register(self.params[AP.VSTOP]), self.params.get(AP.MINIMUM_SPEED, 0))

    def _top_speed(self, requested: int) -> int:
        """Dividers must cover the requested speed and the speed the motor has right now."""
        return max(abs(requested), abs(self.actual_speed()))

    def _apply_limits(self, top_speed: int) -> None:
        self._set_dividers(self._top_speed(top_speed), self.params[AP.MAX_ACCELERATION])
        self._write(Reg.V_MAX, self._to_register(top_speed))

    def limits_changed(self, positioning: bool, velocity_command: int) -> None:
        """A speed, acceleration, divider or unit parameter changed: re-plan what runs."""
        if positioning:
            self._apply_limits(self.params[AP.MAX_SPEED])
        elif self._mode() == RampMode.VELOCITY:
            self._set_dividers(self._top_speed(velocity_command), self.params[AP.MAX_ACCELERATION])

    # == switches ==============================================================================

    def _soft_stop(self) -> bool:
        return bool(self.params[AP.SOFT_STOP] or self.params.get(AP.SOFT_STOP_FLAG, 0))

    def _write_ref_conf(self, mode: RampMode) -> None:
        conf: int = mode
        if self._searching or self.params[AP.LEFT_DISABLE]:
            conf |= DISABLE_STOP_L
        if self._searching or self.params[AP.RIGHT_DISABLE]:
            conf |= DISABLE_STOP_R
        if self._soft_stop():
            conf |= SOFT_STOP
        self._write(Reg.REF_CONF_RAMP_MODE, conf)

    def configure_stops(self, searching: bool) -> None:
        """Stop switches as AP 12/13 and the soft-stop parameter say; a reference search
        drives through them.  AP 141 (where the table has it) is the switch tolerance."""
        self._searching = searching
        tolerance = self.params.get(AP.REFERENCE_SWITCH_TOLERANCE, 0)
        if tolerance != self._dx_ref_tolerance:
            self._write(Reg.DX_REF_TOLERANCE, tolerance)
            self._dx_ref_tolerance = tolerance
        self._write_ref_conf(self._mode())

    # == motion ================================================================================

    def _positioning_mode(self) -> RampMode:
        """Ramp mode of a move: soft if AP 138 asks for it (TMC429 modules), else ramp."""
        return RampMode.SOFT if self.params.get(AP.RAMP_MODE) == RampMode.SOFT else RampMode.RAMP

    def start_velocity(self, speed: int) -> None:
        self._set_dividers(self._top_speed(speed), self.params[AP.MAX_ACCELERATION])
        register = self._to_register(speed)
        self._write(Reg.V_MAX, register)
        self._write(Reg.V_TARGET, (register if speed >= 0 else -register) & 0xFFF)
        self._write_ref_conf(RampMode.VELOCITY)

    def start_positioning(self, target: int, top_speed: int) -> None:
        self._feed_target(target)  # first: a move in flight judges a new scale by it
        self._set_dividers(self._top_speed(top_speed), self.params[AP.MAX_ACCELERATION])
        self._write(Reg.V_MAX, self._to_register(top_speed))
        self._write_ref_conf(self._positioning_mode())

    def set_positioning_mode(self) -> None:
        """AP 138 changed during a move: ramp or soft from now on."""
        if self._mode() in (RampMode.RAMP, RampMode.SOFT):
            self._write_ref_conf(self._positioning_mode())

    def _feed_target(self, target: int) -> None:
        """Write X_TARGET; a move beyond the 24-bit range goes in rolling pieces.

        The way to the target is its 32-bit difference, as the firmware's int arithmetic
        gives it (the manual's MVP note): a target more than 2**31 - 1 steps away is reached
        the other way round, the shorter way across the wrap of the 32-bit position."""
        remaining = to_signed(target - self.position, self.position_bits)
        if abs(remaining) > ROLLING_SPAN:
            remaining = ROLLING_SPAN if remaining > 0 else -ROLLING_SPAN
        self._chip_target = (self._x_last + remaining) & MASK24
        self._write(Reg.X_TARGET, self._chip_target)

    def _chip_goal(self) -> int:
        """Where the chip is headed now, as a 32-bit position."""
        return to_signed(self.position + sdiff24(self._chip_target, self._x_last),
                         self.position_bits)

    def continue_move(self, target: int) -> None:
        """At a notable instant of a move to ``target``: hand the chip the next rolling piece."""
        if (self._chip_goal() != target
                and abs(sdiff24(self._chip_target, self._x_last)) <= ROLLING_REFRESH):
            self._feed_target(target)

    def refill_mark(self, target: int) -> int | None:
        """The motor position at which a long move to ``target`` needs its next piece."""
        ahead = sdiff24(self._chip_target, self._x_last)
        if abs(ahead) > ROLLING_REFRESH and target != to_signed(self.position + ahead,
                                                                  self.position_bits):
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
            self._write_ref_conf(mode)
            return False
        self._write(Reg.V_TARGET, 0)  # a move in flight ends with a ramped stop
        return True
