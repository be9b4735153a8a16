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

from collections.abc import Callable

from axes.chips.tmc42x.engine import MotorEngine
from axes.chips.tmc42x.registers import (
    DEFAULT_CLOCK_HZ,
    DISTANCE_LIMIT,
    GLOBAL_REGISTERS,
    MASK24,
    Irq,
    RampMode,
    Reg,
    datagram,
    sdiff24,
    shallow_copy,
    signed,
)
from axes.core import Board, Stop

__all__ = [
    "DEFAULT_CLOCK_HZ", "DISTANCE_LIMIT", "EN_SD", "IF_CONFIG_MASK", "INV_REF", "MASK24", "MOT1R",
    "POS_COMP_SEL", "SDO_INT", "SMGP_MASK", "SMGP_POWER_ON", "TMC4210", "TYPE_VERSION", "Board",
    "Irq", "RampMode", "Reg", "Stop", "datagram", "sdiff24", "signed",
]

TYPE_VERSION = 0x429101
SMGP_POWER_ON = 0x000F00
SMGP_MASK = 0x31FFFF
IF_CONFIG_MASK = 0x1FF

#: X_ACTUAL's address as a plain int (spi_data compares it on every position read).
_X_ACTUAL = int(Reg.X_ACTUAL)
#: The legacy driver-chain registers (stored; no chain on the TMC4210).
_LEGACY = (Reg.DATAGRAM_LOW, Reg.DATAGRAM_HIGH, Reg.COVER_POS_LEN, Reg.COVER_DATAGRAM)

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

    def reads_are_quiet(self) -> bool:
        """:meth:`spi_data`'s read of an axis register only wakes the chip and clears CDGW,
        and with SDO_INT it is a whole frame."""
        return not (self.powered_down or self.cdgw or self.if_config & SDO_INT)

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
        if address < GLOBAL_REGISTERS:  # the TMC429's hidden axes read 0 (not in the contract)
            return self.read_motor(address) if address < 0x10 else 0
        read = _GLOBAL_READS.get(address)
        return 0 if read is None else read(self)

    def _reference_switches(self) -> int:
        """REFERENCE_SWITCHES in the TMC429's layout (docs/motion.md)."""
        r_active = self._active(self.ref_r)
        return ((r_active and self.mot1r) | self.left_active << 1
                | self._active(self.gp_in) << 3 | (r_active and not self.mot1r) << 5)

    def _write(self, address: int, data: int) -> None:
        if address < GLOBAL_REGISTERS:  # the TMC429's hidden axes ignore writes
            if address < 0x10:
                self.write_motor(address, data)
            return
        write = _GLOBAL_WRITES.get(address)
        if write is not None:
            write(self, data)

    def _write_legacy(self, address: int, data: int) -> None:
        self.legacy[address - Reg.DATAGRAM_LOW] = data
        if address != Reg.COVER_POS_LEN:
            self.cdgw = True  # visible in the next frame's status, then the chain is done

    def _write_if_configuration(self, data: int) -> None:
        self.if_config = data & IF_CONFIG_MASK
        self._wire()

    def _write_pos_comp_int(self, data: int) -> None:
        self.pos_comp_mask = bool(data >> 8 & 1)
        if data & 1 or not self.pos_comp_mask:
            self.pos_comp_flag = False
        self.pos_comp_on = self.pos_comp_mask and not self.if_config & POS_COMP_SEL

    def _write_smgp(self, data: int) -> None:
        self.smgp = data & SMGP_MASK
        self._wire()


def _legacy_read(index: int) -> Callable[[TMC4210], int]:
    return lambda chip: chip.legacy[index]


def _legacy_write(address: int) -> Callable[[TMC4210, int], None]:
    return lambda chip, data: chip._write_legacy(address, data)


def _write_pos_comp(chip: TMC4210, data: int) -> None:
    chip.pos_comp = data & MASK24


def _power_down(chip: TMC4210, data: int) -> None:
    chip.powered_down = True


#: The global registers' reads (an address not here reads 0).
_GLOBAL_READS: dict[int, Callable[[TMC4210], int]] = {
    **{address: _legacy_read(index) for index, address in enumerate(_LEGACY)},
    Reg.IF_CONFIGURATION: lambda chip: chip.if_config,
    Reg.POS_COMP: lambda chip: chip.pos_comp,
    Reg.POS_COMP_INT: lambda chip: chip.pos_comp_mask << 8 | chip.pos_comp_flag,
    Reg.TYPE_VERSION: lambda chip: TYPE_VERSION,
    Reg.REFERENCE_SWITCHES: TMC4210._reference_switches,
    Reg.SMGP: lambda chip: chip.smgp,
}

#: The global registers' writes (an address not here ignores them: TYPE_VERSION, ...).
_GLOBAL_WRITES: dict[int, Callable[[TMC4210, int], None]] = {
    **{address: _legacy_write(address) for address in _LEGACY},
    Reg.IF_CONFIGURATION: TMC4210._write_if_configuration,
    Reg.POS_COMP: _write_pos_comp,
    Reg.POS_COMP_INT: TMC4210._write_pos_comp_int,
    Reg.POWER_DOWN: _power_down,
    Reg.SMGP: TMC4210._write_smgp,
}
