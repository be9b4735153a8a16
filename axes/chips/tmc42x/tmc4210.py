"""One TMC4210 motion controller: its register file behind 32-bit SPI datagrams, and its motion.

The register layout, widths and power-on values follow the TMC4210 datasheet.  The
TMC4210 is one motor of the TMC42x family: the axis registers, switches, interrupts and the
ramp and pulse generators are :class:`axes.chips.tmc42x.engine.MotorEngine` (shared with the TMC429);
this class adds the global registers, the status byte and the SPI interface, and is the
motor at the same time (one chip, one motor, one object).

The chip knows nothing about seconds: time is a clk32 tick count.  Its pins (REF_L, REF_R,
GP_IN) are driven by a :class:`Board`, which also names the motor positions at which the
outside world changes so that the engine can stop there.
"""

from __future__ import annotations

from enum import IntEnum

from axes.chips.tmc42x.engine import (
    DEFAULT_CLOCK_HZ,
    DISABLE_STOP_L,
    DISABLE_STOP_R,
    DISTANCE_LIMIT,
    HALF24,
    LATCH_PENDING,
    MASK24,
    REF_RNL,
    SOFT_STOP,
    Irq,
    MotorEngine,
    MotorReg,
    RampMode,
    datagram,
    floor_sum,
    sdiff24,
    shallow_copy,
    signed,
)
from axes.core import Board, Stop

__all__ = [
    "DEFAULT_CLOCK_HZ", "DISABLE_STOP_L", "DISABLE_STOP_R", "DISTANCE_LIMIT", "EN_SD", "HALF24",
    "IF_CONFIG_MASK", "INV_REF", "LATCH_PENDING", "MASK24", "MOT1R", "PLAIN_REGISTERS",
    "POS_COMP_SEL", "REF_RNL", "SDO_INT", "SMGP_MASK", "SMGP_POWER_ON", "SOFT_STOP", "TMC4210",
    "TYPE_VERSION", "Board", "Irq", "RampMode", "Reg", "Stop", "datagram", "floor_sum", "sdiff24",
    "signed",
]

TYPE_VERSION = 0x429101
SMGP_POWER_ON = 0x000F00
SMGP_MASK = 0x31FFFF
IF_CONFIG_MASK = 0x1FF


class Reg(IntEnum):
    """Register addresses: the 7-bit ``RRS|SMDA|IDX`` field (datagram bits 31..25): the one
    motor's axis registers (:class:`MotorReg`) and the family's global registers
    (:class:`GlobalReg`), at the TMC429's addresses.  Spelt out so a type checker knows the
    names; tests/axes/test_tmc4210.py keeps it equal to the two tables."""

    X_TARGET = 0x0
    X_ACTUAL = 0x1
    V_MIN = 0x2
    V_MAX = 0x3
    V_TARGET = 0x4
    V_ACTUAL = 0x5
    A_MAX = 0x6
    A_ACTUAL = 0x7
    A_THRESHOLD = 0x8
    PMUL_PDIV = 0x9
    REF_CONF_RAMP_MODE = 0xA
    INTERRUPT = 0xB
    DIVIDERS = 0xC
    DX_REF_TOLERANCE = 0xD
    X_LATCHED = 0xE
    USTEP_COUNT = 0xF
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


#: Registers that are plain storage: attribute and the bits that exist (spec §3.2/§3.3).
PLAIN_REGISTERS: dict[int, tuple[str, int]] = {
    Reg.X_TARGET: ("x_target", MASK24),
    Reg.X_ACTUAL: ("x_actual", MASK24),
    Reg.V_MIN: ("v_min", 0x7FF),
    Reg.V_MAX: ("v_max", 0x7FF),
    Reg.A_MAX: ("a_max", 0x7FF),
    Reg.A_THRESHOLD: ("a_threshold", 0x777FFF),
    Reg.DX_REF_TOLERANCE: ("dx_ref_tolerance", 0xFFF),
    Reg.USTEP_COUNT: ("ustep_count", 0xFF),
    Reg.POS_COMP: ("pos_comp", MASK24),
}

#: X_ACTUAL's address as a plain int (spi_data compares it on every position read).
_X_ACTUAL = int(MotorReg.X_ACTUAL)

# Bits of IF_CONFIGURATION and SMGP.
INV_REF = 1 << 0
SDO_INT = 1 << 1
EN_SD = 1 << 5
POS_COMP_SEL = 3 << 6
MOT1R = 1 << 21


class TMC4210(MotorEngine):
    """The chip.  Host access is :meth:`spi`; the world drives pins through the board."""

    a_threshold_mask = 0x777FFF

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, board: Board | None = None) -> None:
        super().__init__(clock_hz, board)
        self.power_on()

    # == power-on ==============================================================================

    def power_on(self) -> None:
        """Every register bit 0 except STPDIV = 15 (datasheet)."""
        self.if_config = 0
        self.pos_comp = 0
        self.pos_comp_mask = False
        self.pos_comp_flag = False
        self.smgp = SMGP_POWER_ON
        self.legacy = [0, 0, 0, 0]
        self.ram = [0] * 64
        self.cdgw = False
        self.powered_down = False
        self._wire()
        self.reset_motor()

    def clone(self) -> TMC4210:
        """An independent copy (for looking ahead without disturbing this chip)."""
        twin = shallow_copy(self)
        twin.ram = list(self.ram)
        twin.legacy = list(self.legacy)
        return twin

    def adopt(self, twin: TMC4210) -> TMC4210:
        """Continue with the state a clone reached (one chip, one motor: the clone itself)."""
        return twin

    # == derived state =========================================================================

    @property
    def mot1r(self) -> bool:
        return bool(self.smgp & MOT1R)

    @property
    def interrupt(self) -> bool:
        return bool(self.int_flags) or (self.pos_comp_flag and self.pos_comp_mask)

    def status_byte(self) -> int:
        """INT, CDGW, RS3 (REF_R unless mot1r), 1, RS1 (GP_IN), 1, RS2 (left), xEQt."""
        inv_ref = self.inv_ref  # in line: the firmware sends a datagram per position read
        ref_r = self.ref_r != inv_ref and not self.smgp & MOT1R
        left = self.left_wired and self.ref_l != inv_ref  # left_active
        interrupt = bool(self.int_flags) or (self.pos_comp_flag and self.pos_comp_mask)
        return (interrupt << 7 | self.cdgw << 6 | ref_r << 5 | 0x14 | (self.gp_in != inv_ref) << 3
                | left << 1 | (self.x_actual == self.x_target))

    def _wire(self) -> None:
        """Tell the motor engine what the global registers mean for it."""
        self.rewire(steps_out=bool(self.if_config & EN_SD), inv_ref=bool(self.if_config & INV_REF),
                    right_wired=self.mot1r,
                    pos_comp_on=self.pos_comp_mask and not self.if_config & POS_COMP_SEL)

    # == SPI ===================================================================================

    def spi(self, frame: int) -> int:
        """Exchange one 32-bit datagram; returns the chip's 32-bit answer.

        Status and read data are sampled at the start of the frame and a write takes effect
        at its end, as on the real chip (nSCS rising edge).  A frame wakes the chip from
        power-down and is then processed normally.
        """
        self.powered_down = False
        status = self.status_byte()
        self.cdgw = False
        address = frame >> 25 & 0x7F
        answer = 0
        if frame >> 24 & 1:  # a read (the axis registers, read most, first)
            if address < 0x10:
                answer = self.read_motor(address)
            elif address & 0x40:
                answer = self.ram[address & 0x3F]
            else:
                answer = self._read(address)
        elif address & 0x40:
            self.ram[address & 0x3F] = frame & 0x3F3F
        else:
            self._write(address, frame & MASK24)
        if self.if_config & SDO_INT:
            # SDO carries nINT permanently: all ones while no interrupt, all zeros otherwise.
            return 0 if self.interrupt else 0xFFFF_FFFF
        return status << 24 | answer

    def spi_data(self, frame: int) -> int:
        """The 24 data bits of ``spi(frame)``'s answer: the same frame with the same effects.

        The firmware's reads ignore the status byte, so a read of an axis register (the
        position, at every GAP 1 of a program) skips sampling it; any other frame is spi's.
        """
        address = frame >> 25
        if frame >> 24 & 1 and address < 0x10 and not self.if_config & SDO_INT:
            self.powered_down = False
            self.cdgw = False
            return self.x_actual if address == _X_ACTUAL else self.read_motor(address)
        return self.spi(frame) & MASK24

    def read(self, reg: int) -> int:
        """Convenience: the 24 data bits of a register read."""
        return self.spi(datagram(reg, read=True)) & MASK24

    def write(self, reg: int, data: int) -> None:
        self.spi(datagram(reg, data))

    def _read(self, address: int) -> int:
        if address < 0x10:
            return self.read_motor(address)
        if address < 0x30:
            return 0  # the TMC429's hidden axes: not part of the TMC4210 contract
        match address:
            case Reg.DATAGRAM_LOW | Reg.DATAGRAM_HIGH | Reg.COVER_POS_LEN | Reg.COVER_DATAGRAM:
                return self.legacy[address - Reg.DATAGRAM_LOW]
            case Reg.IF_CONFIGURATION:
                return self.if_config
            case Reg.POS_COMP:
                return self.pos_comp
            case Reg.POS_COMP_INT:
                return self.pos_comp_mask << 8 | self.pos_comp_flag
            case Reg.TYPE_VERSION:
                return TYPE_VERSION
            case Reg.REFERENCE_SWITCHES:
                r_active = self._active(self.ref_r)
                return ((r_active and self.mot1r) | self.left_active << 1
                        | self._active(self.gp_in) << 3 | (r_active and not self.mot1r) << 5)
            case Reg.SMGP:
                return self.smgp
        return 0

    def _write(self, address: int, data: int) -> None:
        if address < 0x10:
            self.write_motor(address, data)
            return
        if address < 0x30:
            return
        match address:
            case Reg.DATAGRAM_LOW | Reg.DATAGRAM_HIGH | Reg.COVER_POS_LEN | Reg.COVER_DATAGRAM:
                self.legacy[address - Reg.DATAGRAM_LOW] = data
                if address != Reg.COVER_POS_LEN:
                    self.cdgw = True  # visible in the next frame's status, then the chain is done
            case Reg.IF_CONFIGURATION:
                self.if_config = data & IF_CONFIG_MASK
                self._wire()
            case Reg.POS_COMP:
                self.pos_comp = data & MASK24
            case Reg.POS_COMP_INT:
                self.pos_comp_mask = bool(data >> 8 & 1)
                if data & 1 or not self.pos_comp_mask:
                    self.pos_comp_flag = False
                self.pos_comp_on = self.pos_comp_mask and not self.if_config & POS_COMP_SEL
            case Reg.POWER_DOWN:
                self.powered_down = True
            case Reg.SMGP:
                self.smgp = data & SMGP_MASK
                self._wire()
