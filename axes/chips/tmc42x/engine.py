"""The motion core of the TMC42x family (TMC4210, TMC429): one motor's registers and motion.

The TMC4210 is a one-motor cut of the TMC429 (``shared/spec/tmc429.md`` §1): both chips have,
per motor, the same sixteen axis registers (IDX 0..15) and the same ramp and pulse generator.
:class:`MotorEngine` is that motor: the axis registers, the switch logic, the latch, the
interrupt flags, and the motion law of ``shared/spec/tmc4210.md`` §4.8.  A chip
(:class:`axes.chips.tmc42x.tmc4210.TMC4210`, :class:`axes.chips.tmc42x.tmc429.TMC429`) owns
the global registers and the SPI interface, and tells each engine how it is wired (see
"Wiring" on the class).

Motion follows the digest's reference model: a clk32 counter drives ramp ticks every
``2**RAMP_DIV`` and pulse ticks every ``2**PULSE_DIV`` clk32 periods, the velocity has 8
hidden fraction bits, and an 11-bit phase accumulator turns the integer part into steps.
The engine never walks single clk32 ticks: stretches where the velocity cannot change are
computed in closed form, and ramps run one *ramp tick* per loop iteration, with the pulses
in between counted arithmetically.  Either way the motor lands on exactly the positions, at
exactly the clk32 ticks, that a tick-by-tick run of the reference model gives
(``tests/axes/test_tmc4210.py`` and ``tests/axes/test_tmc429.py`` check this against
``tests/axes/reference_tmc4210.py``).

The engine knows nothing about seconds: time is a clk32 tick count.  Its pins (left and
right switch, home) are driven by a :class:`Board`, which also names the motor positions at
which the outside world changes so that the engine can stop there.
"""

from __future__ import annotations

import copy
from abc import abstractmethod
from enum import IntEnum
from math import isqrt
from typing import Self

from axes.core import Board, ChipModel, Stop
from axes.search import first_true

MASK24 = 0xFFFFFF
HALF24 = 1 << 23
#: The deceleration ramp is internally limited to 2**19 steps (datasheet).
DISTANCE_LIMIT = 1 << 19
DEFAULT_CLOCK_HZ = 16_000_000
#: clk32 ticks per simulated second are clock_hz / 32; this is 32 s in ns.
_NS_PER_32_TICKS = 32_000_000_000


class RampMode(IntEnum):
    RAMP = 0
    SOFT = 1
    VELOCITY = 2
    HOLD = 3


class MotorReg(IntEnum):
    """The axis registers of one motor: IDX, the low four bits of the 7-bit address."""

    X_TARGET = 0x0
    X_ACTUAL = 0x1
    V_MIN = 0x2
    V_MAX = 0x3
    V_TARGET = 0x4
    V_ACTUAL = 0x5
    A_MAX = 0x6
    A_ACTUAL = 0x7
    A_THRESHOLD = 0x8  # TMC429: IS_AGTAT / IS_ALEAT / IS_V0 / A_THRESHOLD (current scaling)
    PMUL_PDIV = 0x9
    REF_CONF_RAMP_MODE = 0xA
    INTERRUPT = 0xB
    DIVIDERS = 0xC
    DX_REF_TOLERANCE = 0xD
    X_LATCHED = 0xE
    USTEP_COUNT = 0xF


class GlobalReg(IntEnum):
    """The family's global registers (SMDA = %11): the 7-bit address ``%011 JDX``; the TMC4210
    has them at the same addresses."""

    DATAGRAM_LOW = 0x30
    DATAGRAM_HIGH = 0x31
    COVER_POS_LEN = 0x32
    COVER_DATAGRAM = 0x33
    IF_CONFIGURATION = 0x34
    POS_COMP = 0x35
    POS_COMP_INT = 0x36
    POWER_DOWN = 0x38
    TYPE_VERSION = 0x39
    REFERENCE_SWITCHES = 0x3E
    SMGP = 0x3F


#: Axis registers that are plain storage: attribute and the bits that exist (tmc4210.md §3.2).
#: The A_THRESHOLD slot's mask is the chip's (``MotorEngine.a_threshold_mask``).
MOTOR_PLAIN_REGISTERS: dict[int, tuple[str, int]] = {
    MotorReg.X_TARGET: ("x_target", MASK24),
    MotorReg.X_ACTUAL: ("x_actual", MASK24),
    MotorReg.V_MIN: ("v_min", 0x7FF),
    MotorReg.V_MAX: ("v_max", 0x7FF),
    MotorReg.A_MAX: ("a_max", 0x7FF),
    MotorReg.DX_REF_TOLERANCE: ("dx_ref_tolerance", 0xFFF),
    MotorReg.USTEP_COUNT: ("ustep_count", 0xFF),
}


#: The modes as plain ints, for the hot paths: an IntEnum member looked up through its class
#: costs about 0.1 us in CPython 3.11, ten times a global int (the two compare equal).
_RAMP = int(RampMode.RAMP)
_SOFT = int(RampMode.SOFT)
_VELOCITY = int(RampMode.VELOCITY)  # modes below it position (ramp, soft)
_HOLD = int(RampMode.HOLD)


class Irq(IntEnum):
    """Interrupt flag bits (INTERRUPT register bits 7..0; the mask is the same, shifted by 8)."""

    POS_END = 0
    REF_WRONG = 1
    REF_MISS = 2
    STOP = 3
    STOP_LEFT_LOW = 4
    STOP_RIGHT_LOW = 5
    STOP_LEFT_HIGH = 6
    STOP_RIGHT_HIGH = 7


_REF_MISS = int(Irq.REF_MISS)  # a plain int for the hot path (see _RAMP)


# Bits of the REF_CONF / RAMP_MODE register.
DISABLE_STOP_L = 1 << 8
DISABLE_STOP_R = 1 << 9
SOFT_STOP = 1 << 10
REF_RNL = 1 << 11
LATCH_PENDING = 1 << 16


def sdiff24(a: int, b: int) -> int:
    """``a - b`` as a signed 24-bit difference (the chip's direction rule)."""
    return ((a - b + HALF24) & MASK24) - HALF24


def signed(value: int, bits: int) -> int:
    sign = 1 << (bits - 1)
    value &= (1 << bits) - 1
    return value - (sign << 1) if value & sign else value


def floor_sum(n: int, m: int, a: int, b: int) -> int:
    """Sum of (a*i + b) // m for i in 0..n-1 (a, b >= 0), in O(log) steps."""
    total = 0
    while True:
        if a >= m:
            total += (n - 1) * n // 2 * (a // m)
            a %= m
        if b >= m:
            total += n * (b // m)
            b %= m
        y_max = a * n + b
        if y_max < m:
            return total
        n, b, m, a = y_max // m, y_max % m, a, m


def datagram(address: int, data: int = 0, read: bool = False) -> int:
    """Build a 32-bit host datagram for a 7-bit register (or RAM) address."""
    return (address & 0x7F) << 25 | int(read) << 24 | (data & MASK24)


class MotorEngine(ChipModel):
    """One motor of a TMC42x chip: axis registers, switches, latch, interrupts and motion.

    The :class:`axes.core.ChipModel` of a TMC42x axis: a chip (the TMC4210) or a motor of
    one (:class:`axes.chips.tmc42x.tmc429.TMC429Motor`) adds SPI (:meth:`spi`,
    :meth:`spi_data`) and what a look-ahead copy is (:meth:`clone`, :meth:`adopt`).

    Wiring: the chip that owns the engine sets these plain attributes whenever its global
    registers change them (they are read on the engine's hot paths):

    * ``steps_out``: steps reach the motor (and ``motor_position``): the TMC4210 with
      ``en_sd = 1``; the TMC429 in Step/Dir mode, or in SPI mode for a motor in the chain.
    * ``inv_ref``: the chip inverts all switch inputs.
    * ``left_wired`` / ``right_wired``: the chip's switch layout gives this motor a left /
      right stop switch (an unwired switch is never active).
    * ``pos_comp_on``: the chip compares this motor's X_ACTUAL with ``pos_comp`` and sets
      ``pos_comp_flag`` on a match (position-compare mask set and this motor selected).
    * ``powered_down``: the chip's clocks stand still until the next SPI frame.
    """

    #: Bits of the IDX %1000 register that exist (the chip narrows or widens it).
    a_threshold_mask = 0x777FFF
    #: Steps that reached the motor, unwrapped (a plain attribute: the engine moves it).
    motor_position: int

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, board: Board | None = None) -> None:
        if clock_hz <= 0:
            raise ValueError("clock frequency must be positive")
        self.clock_hz = clock_hz
        self.board = board
        self.t = 0  # clk32 ticks fully processed
        self.motor_position = 0  # steps that reached the motor, unwrapped
        self.steps_out = False
        self.inv_ref = False
        self.left_wired = True
        self.right_wired = False
        self.pos_comp_on = False
        self.pos_comp = 0
        self.pos_comp_flag = False
        self.powered_down = False
        self.reset_motor()

    def reset_motor(self) -> None:
        """The axis registers' power-on values (all 0) and an idle ramp generator."""
        self.x_target = 0
        self.x_actual = 0
        self.v_min = 0
        self.v_max = 0
        self.v_target = 0  # signed 12-bit register
        self.v = 0  # signed internal velocity in 1/256 velocity units
        self.a_max = 0
        self.a_actual = 0
        self.a_threshold = 0
        self.pmul = 128
        self.pdiv = 0
        self.ref_conf = 0  # bits 11..8 of the register, as stored (mode kept apart)
        self.mode = RampMode.RAMP
        self.latch_pending = False
        self.int_mask = 0
        self.int_flags = 0
        self.pulse_div = 0
        self.ramp_div = 0
        self.usrs = 0
        self.dx_ref_tolerance = 0
        self.x_latched = 0
        self.ustep_count = 0
        self.acc = 0
        self.ramp_next = self.t + 1
        self._work = 1  # loop iterations the last _fast took (run's work budget)
        self.ref_l = self.ref_r = self.gp_in = False  # electrical pin levels
        self._refresh_pins()

    @abstractmethod
    def spi_data(self, frame: int) -> int:
        """``spi(frame) & MASK24``, the data bits of the answer: the firmware's reads ignore
        the status byte, so a chip may skip sampling it (the frame acts the same)."""

    def steps_reach_motor(self) -> bool:
        return self.steps_out

    def at_rest(self) -> bool:
        """Stopped, and no ramp tick will start the motor again."""
        return self.v == 0 and self._steady_steps() == -1

    def clone(self) -> Self:
        """An independent copy (for looking ahead without disturbing this motor)."""
        return copy.copy(self)

    # == time ==================================================================================

    def ticks_at(self, t_ns: int) -> int:
        """clk32 ticks that have happened by simulated time ``t_ns``."""
        return t_ns * self.clock_hz // _NS_PER_32_TICKS

    def ns_at(self, ticks: int) -> int:
        """The simulated time (ns, rounded up) of clk32 tick ``ticks``."""
        return -(-ticks * _NS_PER_32_TICKS // self.clock_hz)

    # == derived state =========================================================================

    @property
    def v_actual(self) -> int:
        """V_ACTUAL: the integer part of the velocity, truncated toward zero."""
        return (self.v >> 8) if self.v >= 0 else -((-self.v) >> 8)

    def _active(self, level: bool) -> bool:
        return level != self.inv_ref

    @property
    def left_active(self) -> bool:
        return self.left_wired and self._active(self.ref_l)

    @property
    def right_active(self) -> bool:
        return self.right_wired and self._active(self.ref_r)

    @property
    def at_target(self) -> bool:
        """xEQt: X_ACTUAL == X_TARGET."""
        return self.x_actual == self.x_target

    # == axis registers ========================================================================

    def read_motor(self, idx: int) -> int:
        """The 24 data bits a read of axis register ``idx`` returns (zero-extended)."""
        plain = MOTOR_PLAIN_REGISTERS.get(idx)
        if plain is not None:
            return getattr(self, plain[0])
        match idx:
            case MotorReg.V_TARGET:
                return self.v_target & 0xFFF
            case MotorReg.V_ACTUAL:
                return self.v_actual & 0xFFF
            case MotorReg.A_ACTUAL:
                return self.a_actual & 0xFFF
            case MotorReg.A_THRESHOLD:
                return self.a_threshold
            case MotorReg.PMUL_PDIV:
                return self.pmul << 8 | self.pdiv
            case MotorReg.REF_CONF_RAMP_MODE:
                return self.latch_pending << 16 | self.ref_conf | self.mode
            case MotorReg.INTERRUPT:
                return self.int_mask << 8 | self.int_flags
            case MotorReg.DIVIDERS:
                return self.pulse_div << 12 | self.ramp_div << 8 | self.usrs
            case MotorReg.X_LATCHED:
                return self.x_latched
        return 0

    def write_motor(self, idx: int, data: int) -> None:
        """A write of ``data`` (24 bits) to axis register ``idx``, with its side effects."""
        plain = MOTOR_PLAIN_REGISTERS.get(idx)
        if plain is not None:
            setattr(self, plain[0], data & plain[1])
            return
        match idx:
            case MotorReg.V_TARGET:
                self.v_target = signed(data, 12)
            case MotorReg.V_ACTUAL:
                if self.mode == RampMode.HOLD:
                    self.v = signed(data, 12) << 8
            case MotorReg.A_THRESHOLD:
                self.a_threshold = data & self.a_threshold_mask
            case MotorReg.PMUL_PDIV:
                self.pmul = (data >> 8 & 0xFF) | 0x80
                self.pdiv = data & 0xF
            case MotorReg.REF_CONF_RAMP_MODE:
                self.ref_conf = data & 0xF00
                self.mode = RampMode(data & 3)
            case MotorReg.INTERRUPT:
                self.int_mask = data >> 8 & 0xFF
                self.int_flags &= ~data & 0xFF
                self.int_flags &= self.int_mask
            case MotorReg.DIVIDERS:
                self.pulse_div = data >> 12 & 0xF
                self.ramp_div = data >> 8 & 0xF
                self.usrs = data & 7
                ramp = 1 << self.ramp_div
                self.ramp_next = (self.t // ramp + 1) * ramp
            case MotorReg.X_LATCHED:
                self.latch_pending = True

    def rewire(self, **wiring: bool) -> None:
        """Change wiring attributes (see the class docstring); level changes act at once."""
        before = self._levels()
        for name, value in wiring.items():
            setattr(self, name, value)
        self._level_changes(before)

    # == pins, switches, interrupts ============================================================

    def _raise(self, irq: Irq) -> None:
        if self.int_mask >> irq & 1:
            self.int_flags |= 1 << irq

    def _levels(self) -> tuple[bool, bool]:
        return self.left_active, self.right_active

    def _refresh_pins(self) -> None:
        if self.board is not None:
            self.ref_l, self.ref_r, self.gp_in = self.board.pins(self.motor_position)

    def set_pins(self, ref_l: bool, ref_r: bool, gp_in: bool) -> None:
        """Drive the input pins (electrical levels); edges act at once."""
        before = self._levels()
        self.ref_l, self.ref_r, self.gp_in = ref_l, ref_r, gp_in
        self._level_changes(before)

    def _level_changes(self, before: tuple[bool, bool]) -> None:
        left, right = self._levels()
        reference_edge = False
        ref_is_right = bool(self.ref_conf & REF_RNL)
        if left != before[0]:
            self._raise(Irq.STOP_LEFT_HIGH if left else Irq.STOP_LEFT_LOW)
            reference_edge |= not ref_is_right
        if right != before[1]:
            self._raise(Irq.STOP_RIGHT_HIGH if right else Irq.STOP_RIGHT_LOW)
            reference_edge |= ref_is_right
        if reference_edge:
            if self.latch_pending and self.v_actual != 0:
                self.x_latched = self.x_actual
                self.latch_pending = False
            active = right if ref_is_right else left
            if active and abs(signed(self.x_actual, 24)) >= self.dx_ref_tolerance:
                self._raise(Irq.REF_WRONG)
        # A hard switch stop acts on the pulse generator at once.
        direction = (self.v > 0) - (self.v < 0)
        if (direction and self._switch_in_play(direction) and self._outside_window()
                and not self.ref_conf & SOFT_STOP):
            self.v = 0
            self._raise(Irq.STOP)

    def _outside_window(self) -> bool:
        """Outside the switch tolerance window: a stop switch in play stops the motor here."""
        return abs(signed(self.x_actual, 24)) >= self.dx_ref_tolerance

    # == ramp generator ========================================================================

    def _curve(self, distance: int) -> int:
        """Target speed magnitude from the remaining distance (ramp: sqrt law, soft: linear)."""
        d = distance if distance < DISTANCE_LIMIT else DISTANCE_LIMIT
        if self.mode == _RAMP:
            return isqrt((self.pmul * d << 8) >> self.pdiv)
        return (self.pmul * d) >> (3 + self.pdiv)

    def _ramp_target(self) -> tuple[int, bool]:
        """(target velocity, hard switch stop) that a ramp tick would use now."""
        mode = self.mode
        # (comparisons rather than min/max: this runs at every ramp tick)
        if mode == _HOLD:
            vt = 0
        elif mode == _VELOCITY:
            v_max = self.v_max
            vt = self.v_target
            if vt > v_max:
                vt = v_max
            elif vt < -v_max:
                vt = -v_max
        else:
            dx = ((self.x_target - self.x_actual + HALF24) & MASK24) - HALF24  # sdiff24
            if dx == 0:
                vt = 0
            else:
                mag = self._curve(dx if dx > 0 else -dx)
                if mag < self.v_min:
                    mag = self.v_min
                if mag > self.v_max:
                    mag = self.v_max
                vt = mag if dx > 0 else -mag
        v = self.v
        direction = (v > 0) - (v < 0) or (vt > 0) - (vt < 0)
        if direction and self._switch_in_play(direction) and self._outside_window():
            vt = max(vt, 0) if direction < 0 else min(vt, 0)
            return vt, mode == _HOLD or not self.ref_conf & SOFT_STOP
        return vt, False

    def _ramp_tick(self) -> None:
        """One ramp tick: the velocity steps towards the ramp target by up to A_MAX."""
        vt, hard = self._ramp_target()
        mode = self.mode
        if mode < _VELOCITY:
            self.v_target = vt
        v_old = v = self.v
        if hard:
            if v:
                self._raise(Irq.STOP)
            v = 0
        if mode != _HOLD:
            target = vt << 8
            if v < target:
                v += self.a_max
                if v > target:
                    v = target
            elif v > target:
                v -= self.a_max
                if v < target:
                    v = target
        self.v = v
        a = v - v_old
        self.a_actual = 2047 if a > 2047 else -2048 if a < -2048 else a

    def _steady_steps(self) -> int | None:
        """If ramp ticks cannot change the velocity for a while, how many steps that lasts.

        Returns None if not steady, -1 for "as long as nothing else changes", else the number of
        further steps after which the ramp generator must be consulted again.
        """
        vt, hard = self._ramp_target()
        v = self.v
        if hard and v:
            return None
        if self.mode == _HOLD or self.a_max == 0 or (v == 0 and vt == 0):
            # Ramp ticks cannot change the velocity: hold mode; no acceleration; or at rest
            # with a target speed of zero (V_MAX 0, a curve value of 0, a blocking switch),
            # which stays zero while the motor does not move.
            if v:
                window = self._window_steps(1 if v > 0 else -1)
                if window:  # inside the tolerance window: leaving it may stop the motor
                    return window
            # Outside it a switch ahead would stop the motor hard (handled above), or
            # softly, which a_max = 0 cannot do: the velocity stays.
            return -1
        if v != vt << 8:
            return None
        window = None
        if v:
            window = self._window_steps(1 if v > 0 else -1)
            if window == 0:
                return None  # outside the window with a switch ahead: not steady
        steady = self._steady_positioning(v, vt)
        if window is None or steady is None:
            return steady
        return window if steady == -1 else min(steady, window)

    def _steady_positioning(self, v: int, vt: int) -> int | None:
        """_steady_steps for a velocity at its ramp target (see there)."""
        if self.mode == _VELOCITY:
            return -1
        dx = sdiff24(self.x_target, self.x_actual)
        if dx == 0:
            return -1 if v == 0 else None
        if (dx > 0) != (v > 0):
            return None
        d = abs(dx)
        mag = abs(vt)
        low: int | None
        if mag == self.v_max and self.v_min >= self.v_max:
            low = 1  # V_MIN >= V_MAX: the clamped curve is V_MAX all the way to the target
        elif mag == self.v_max:
            low = self._distance_for(self.v_max)
            if low is None:
                return None
        elif mag == self.v_min:
            low = 1  # the curve only falls as the distance shrinks: V_MIN holds to the target
        elif d >= DISTANCE_LIMIT:
            low = DISTANCE_LIMIT
        else:
            return None
        return d - low + 1 if d >= low else None

    def _distance_for(self, speed: int) -> int | None:
        """Smallest distance whose curve value reaches ``speed`` (None if none below the limit)."""
        if self.mode == _RAMP:
            low = -(-(speed * speed << self.pdiv) // (self.pmul << 8))
        else:
            low = -(-(speed << (3 + self.pdiv)) // self.pmul)
        low = max(low, 1)
        return low if low <= DISTANCE_LIMIT else None

    # == pulse generator =======================================================================

    def _apply_steps(self, count: int, direction: int) -> None:
        delta = count * direction
        self.x_actual = (self.x_actual + delta) & MASK24
        if self.steps_out:
            self.motor_position += delta
        usrs = self.usrs
        self.ustep_count = (self.ustep_count + (delta << (6 - usrs if usrs < 6 else 0))) & 0xFF

    def _stop_distance(self, direction: int) -> tuple[int | None, int | None]:
        """Steps to the nearest position where the pulse generator must look closer.

        Returns (nearest of all, distance to the next board mark).
        """
        best: int | None = None
        x = self.x_actual
        if self.mode < _VELOCITY:
            # sdiff24(x_target, x) in line: this runs at every position read of a moving axis
            d = (((self.x_target - x + HALF24) & MASK24) - HALF24) * direction
            if d > 0:
                best = d
        if self.int_mask >> _REF_MISS & 1:
            d = sdiff24(0, x) * direction
            if d > 0 and (best is None or d < best):
                best = d
        if self.pos_comp_on:
            d = sdiff24(self.pos_comp, x) * direction
            if d > 0 and (best is None or d < best):
                best = d
        mark_distance = None
        if self.board is not None and self.steps_out:
            mark = self.board.next_mark(self.motor_position, direction)
            if mark is not None:
                mark_distance = (mark - self.motor_position) * direction
                if mark_distance > 0 and (best is None or mark_distance < best):
                    best = mark_distance
        return best, mark_distance

    def _arrived_here(self) -> None:
        """Per-step checks at a position the pulse generator stopped at."""
        if self.x_actual == 0 and not (self.right_active if self.ref_conf & REF_RNL
                                        else self.left_active):
            self._raise(Irq.REF_MISS)
        if self.pos_comp_on and self.x_actual == self.pos_comp:
            self.pos_comp_flag = True

    def _pulses(self, t_end: int, max_steps: int | None = None) -> Stop | None:
        """Process the pulse ticks in (t, t_end] with the current velocity.

        Returns early (with ``self.t`` at the pulse tick concerned) when the motor arrives at
        its target, reaches a board mark, or has made ``max_steps`` steps (returns None then
        too, with ``self.t`` short of ``t_end``).
        """
        pulse_div = self.pulse_div
        first = (self.t >> pulse_div) + 1 << pulse_div  # the first pulse tick after t
        if first > t_end:
            self.t = t_end
            return None
        ticks = (t_end - first >> pulse_div) + 1
        used = 0
        positioning = self.mode < _VELOCITY
        while True:  # (used < ticks here; this runs at every position read of a moving axis)
            v = self.v
            vi = (v if v > 0 else -v) >> 8
            if positioning and vi <= self.v_min and self.x_actual == self.x_target:
                if v:
                    self.v = 0
                    self.t = first + (used << pulse_div)
                    self._raise(Irq.POS_END)
                    return Stop.ARRIVED
                self.t = t_end
                return None
            if vi == 0:
                self.t = t_end
                return None
            direction = 1 if v > 0 else -1
            remaining = ticks - used
            acc = self.acc
            total = (acc + vi * remaining) >> 11
            limit, mark_distance = self._stop_distance(direction)
            if max_steps is not None and (limit is None or max_steps < limit):
                limit = max_steps
            if limit is None or limit > total:
                self._apply_steps(total, direction)
                self.acc = acc + vi * remaining - (total << 11)
                self.t = t_end
                return None
            k = ((limit << 11) - acc + vi - 1) // vi  # pulse ticks until step number `limit`
            self._apply_steps(limit, direction)
            self.acc = acc + vi * k - (limit << 11)
            used += k
            self.t = first + (used - 1 << pulse_div)
            self._arrived_here()
            if limit == mark_distance and self.board is not None:
                self.set_pins(*self.board.pins(self.motor_position))
                return Stop.MARK
            if max_steps is not None:
                max_steps -= limit
                if max_steps == 0:
                    return None
            if used >= ticks:
                self.t = t_end
                return None

    # == the engine ============================================================================

    def run(self, until: int, budget: int | None = None) -> Stop | None:
        """Advance to clk32 tick ``until``; return early (self.t < until) at a notable instant.

        ``budget`` bounds the work: after that many loop iterations (a ramp tick taken the
        plain way, or a batch of them in closed form: each counts 1), it returns
        None short of ``until`` (the caller looks again from there).
        """
        while self.t < until:
            if self.powered_down:
                self.t = until
                ramp = 1 << self.ramp_div
                self.ramp_next = (until // ramp + 1) * ramp
                return None
            nr = self.ramp_next
            if nr > until:
                # No ramp tick on the way (a look at the position mid-move): the velocity
                # stays as it is, only pulses happen.
                return self._pulses(until)
            if nr + (1 << self.ramp_div) > until and budget is None:
                # Exactly one ramp tick on the way: take it plainly (the closed forms below
                # pay off over many ticks; one tick the plain way is the same tick).
                if self.t < nr - 1:
                    stop = self._pulses(nr - 1)
                    if stop is not None:
                        return stop
                stop = self._slow_tick(nr)
                if stop is not None:
                    return stop
                continue
            steady = self._steady_steps()
            if steady is not None:
                moving = self.v != 0
                # What each skipped ramp tick would have written (constant while steady).
                vt_steady = self._ramp_target()[0]
                stop = self._pulses(until) if steady < 0 else self._pulses(until, steady)
                ramp = 1 << self.ramp_div
                if self.ramp_next <= self.t:
                    self.a_actual = 0
                    if self.mode < _VELOCITY:
                        # with no acceleration the curve moves on while the speed cannot:
                        # the last skipped tick wrote its value where the motor is now
                        self.v_target = self._ramp_target()[0] if self.a_max == 0 else vt_steady
                self.ramp_next = (self.t // ramp + 1) * ramp
                if stop is not None:
                    return stop
                if moving and self.v == 0:
                    return Stop.STOPPED
                continue
            if budget is not None and budget <= 0:
                return None  # out of budget, short of until
            last = until
            if self.t < nr - 1:
                stop = self._pulses(nr - 1)
                if stop is not None:
                    return stop
            self._work = 1
            if self._can_fast() and nr + (1 << self.ramp_div) - 1 <= last:
                stop = self._fast(last, budget)
            else:
                stop = self._slow_tick(nr)
            if budget is not None:
                budget -= self._work  # loop iterations, however many ticks they covered
            if stop is not None:
                return stop
        return None

    def _can_fast(self) -> bool:
        return self.mode != _HOLD

    def _pulse_plan(self, nr: int) -> tuple[int, int, int]:
        """How pulse ticks fall on the ramp ticks from ``nr`` on: (pulses per ramp tick,
        ramp ticks per pulse, index of the first ramp tick with a pulse).  With
        PULSE_DIV <= RAMP_DIV every ramp period has 2**(RAMP_DIV-PULSE_DIV) pulses, all at the
        speed its ramp tick set; with PULSE_DIV > RAMP_DIV a pulse tick falls on every
        2**(PULSE_DIV-RAMP_DIV)-th ramp tick (after it, at the same clk32 tick)."""
        rd, pd = self.ramp_div, self.pulse_div
        if rd >= pd:
            return 1 << (rd - pd), 1, 0
        return 1, 1 << (pd - rd), ((-nr) & ((1 << pd) - 1)) >> rd

    def _slew_steps(self, k: int, w: int, acc: int, rising: bool,
                    plan: tuple[int, int, int]) -> tuple[int, int]:
        """(steps, accumulator) after ``k`` ramp ticks that each change the speed ``w`` by
        A_MAX (up if ``rising``), pulses as ``plan`` says (floor sums, not a loop)."""
        per_ramp, every, phase = plan
        pulses = 0 if k <= phase else (k - 1 - phase) // every + 1
        if pulses == 0:
            return acc >> 11, acc & 2047
        a = self.a_max
        if rising:
            speeds = floor_sum(pulses, 256, every * a, w + (phase + 1) * a)
        else:
            speeds = floor_sum(pulses, 256, every * a,
                               w - (phase + 1 + (pulses - 1) * every) * a)
        total = acc + per_ramp * speeds
        return total >> 11, total & 2047

    def _switch_in_play(self, direction: int) -> bool:
        """True if the stop switch ahead (in ``direction``) is active and enabled: the ramp
        tick may then stop the motor (or will once it leaves the tolerance window).  A switch
        behind the motor, or one that is off or disabled, leaves the ramp alone: its pin only
        changes at a board mark, where the pulse generator stops anyway."""
        # left_active / right_active spelled out: this runs at every ramp tick
        if direction < 0:
            return (self.left_wired and self.ref_l != self.inv_ref
                    and not self.ref_conf & DISABLE_STOP_L)
        return (self.right_wired and self.ref_r != self.inv_ref
                and not self.ref_conf & DISABLE_STOP_R)

    def _window_steps(self, direction: int) -> int | None:
        """Steps until the motor leaves the switch tolerance window while a switch ahead is in
        play (None: no such limit); 0 when outside it already."""
        if not self._switch_in_play(direction):
            return None
        if not self.dx_ref_tolerance:
            return 0
        x = signed(self.x_actual, 24)
        if abs(x) >= self.dx_ref_tolerance:
            return 0
        return (self.dx_ref_tolerance - x) if direction > 0 else (x + self.dx_ref_tolerance)

    def _fast(self, until: int, work: int | None = None) -> Stop | None:
        """Ramp ticks one per iteration with their pulses counted in bulk (no switches active).

        Entered with ``self.t == ramp_next - 1``.  Leaves as soon as a tick would bring the
        motor to a position of interest, the velocity becomes steady or changes sign, or the
        next whole ramp period would pass ``until``; the general path then takes over.
        """
        rd = self.ramp_div
        period = 1 << rd
        nr = self.ramp_next
        plan = self._pulse_plan(nr)
        per_ramp, every = plan[0], plan[1]
        pulse_mask = (1 << self.pulse_div) - 1
        v = self.v
        acc = self.acc
        a_max = self.a_max
        v_max = self.v_max
        v_min = self.v_min
        mode = self.mode
        positioning = mode != _VELOCITY
        x = self.x_actual
        x_target = self.x_target
        k_mul = self.pmul << 8
        pdiv = self.pdiv
        soft_shift = 3 + pdiv
        pmul = self.pmul
        vt_fixed = 0
        if positioning:
            dx = sdiff24(x_target, x)
            if dx == 0:
                # at the target still moving (too fast to stop there): braking towards 0
                return self._fast_brake(until, 0) if v else self._slow_tick(nr)
            direction = 1 if dx > 0 else -1
            d = abs(dx)
            if v * direction < 0:
                return self._fast_brake(until, d)
        else:
            vt_fixed = max(-v_max, min(v_max, self.v_target))
            direction = (v > 0) - (v < 0) or (vt_fixed > 0) - (vt_fixed < 0)
            if direction == 0:
                return self._slow_tick(nr)
            d = 0
        if v * direction < 0:
            return self._slow_tick(nr)
        room, _ = self._stop_distance(direction)
        if room is None:
            room = 1 << 62
        window = self._window_steps(direction)
        if window is not None:  # a switch ahead: go no further than its tolerance window
            if window == 0:
                if v * direction > 0 and self.ref_conf & SOFT_STOP:
                    # a soft stop at the switch: every tick slows the motor by A_MAX
                    return self._fast_brake(until, None)
                return self._slow_tick(nr)
            room = min(room, window)
        w = v * direction  # speed along the direction of travel, 1/256 units, >= 0
        walked = 0
        applied = 0
        a_step = 0
        vt_reg = self.v_target
        last = until - period + 1
        is_ramp = mode == _RAMP
        batch = self._linear_batch(w, acc, d, room, (last - nr) // period + 1, plan,
                                   positioning, vt_fixed * direction if not positioning else 0)
        if batch is not None:
            ticks, w, acc, steps, vt_reg_mag = batch
            room -= steps
            d -= steps
            walked += steps
            applied += ticks
            nr += ticks * period
            a_step = a_max if positioning or vt_fixed * direction << 8 > w else -a_max
            if positioning:
                vt_reg = vt_reg_mag * direction
        iterations = 0
        prev_mag = -1  # the ramp target's magnitude at the previous tick
        flat = 0  # for how many ticks in a row it has not changed
        while nr <= last:
            iterations += 1
            if work is not None and iterations > work:
                break  # out of budget: what was applied stands, the caller looks again
            if positioning:
                dd = d if d < DISTANCE_LIMIT else DISTANCE_LIMIT
                mag = isqrt((k_mul * dd) >> pdiv) if is_ramp else (pmul * dd) >> soft_shift
                if mag < v_min:
                    mag = v_min
                if mag > v_max:
                    mag = v_max
                target = mag << 8
                if w == target and (mag in (v_max, v_min) or d >= DISTANCE_LIMIT):
                    break  # steady: the closed-form path takes over
                # While the clamped curve stays flat the target does: those ticks go in one
                # batch (slow ramps, slow pulses or a long way at the distance limit).  Tried
                # on entry and once the target has not changed for two ticks; a curve that
                # changes every tick or two (an ordinary ramp) skips the search.
                same = None
                flat = flat + 1 if mag == prev_mag else 0
                if flat >= 2 or iterations == 1:
                    same = self._same_target_ticks(w, mag, d, room, acc, nr,
                                                   (last - nr) // period + 1)
                prev_mag = mag
                if same is not None:
                    k, w_next, acc, steps = same
                    if w_next != w:
                        a_step = a_max if w_next > w else -a_max
                    w = w_next
                    room -= steps
                    d -= steps
                    walked += steps
                    applied += k
                    nr += k * period
                    vt_reg = mag * direction
                    if w == 0 or nr > last:
                        break
                    continue
            else:
                target = vt_fixed * direction << 8
                if target < 0:
                    if w < a_max:
                        break  # this tick crosses zero: the general path does it
                    target = 0  # reversing: down towards zero here
                if w == target:
                    break  # steady: the closed-form path takes over
            if w < target:
                nw = w + a_max
                if nw > target:
                    nw = target
            else:
                nw = w - a_max
                if nw < target:
                    nw = target
            vi = nw >> 8
            # every == 1: per_ramp pulses per ramp period; else a pulse on some ramp ticks
            total = acc + vi * (per_ramp if every == 1 else nr & pulse_mask == 0)
            steps = total >> 11
            if steps >= room:
                break
            a_step = nw - w
            w = nw
            acc = total & 2047
            room -= steps
            d -= steps
            walked += steps
            applied += 1
            nr += period
            if positioning:
                vt_reg = mag * direction
            if w == 0:
                break
        self._work = max(1, iterations)
        if applied:
            self.v = w * direction
            self.acc = acc
            self.a_actual = max(-2048, min(2047, a_step * direction))
            self.v_target = vt_reg
            self._apply_steps(walked, direction)
            self.ramp_next = nr
            if w == 0 and self._ramp_target()[0] == 0:
                self.t = nr - period
                return Stop.STOPPED
            self.t = nr - 1
            return None
        if self._steady_steps() is not None:
            return None
        return self._slow_tick(nr)

    def _same_target_ticks(self, w: int, mag: int, d: int, room: int, acc: int, nr: int,
                           max_ticks: int) -> tuple[int, int, int, int] | None:
        """Positioning: ramp ticks from ``nr`` on whose ramp target stays ``mag`` (the clamped
        curve is flat over the distances the motor covers meanwhile) and that stop short of
        ``room``: in one batch, the speed slews by A_MAX towards the target and then holds
        it.  Returns (ticks, speed, accumulator, steps) after them, or None if fewer than 2
        ticks qualify.  ``w`` is the speed along the travel (1/256), ``d`` the distance."""
        a_max = self.a_max
        target = mag << 8
        rising = w < target
        if w == target:
            limit = max_ticks
        else:
            limit = min(max_ticks, (target - w) // a_max if rising else (w - target) // a_max)
        if limit < 2:
            return None  # (most calls: a speed that tracks the curve is within 2 A_MAX of it)
        # the lowest distance with the same target (the clamp at V_MIN holds it to the end)
        low = (1 if self.v_min >= self.v_max or mag == self.v_min
               else self._distance_for(mag) or d)
        allowed = d - low  # steps that keep the curve at mag
        plan = self._pulse_plan(nr)
        per_ramp, every, phase = plan
        if w == target:
            vi = w >> 8

            def after(k: int) -> tuple[int, int]:
                pulses = 0 if k <= phase else (k - 1 - phase) // every + 1
                total = acc + pulses * per_ramp * vi
                return total >> 11, total & 2047
        else:
            def after(k: int) -> tuple[int, int]:
                return self._slew_steps(k, w, acc, rising, plan)

        def fits(k: int) -> bool:
            return after(k - 1)[0] <= allowed and after(k)[0] < room

        if not fits(2):
            return None
        k = first_true(lambda k: not fits(k), limit) - 1  # fits(1) and fits(2) hold
        steps, new_acc = after(k)
        speed = w if w == target else w + k * a_max if w < target else w - k * a_max
        return k, speed, new_acc, steps

    def _window_entry(self, travel: int) -> int | None:
        """Steps (moving in ``travel``) until the motor enters the switch tolerance window from
        outside it (None: a window of 0 is never entered)."""
        tol = self.dx_ref_tolerance
        if not tol:
            return None
        x = signed(self.x_actual, 24)
        edge = 1 - tol if travel > 0 else tol - 1
        return ((edge - x) * travel) & MASK24

    def _fast_brake(self, until: int, d: int | None) -> Stop | None:
        """Ramp ticks that each slow the motor by A_MAX until it is nearly stopped, in one batch:
        positioning while moving away from the target (a move reversed in flight, or one too
        fast to stop at it; ``d`` is the distance to the target), or a soft stop at an active
        stop switch ahead, outside its tolerance window (``d`` None): the ramp target is then
        0 or points the other way.  Entered with ``t == ramp_next - 1``."""
        nr = self.ramp_next
        period = 1 << self.ramp_div
        travel = 1 if self.v > 0 else -1
        room, _ = self._stop_distance(travel)
        if room is None:
            room = 1 << 62
        soft = self.ref_conf & SOFT_STOP
        window = self._window_steps(travel)
        if window == 0:  # the switch ahead blocks: only a soft stop keeps braking
            if not soft:
                return self._slow_tick(nr)
            entry = self._window_entry(travel)  # inside the window the switch lets go
            if entry is not None:
                room = min(room, entry)
        elif window is not None and not soft:
            room = min(room, window)  # past the window a hard stop ends the motion
        if d is not None:
            # the ramp ticks must see the target behind: a distance of at most 2**23 - 1
            # (or the 2**23 it is at; the first step then turns the target round)
            room = min(room, max(1, HALF24 - d))
        last = until - period + 1
        batch = None
        plan = self._pulse_plan(nr)
        max_ticks = (last - nr) // period + 1
        if d == 0:
            # at the target a pulse at V_MIN or below ends the move: stay above it
            max_ticks = min(max_ticks, (abs(self.v) - (self.v_min + 1 << 8)) // self.a_max
                            if self.a_max else 0)
        if room > 0 and nr <= last and max_ticks > 0:
            batch = self._linear_batch(abs(self.v), self.acc, 0, room, max_ticks, plan, False, 0)
        if batch is None:
            return self._slow_tick(nr)
        ticks, w, acc, steps, _ = batch
        if self.mode < _VELOCITY:
            if d is None:
                self.v_target = 0  # the switch clamps the curve towards the target to 0
            else:
                before, _ = self._slew_steps(ticks - 1, abs(self.v), self.acc, False, plan)
                if d + before:
                    mag = min(max(self._curve(d + before), self.v_min), self.v_max)
                    self.v_target = -mag * travel
                else:
                    self.v_target = 0  # still at the target at the last tick
        self.v = w * travel
        self.acc = acc
        self.a_actual = max(-2048, min(2047, -self.a_max * travel))
        self._apply_steps(steps, travel)
        self.ramp_next = nr + ticks * period
        if w == 0 and self._ramp_target()[0] == 0:
            self.t = self.ramp_next - period
            return Stop.STOPPED
        self.t = self.ramp_next - 1
        return None

    def _linear_batch(self, w: int, acc: int, d: int, room: int, max_ticks: int,
                      plan: tuple[int, int, int],
                      positioning: bool, fixed_target: int
                      ) -> tuple[int, int, int, int, int] | None:
        """Many ramp ticks of full-A_MAX slew at once (floor sums instead of a loop).

        ``w`` is the speed along the direction of travel (1/256 units).  In velocity mode the
        target is fixed; in ramp/soft mode it is the curve, and the batch ends before the tick
        at which the curve would limit the acceleration.  Returns (ticks, speed, accumulator,
        steps, last target magnitude: 0 in velocity mode) or None if fewer than 16 ticks
        qualify.
        """
        a_max = self.a_max
        if a_max == 0:
            return None
        if positioning:
            cap = self.v_max << 8
            if w + a_max > cap:
                return None
            ticks = min(max_ticks, (cap - w) // a_max)
            rising = True
        else:
            target = max(0, fixed_target << 8)  # a reversal decelerates to zero first
            rising = target > w
            ticks = min(max_ticks, (target - w) // a_max if rising else (w - target) // a_max)
        if ticks < 16:
            return None

        def after(k: int) -> tuple[int, int]:
            """(steps, accumulator) after k full-slew ticks."""
            return self._slew_steps(k, w, acc, rising, plan)

        def fits(k: int) -> bool:
            steps, _ = after(k)
            if steps >= room:
                return False
            if positioning:
                before, _ = after(k - 1)  # distance at the start of tick k
                mag = min(max(self._curve(d - before), self.v_min), self.v_max)
                return mag << 8 >= w + k * a_max
            return True

        ticks = first_true(lambda k: not fits(k), ticks) - 1
        if ticks < 16:
            return None
        steps, new_acc = after(ticks)
        speed = w + ticks * a_max if rising else w - ticks * a_max
        last_mag = 0
        if positioning:
            before, _ = after(ticks - 1)
            last_mag = min(max(self._curve(d - before), self.v_min), self.v_max)
        return ticks, speed, new_acc, steps, last_mag

    def _slow_tick(self, nr: int) -> Stop | None:
        """One ramp tick the plain way (its pulses follow in the caller's next round)."""
        moving = self.v != 0
        self._ramp_tick()
        self.ramp_next = nr + (1 << self.ramp_div)
        if moving and not self.v and self._ramp_target()[0] == 0:
            self.t = nr
            return Stop.STOPPED
        return None
