"""The TMC4361A-EVAL on a Landungsbruecke: the evaluation firmware's axis over the TMC4361A.

Not a TMCL module's firmware: the TMC-EvalSystem firmware (``boards/TMC4361A_eval.c``, v3.11)
maps its few axis parameters straight onto chip registers, starts moves by writing RAMPMODE,
VMAX and XTARGET, and has no reference search, events or standby current.  This class does the
same over 40-bit :meth:`TMC4361A.spi` datagrams, including the register cache of Trinamic's
TMC-API (write-only registers read back what was last written).  Time is lazy: nothing the
Landungsbruecke does depends on the chip's events, so the chip runs only when a command
looks at it.  Every choice, and what could not be confirmed, is in docs/tmc4361a.md ("The
evaluation board").
"""

from __future__ import annotations

from collections.abc import Mapping

from axes.board import AxisBoard
from axes.chips.tmc4361a import TMC4361A, Reg, Status, datagram
from axes.chips.tmc4361a.registers import MASK32, POWER_ON, RESET_KEY, signed32
from axes.interface import AxisEvent, AxisStatus
from axes.rig import RiggedAxis
from axes.world import AxisWorld
from tmcl_spec.eval_boards import EvalError
from tmcl_spec.numbers import NS_PER_MS, to_int32
from tmcl_spec.parameters import ParamSpec

DEFAULT_CLOCK_HZ = 16_000_000  # the TMC4361A-EVAL's oscillator
RAMPMODE_POSITIONING = 0b100
RAMPMODE_PROFILE = 0b011
#: AP 4 after the firmware starts (``vmax_position``); kept across board re-detection.
DEFAULT_MOVE_VELOCITY = 51_200
#: The firmware clamps velocities to +-8 000 000 pps before writing VMAX (24.8 format).
VELOCITY_LIMIT = 8_000_000
#: AP 214 is written to STDBY_DELAY times this (clock cycles per 10 ms at 16 MHz).
STANDBY_DELAY_SCALE = 160_000

# -- the TMC-API's view of the register file (access rights), as the firmware uses it ------
#: Registers without a read view: the firmware answers reads from its cache of the last write.
WRITE_ONLY = frozenset({0x53, 0x55, 0x56, 0x57, 0x58, 0x5C, 0x5E, 0x5F, 0x60, 0x61, 0x62, 0x63,
                        0x64, 0x67, 0x68, 0x69, *range(0x70, 0x79), 0x7D, 0x7E})
#: Registers with a hardware preset: a board reset leaves them to the chip's power-on value.
HARDWARE_PRESET = frozenset({0x00, 0x06, 0x07, 0x0A, 0x0B, 0x12, 0x1C, 0x1F, 0x31, 0x53, 0x56,
                             0x57, 0x58, 0x62, *range(0x70, 0x79), 0x7E})
#: Read-only registers (and the unused 0x64): never written by a reset.
_NOT_WRITTEN = frozenset({0x0F, 0x22, 0x23, 0x64, 0x65, 0x66, 0x6A, 0x6B, 0x6E, 0x6F, 0x7A, 0x7F})
#: What a board reset writes, in address order: every other register, 0 unless listed here.
RESET_VALUES: dict[int, int] = {
    Reg.STP_LENGTH_ADD: 0x0004_0001,
    Reg.RAMPMODE: 0x1,  # velocity mode, trapezoid
    Reg.AMAX: 0x0001_3880,  # 20 000 pps²
    Reg.DMAX: 0x0001_3880,
    Reg.BOW1: 1000, Reg.BOW2: 1000, Reg.BOW3: 1000, Reg.BOW4: 1000,
    Reg.ENC_IN_RES: 40_000,
}
RESET_ORDER = tuple(a for a in range(0x80) if a not in HARDWARE_PRESET | _NOT_WRITTEN)
#: After the reset values, the firmware's callback: SPI output for no driver board (format
#: 0x0F, 40-bit datagrams), current scaling off, then GENERAL_CONF without pol_dir_out.
RESET_EPILOGUE = ((Reg.SPI_OUT_CONF, 0x4440_0040 | 40 << 13 | 0x0F),
                  (Reg.CURRENT_CONF, 0x3), (Reg.SCALE_VALUES, 0x0),
                  (Reg.GENERAL_CONF, 0x0000_6000))


#: RAMPMODE bits of the TMC-API: positioning, and the "hold" profile (no ramp).
RAMP_POSITION = 0b100
RAMP_HOLD = 0b000
#: ENC_IN_CONF fields the closed-loop calibration sets (stored: closed loop is not emulated).
REGULATION_MODUS = 0b11 << 22
CL_CALIBRATION_EN = 1 << 24
#: The calibration's move to the next full step: VMAX 10 000 pps (24.8), AMAX/DMAX at least 1000.
CALIBRATION_VMAX = 10_000 << 8
CALIBRATION_MIN_ACCELERATION = 1000
#: The firmware's periodic job runs once per systick.
SYSTICK_NS = NS_PER_MS


class EvalBoardInputs(AxisBoard):
    """The eval board's STOPL/STOPR/HOME_REF lines: pulled up, pulled low by an actuated
    switch (active for the chip's power-on low-active polarity) or by the microcontroller
    (command 144, the firmware's switch simulation).  A line the microcontroller releases (or
    drives high, as at start-up) follows the switch: the firmware's own comment has external
    switches work "if the signals from µC are high or floating"."""

    def __init__(self, world: AxisWorld | None = None) -> None:
        super().__init__(world)
        #: The lines ("left", "right", "home") the microcontroller drives low.
        self.driven_low: set[str] = set()

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        left, right, home = super().pins(motor_position)
        low = self.driven_low
        return (not left and "left" not in low, not right and "right" not in low,
                not home and "home" not in low)


def _c_div(value: int, divisor: int) -> int:
    """C's integer division (toward zero), as the firmware divides."""
    quotient = abs(value) // divisor
    return -quotient if value < 0 else quotient


class TMC4361AEvalAxis(RiggedAxis):
    """Motor 0 of a TMC4361A-EVAL, as the evaluation firmware drives it."""

    board: EvalBoardInputs

    def __init__(self, index: int, parameters: Mapping[int, ParamSpec] | None = None,
                 world: AxisWorld | None = None, clock_hz: int | None = None) -> None:
        self.index = index
        unknown = sorted(set(parameters or ()) - _SERVED)
        if unknown:
            raise ValueError(f"the tmc4361a-eval core is the evaluation firmware's axis: it does "
                             f"not serve axis parameters {unknown} (module type "
                             f"landungsbruecke-tmc4361a)")
        self.board = EvalBoardInputs(world)
        self.chip = TMC4361A(DEFAULT_CLOCK_HZ if clock_hz is None else clock_hz, self.board)
        self._now_ns = 0
        #: The TMC-API cache: last value written per address (reads of write-only ones).
        self._cache: dict[int, int] = {}
        self.move_velocity = DEFAULT_MOVE_VELOCITY  # AP 4, the firmware's vmax_position
        #: The closed-loop calibration's state (the firmware's static ``state``, 0: idle) and
        #: the RAMPMODE it restores.
        self._calibration = 0
        self._calibration_ramp = 0
        self.reset_board()

    # == SPI, as the TMC-API does it ===========================================================

    def _write(self, address: int, value: int) -> None:
        value &= MASK32
        self.chip.spi(datagram(address, value, write=True))
        self._cache[address & 0x7F] = value

    def _read(self, address: int) -> int:
        address &= 0x7F
        if address in WRITE_ONLY:
            return self._cache.get(address, 0)
        frame = datagram(address)
        self.chip.spi(frame)  # the answer comes with the next datagram
        return self.chip.spi(frame) & MASK32

    def _field(self, address: int, mask: int, value: int) -> None:
        self._write(address, (self._read(address) & ~mask) | (value & mask))

    def reset_board(self) -> None:
        """What a board (re-)detection does: NRST pulsed (the chip resets, the motor stays),
        then the firmware writes its reset values one register after the other."""
        self._sync()
        self.chip.spi(datagram(Reg.RESET_CLK_GATING, RESET_KEY << 8, write=True))
        self._cache = {a: POWER_ON[a] for a in WRITE_ONLY & HARDWARE_PRESET if a in POWER_ON}
        for address in RESET_ORDER:
            self._write(address, RESET_VALUES.get(address, 0))
        for address, value in RESET_EPILOGUE:
            self._write(address, value)

    # == time ==================================================================================

    def _sync(self) -> None:
        """Run the chip up to the present (nothing the firmware does reacts to its stops)."""
        chip = self.chip
        until = chip.ticks_at(self._now_ns)
        while chip.t < until:
            chip.run(until)

    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        while self._calibration and (tick := self._next_systick()) <= t_ns:
            self._now_ns = tick  # the periodic job, once per systick, as the worker
            self._sync()
            self._calibrate(master=False)
        if t_ns > self._now_ns:
            self._now_ns = t_ns
        return []

    def next_event_ns(self) -> int | None:
        """The evaluation firmware waits for the host: no events, but while a closed-loop
        calibration runs its periodic job works at every systick."""
        return self._next_systick() if self._calibration else None

    def _next_systick(self) -> int:
        return (self._now_ns // SYSTICK_NS + 1) * SYSTICK_NS

    # == motion (the firmware's rotate / moveTo) ===============================================

    def rotate(self, velocity: int) -> bool:
        """ROR/ROL/MST: velocity mode, VMAX = the velocity (the profile stays)."""
        self._sync()
        self._field(Reg.RAMPMODE, RAMPMODE_POSITIONING, 0)
        self._write(Reg.VMAX, _velocity_register(velocity))
        return True  # the evaluation firmware writes the registers every time

    def stop(self) -> bool:
        return self.rotate(0)

    def emergency_stop(self) -> None:
        self.rotate(0)  # the Landungsbruecke has no heartbeat; a plain stop

    def move_to(self, target: int) -> None:
        """MVP: positioning mode, VMAX = AP 4, XTARGET = the target."""
        self._sync()
        self._field(Reg.RAMPMODE, RAMPMODE_POSITIONING, RAMPMODE_POSITIONING)
        self._write(Reg.VMAX, _velocity_register(self.move_velocity))
        self._write(Reg.XTARGET, target)

    def reference_search(self, action: int) -> int:
        return 0  # not part of the evaluation firmware (RFS answers status 2)

    # == axis parameters =======================================================================

    def get_parameter(self, number: int) -> int:
        self._sync()
        read = self._read
        if number in _PLAIN:
            return to_int32(read(_PLAIN[number]))
        if number == 2:
            return signed32(read(Reg.VMAX)) >> 8
        if number == 3:
            return signed32(read(Reg.VACTUAL))
        if number == 4:
            return to_int32(self.move_velocity)
        if number in _ACCELERATIONS:
            return read(_ACCELERATIONS[number]) >> 2
        if number == 8:
            return read(Reg.STATUS) & Status.TARGET_REACHED_F
        if number == 14:
            return int(read(Reg.RAMPMODE) & RAMPMODE_PROFILE == 0b10)
        if number in _SCALED_VELOCITIES:  # the firmware's own scaling: register * 256
            return to_int32(read(_SCALED_VELOCITIES[number]) * 256)
        if number == 21:
            return to_int32(read(Reg.DSTOP) * 4)
        if number == 214:
            return to_int32(read(Reg.STDBY_DELAY))
        raise ValueError(f"axis parameter {number} is not served")

    def set_parameter(self, number: int, value: int) -> bool:
        self._set_parameter(number, value)
        return True  # the evaluation firmware writes the register every time

    def _set_parameter(self, number: int, value: int) -> None:
        self._sync()
        write = self._write
        if number in _PLAIN:
            write(_PLAIN[number], value)
        elif number == 2:
            write(Reg.VMAX, _velocity_register(value))
        elif number == 4:
            self.move_velocity = value
            if self._read(Reg.RAMPMODE) & RAMPMODE_POSITIONING:
                write(Reg.VMAX, _velocity_register(value))
        elif number in _ACCELERATIONS:
            write(_ACCELERATIONS[number], value << 2)
        elif number == 14:
            self._field(Reg.RAMPMODE, RAMPMODE_PROFILE, 0b10 if value else 0b01)
        elif number in _SCALED_VELOCITIES:  # the firmware divides by 256 (sic)
            write(_SCALED_VELOCITIES[number], _c_div(value, 256))
        elif number == 21:
            write(Reg.DSTOP, _c_div(value, 4))
        elif number == 214:
            write(Reg.STDBY_DELAY, value * STANDBY_DELAY_SCALE)
        else:
            raise ValueError(f"axis parameter {number} is read-only or not served")

    # == the board's user function (command 144) ===============================================

    def user_function(self, type_: int, value: int) -> tuple[int, int]:
        """Command 144 (``userFunction`` of ``boards/TMC4361A_eval.c``, motor ignored):
        (the board's error bits, the reply value).

        0: simulated stop switches, bit 0 STOP_R, bit 1 STOP_L (1 releases the line, high; 0
        drives it low; a value with other bits does nothing); 1: HOME_REF, 2: FREEZE (non-zero
        releases, 0 drives low); 3: the closed-loop calibration (value 0 and NOT_DONE while it
        runs); 255: the boards' reset (NRST pulse, configuration written anew).
        """
        self._sync()
        match type_:
            case 0:
                if not value & ~3:
                    self._drive("right", value & 1)
                    self._drive("left", value & 2)
            case 1:
                self._drive("home", value)
            case 2:
                self.chip.set_freeze(bool(value))
            case 3:
                value = self._calibrate(master=True)
                return (EvalError.NONE if value else EvalError.NOT_DONE), value
            case 255:
                self.reset_board()
            case _:
                return EvalError.TYPE, value
        return EvalError.NONE, value

    def _drive(self, line: str, release: int) -> None:
        if release:
            self.board.driven_low.discard(line)
        else:
            self.board.driven_low.add(line)
        self._pins_changed()

    def _calibrate(self, master: bool) -> int:
        """One call of the firmware's ``tmc4361A_calibrateClosedLoop``: the host's (master,
        command 144 type 3) starts it; the periodic job (worker) drives it on.  1 when it
        ends (5 -> 0), else 0."""
        state = self._calibration
        if master and state == 0:
            state = 1
        result = 0
        if state == 1:  # hold position: no ramp, VMAX 0, accelerations at least 1000
            amax, dmax = self._read(Reg.AMAX), self._read(Reg.DMAX)
            self._calibration_ramp = self._read(Reg.RAMPMODE)
            self._write(Reg.RAMPMODE, RAMP_POSITION | RAMP_HOLD)
            self._write(Reg.AMAX, max(amax, CALIBRATION_MIN_ACCELERATION))
            self._write(Reg.DMAX, max(dmax, CALIBRATION_MIN_ACCELERATION))
            self._write(Reg.VMAX, 0)
            state = 2
        elif state == 2:
            self._field(Reg.ENC_IN_CONF, CL_CALIBRATION_EN, 0)
            self._field(Reg.ENC_IN_CONF, REGULATION_MODUS, 1 << 22)
            if self._move_to_next_fullstep():
                state = 3
        elif state == 3:
            self._field(Reg.ENC_IN_CONF, CL_CALIBRATION_EN, CL_CALIBRATION_EN)
            state = 4
        elif state == 4 and not master:
            self._field(Reg.ENC_IN_CONF, CL_CALIBRATION_EN, 0)
            self._field(Reg.ENC_IN_CONF, REGULATION_MODUS, 1 << 22)
            self._write(Reg.RAMPMODE, RAMP_POSITION | self._calibration_ramp)
            state = 5
        elif state == 5:
            state, result = 0, 1
        self._calibration = state
        return result

    def _move_to_next_fullstep(self) -> bool:
        """Once the motor stands: position mode without ramp at 10 000 pps to the next full
        step (MSCNT % 256 = 128, "256 microsteps assumed"); True when it stands on one."""
        if self._read(Reg.VACTUAL) != 0:
            return False
        self._write(Reg.RAMPMODE, RAMP_POSITION)
        self._write(Reg.VMAX, CALIBRATION_VMAX)
        steps = 128 - self._read(Reg.MSCNT) % 256
        if steps == 0:
            return True
        self._write(Reg.XTARGET, signed32(self._read(Reg.XACTUAL)) + steps)
        return False

    # == registers (146 / 148) =================================================================

    def register_access(self, address: int, value: int | None = None) -> int:
        """WRITE_MC / READ_MC: one register's 32 data bits (write-only ones from the cache)."""
        self._sync()
        if value is None:
            return to_int32(self._read(address))
        self._write(address, value)
        return to_int32(value)

    def status(self) -> AxisStatus:
        self._sync()
        chip = self.chip
        position = signed32(self._read(Reg.XACTUAL))
        target = signed32(self._read(Reg.XTARGET))
        left, right, home = AxisBoard.pins(self.board, chip.motor_position)  # actuated or not
        return AxisStatus(
            position=position, target=target, velocity=signed32(self._read(Reg.VACTUAL)),
            mode="position" if self._read(Reg.RAMPMODE) & RAMPMODE_POSITIONING else "velocity",
            position_reached=position == target, home_switch=home, left_switch=left,
            right_switch=right, encoder_position=signed32(self._read(Reg.ENC_POS)),
            mechanical_position=self.board.mechanical(chip.motor_position))

    # == the rig's hooks (axes/rig.py: the world and the faults around the axis) ==================

    def _motor_position(self) -> int:
        return self.chip.motor_position

    def _rig_begin(self) -> None:
        self._sync()

    def _pins_changed(self) -> None:
        self.chip.set_pins(*self.board.pins(self.chip.motor_position))


def _velocity_register(pps: int) -> int:
    """The firmware's ``discardVelocityDecimals``: clamp to +-8 000 000 pps, then 24.8."""
    return max(-VELOCITY_LIMIT, min(VELOCITY_LIMIT, pps)) << 8


#: Axis parameters that are a register as it is.
_PLAIN = {0: Reg.XTARGET, 1: Reg.XACTUAL, 22: Reg.BOW1, 23: Reg.BOW2, 24: Reg.BOW3,
          25: Reg.BOW4, 26: Reg.VIRT_STOP_LEFT, 27: Reg.VIRT_STOP_RIGHT, 209: Reg.ENC_POS,
          225: Reg.ENC_POS_DEV_TOL}
#: Accelerations: the register is the value times 4 (22.2 pps²).
_ACCELERATIONS = {5: Reg.AMAX, 16: Reg.ASTART, 17: Reg.DMAX, 19: Reg.DFINAL}
#: VSTART, VBREAK, VSTOP: the firmware writes value / 256 and reads register * 256.
_SCALED_VELOCITIES = {15: Reg.VSTART, 18: Reg.VBREAK, 20: Reg.VSTOP}
#: Every axis parameter the evaluation firmware serves (tmcl_spec/landungsbruecke.py's table).
_SERVED = frozenset({2, 3, 4, 8, 14, 21, 214, *_PLAIN, *_ACCELERATIONS, *_SCALED_VELOCITIES})
