"""A small TMC262 stepper driver: its five write registers, its status word, stallGuard2.

The TMC262 datasheet is not among our references; the register layout below is public
knowledge (Trinamic's TMC26x datasheet, as used by Trinamic's open-source stepRocker
firmware), and the load model is ours, marked [inferred] in ``docs/tmc429.md``.

Datagrams are 20 bits, MSB first.  Bits 19..17 select the register (DRVCTRL has bit 19 = 0):

* DRVCTRL, Step/Dir mode (SDOFF = 0): INTPOL 9, DEDGE 8, MRES 3..0 (0 = 256 microsteps ..
  8 = full step).  SPI mode (SDOFF = 1): PHA 17, CA 16..9, PHB 8, CB 7..0 (coil currents).
* CHOPCONF (%100): TBL 16..15, CHM 14, RNDTF 13, HDEC 12..11, HEND 10..7, HSTRT 6..4,
  TOFF 3..0 (TOFF = 0 switches the bridges off).
* SMARTEN (%101): SEIMIN 15, SEDN 14..13, SEMAX 11..8, SEUP 6..5, SEMIN 3..0 (coolStep).
* SGCSCONF (%110): SFILT 16, SGT 14..8 (signed), CS 4..0 (current scale (CS + 1) / 32).
* DRVCONF (%111): TST 16, SLPH 15..14, SLPL 13..12, DISS2G 10, TS2G 9..8, SDOFF 7,
  VSENSE 6, RDSEL 5..4.

Every datagram is answered, in the same transfer, with the 20-bit status word as it was when
the transfer began: bits 19..10 per RDSEL (0: MSTEP, the microstep position in the sine
table, 1: SG, the stallGuard2 value, 2: SG bits 9..5 and SE, the coolStep current), bits
7..0 the flags STST, OLB, OLA, S2GB, S2GA, OTPW, OT, SG.

The driver senses its motor through a :class:`MotorSense` (the TMC429 motor it is wired to):
the step pulses it has received, whether it stands still, and the world's load value at a
motor position.  It measures stallGuard2 at every full step it makes, from the load there;
nothing is measured at rest (the last value stays).  The driver keeps no clock of its own.
"""

from __future__ import annotations

from enum import IntEnum, IntFlag
from typing import Protocol, Self

from axes import stallguard
from axes.chips.tmc42x.registers import shallow_copy

DATAGRAM_BITS = 20
DATAGRAM_MASK = (1 << DATAGRAM_BITS) - 1
#: Microstep-table units (1/256 microsteps) per full step, and per electrical period.
FULLSTEP_UNITS = 256
PERIOD_UNITS = 4 * FULLSTEP_UNITS
SG_MAX = 1023
#: [inferred] stallGuard2 reading change per SGT count (a higher SGT reads higher: less
#: sensitive): the firmware model's law (axes/stallguard.py).
SG_PER_SGT = stallguard.THRESHOLD_STEP
#: The load value of a motor without a world around it: that of a free-running motor
#: (the same number as ``axes.world.DEFAULT_LOAD``).
UNLOADED = 500
#: Driver clocks without a step pulse after which STST is set (TMC26x datasheet).
STANDSTILL_CLOCKS = 1 << 20
#: Full-scale sense voltage in mV for VSENSE = 0 / 1.
SENSE_MV = (305, 165)


class DrvReg(IntEnum):
    """The register a datagram writes: its bits 19..17 (DRVCTRL: bit 19 = 0, bits 18..17 data)."""

    DRVCTRL = 0
    CHOPCONF = 0b100
    SMARTEN = 0b101
    SGCSCONF = 0b110
    DRVCONF = 0b111


class ReadSelect(IntEnum):
    """DRVCONF RDSEL: what bits 19..10 of the status word carry."""

    MSTEP = 0
    SG = 1
    SG_SE = 2


class DriverFlag(IntFlag):
    """Bits 7..0 of the status word."""

    SG = 1 << 0  # stallGuard2 reached zero at the last measurement
    OT = 1 << 1  # overtemperature shutdown
    OTPW = 1 << 2  # overtemperature pre-warning
    S2GA = 1 << 3  # short to ground, coil A
    S2GB = 1 << 4
    OLA = 1 << 5  # open load, coil A
    OLB = 1 << 6
    STST = 1 << 7  # standstill: no step pulse for 2**20 clocks


#: Flags a world (or a test) may force: the electrical faults.  SG and STST follow the motor.
FAULT_FLAGS = DriverFlag.OT | DriverFlag.OTPW | DriverFlag.S2GA | DriverFlag.S2GB \
    | DriverFlag.OLA | DriverFlag.OLB


def drv_datagram(reg: DrvReg, data: int) -> int:
    """A 20-bit TMC262 datagram: ``data`` in the bits below the register's address bits."""
    if reg == DrvReg.DRVCTRL:
        return data & 0x3FFFF
    return reg << 17 | (data & 0x1FFFF)


class MotorSense(Protocol):
    """What a driver senses of the motor it drives."""

    def sensed_steps(self) -> int:
        """Step pulses received so far, as a signed unwrapped count."""
        ...

    def sensed_standstill(self) -> bool:
        """No step pulse for at least ``STANDSTILL_CLOCKS`` driver clocks."""
        ...

    def sensed_load(self, steps: int) -> int:
        """The world's load value (stallGuard2 units at SGT 0; a blocked motor's lies below 0:
        axes.world.BLOCKED_LOAD) at motor position ``steps``."""
        ...

    def sequencer_units(self) -> int:
        """With SDOFF = 1: microstep-table units (1/256) the controller's sequencer makes per step."""
        ...


class TMC262:
    """One TMC262: host access is :meth:`spi` (20-bit datagrams), directly or through a chain."""

    def __init__(self) -> None:
        self.sense: MotorSense | None = None
        self.faults = DriverFlag(0)
        self.power_on()

    def power_on(self) -> None:
        """All registers 0 (TOFF = 0: bridges off), counters at 0, nothing measured yet."""
        self.drvctrl = 0
        self.chopconf = 0
        self.smarten = 0
        self.sgcsconf = 0
        self.drvconf = 0
        self._mscnt = 0  # unwrapped microstep-table position, 1/256 microsteps
        self.sg = 0
        self.measured = False
        self._se = 0
        self._above = 0  # measurements above coolStep's upper threshold not yet counted down
        self._seen_steps = self.sense.sensed_steps() if self.sense is not None else 0

    def attach(self, sense: MotorSense | None) -> None:
        """Wire the driver to a motor; steps made before count as already seen."""
        self.sense = sense
        self._seen_steps = sense.sensed_steps() if sense is not None else 0

    def registers(self) -> tuple[int, int, int, int, int]:
        """The five write registers (DRVCTRL, CHOPCONF, SMARTEN, SGCSCONF, DRVCONF)."""
        return self.drvctrl, self.chopconf, self.smarten, self.sgcsconf, self.drvconf

    def clone(self) -> Self:
        """A copy still wired to the same motor (the owner re-attaches it to a twin)."""
        return shallow_copy(self)

    # == fields ================================================================================

    @property
    def sdoff(self) -> bool:
        """SPI mode: DRVCTRL carries coil currents, the STEP input is ignored."""
        return bool(self.drvconf >> 7 & 1)

    @property
    def mres(self) -> int:
        return self.drvctrl & 0xF

    @property
    def microsteps(self) -> int:
        """Microsteps per full step in Step/Dir mode (MRES 0 = 256 .. 8 = 1; above 8 as 8)."""
        return FULLSTEP_UNITS >> min(self.mres, 8)

    @property
    def intpol(self) -> bool:
        return bool(self.drvctrl >> 9 & 1)

    @property
    def dedge(self) -> bool:
        return bool(self.drvctrl >> 8 & 1)

    @property
    def coil_currents(self) -> tuple[int, int]:
        """SPI mode: signed coil currents (A, B) as written, -255..255 (PHx = 1: negative)."""
        ca, cb = self.drvctrl >> 9 & 0xFF, self.drvctrl & 0xFF
        return (-ca if self.drvctrl >> 17 & 1 else ca), (-cb if self.drvctrl >> 8 & 1 else cb)

    @property
    def toff(self) -> int:
        return self.chopconf & 0xF

    @property
    def enabled(self) -> bool:
        """The bridges are on (TOFF != 0) and not shut down by overtemperature."""
        return self.toff != 0 and not self.faults & DriverFlag.OT

    @property
    def cs(self) -> int:
        return self.sgcsconf & 0x1F

    @property
    def sgt(self) -> int:
        value = self.sgcsconf >> 8 & 0x7F
        return value - 128 if value & 0x40 else value

    @property
    def sfilt(self) -> bool:
        return bool(self.sgcsconf >> 16 & 1)

    @property
    def vsense(self) -> bool:
        return bool(self.drvconf >> 6 & 1)

    @property
    def full_scale_mv(self) -> int:
        """Sense-resistor voltage at CS = 31: the board's R_SENSE turns it into amperes."""
        return SENSE_MV[self.vsense]

    @property
    def rdsel(self) -> int:
        return self.drvconf >> 4 & 3

    @property
    def semin(self) -> int:
        return self.smarten & 0xF

    @property
    def semax(self) -> int:
        return self.smarten >> 8 & 0xF

    @property
    def seimin(self) -> bool:
        return bool(self.smarten >> 15 & 1)

    @property
    def sedn(self) -> int:
        return self.smarten >> 13 & 3

    @property
    def seup(self) -> int:
        return self.smarten >> 5 & 3

    @property
    def se(self) -> int:
        """The coolStep current scale: CS without coolStep (SEMIN = 0), else what it adapted to."""
        if self.semin == 0:
            return self.cs
        self.observe()
        return max(self._se_floor(), min(self.cs, self._se))

    @property
    def current_scale(self) -> float:
        """Fraction of full-scale current the coils get now: (SE + 1) / 32, 0 with the bridges off."""
        return (self.se + 1) / 32 if self.enabled else 0.0

    def _se_floor(self) -> int:
        return stallguard.minimum_scale(self.cs, self.seimin)

    # == SPI ===================================================================================

    def spi(self, frame: int) -> int:
        """Exchange one 20-bit datagram: the answer is the status word from before the write."""
        answer = self.status_word()
        self.write(frame)
        return answer

    def write(self, frame: int) -> None:
        """Take a datagram (the end of a transfer, nCS rising)."""
        self.observe()  # steps so far count with the settings they were made with
        frame &= DATAGRAM_MASK
        if not frame >> 19:
            self.drvctrl = frame & 0x3FFFF
            return
        data = frame & 0x1FFFF
        match frame >> 17:
            case DrvReg.CHOPCONF:
                self.chopconf = data
            case DrvReg.SMARTEN:
                if not self.semin:
                    self._se = self.cs  # coolStep starts from the full current
                self.smarten = data & 0xEF6F
            case DrvReg.SGCSCONF:
                self.sgcsconf = data & 0x17F1F
            case DrvReg.DRVCONF:
                self.drvconf = data & 0x1F7F0

    def flags(self) -> DriverFlag:
        self.observe()
        flags = self.faults & FAULT_FLAGS
        if self.measured and self.sg == 0:
            flags |= DriverFlag.SG
        if self.sense is None or self.sense.sensed_standstill():
            flags |= DriverFlag.STST
        return flags

    def status_word(self) -> int:
        """The 20-bit answer a transfer starting now shifts out."""
        flags = self.flags()
        match self.rdsel:
            case ReadSelect.MSTEP:
                high = self._mscnt & 0x3FF
            case ReadSelect.SG:
                high = self.sg
            case ReadSelect.SG_SE:
                high = (self.sg >> 5) << 5 | self.se
            case _:
                high = 0
        return high << 10 | int(flags)

    # == the motor =============================================================================

    @property
    def mscnt(self) -> int:
        """The microstep-table position (1/256 microsteps, unwrapped; MSTEP is its low 10 bits)."""
        self.observe()
        return self._mscnt

    def stallguard(self) -> int:
        """The stallGuard2 value SG (0..1023) as the driver would report it now."""
        self.observe()
        return self.sg

    def _step_units(self) -> int:
        if self.sdoff:
            return self.sense.sequencer_units() if self.sense is not None else FULLSTEP_UNITS
        return 1 << min(self.mres, 8)

    def _sg_at(self, steps: int) -> int:
        load = self.sense.sensed_load(steps) if self.sense is not None else UNLOADED
        return stallguard.reading(load, self.sgt)

    def observe(self) -> None:
        """Catch up with the steps the motor made since the driver last looked.

        The microstep position advances by the step size in force; stallGuard2 is measured
        at the last full step crossed (SFILT = 0), or, filtered, as the mean over the four
        full steps of the last electrical period completed (SFILT = 1).  The motion since
        the last look is taken to be in one direction (a driver is looked at whenever the
        host talks to it, and a reversal in between only changes which loads were sampled).
        """
        if self.sense is None:
            return
        steps = self.sense.sensed_steps()
        delta = steps - self._seen_steps
        if delta == 0:
            return
        self._seen_steps = steps
        unit = self._step_units()
        start = self._mscnt
        end = start + delta * unit
        self._mscnt = end
        grid = PERIOD_UNITS if self.sfilt else FULLSTEP_UNITS
        if delta > 0:
            boundary = end - end % grid
            if boundary <= start:
                return
            at = steps - (end - boundary) // unit
            measurements = end // grid - start // grid
        else:
            boundary = -(-end // grid) * grid
            if boundary >= start:
                return
            at = steps + (boundary - end) // unit
            measurements = -(-start // grid) + -end // grid  # multiples in [end, start)
        if self.sfilt:
            back = -(FULLSTEP_UNITS // unit) if delta > 0 else FULLSTEP_UNITS // unit
            self.sg = sum(self._sg_at(at + k * back) for k in range(4)) // 4
        else:
            self.sg = self._sg_at(at)
        self.measured = True
        self._cool_step(measurements)

    def _cool_step(self, measurements: int) -> None:
        """coolStep after ``measurements`` stallGuard2 measurements that read ``sg`` (the
        measurements since the last look are taken to read alike): the TMC26x law of
        :func:`axes.stallguard.regulate` (SEUP increments per measurement below SEMIN * 32,
        one decrement per 32/8/2/1 measurements (SEDN) at or above (SEMIN + SEMAX + 1) * 32,
        between CS and half or a quarter of it (SEIMIN))."""
        if self.semin == 0:
            self._se, self._above = self.cs, 0
            return
        scale = max(self._se_floor(), min(self.cs, self._se))
        self._se, self._above = stallguard.regulate(
            scale, self._above, measurements, self.sg, self.semin, self.semax, self.seup,
            self.sedn, self.cs, self._se_floor())
