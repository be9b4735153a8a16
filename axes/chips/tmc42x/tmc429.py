"""One TMC429: three motors behind one SPI interface, and its SPI driver chain.

Sources: ``shared/spec/tmc429.md`` (the digest; section numbers below are its own) and the
datasheet; choices where they are silent are in ``docs/tmc429.md``.

Design
------
* :class:`TMC429` is the chip: the global registers (SMDA %11: the driver-chain read-back
  and cover datagram, IF_CONFIGURATION, position compare, POWER_DOWN, TYPE_VERSION, the
  reference-switch register, SMGP), the 128 words of RAM, the status byte and :meth:`spi`.
* Each motor is a :class:`TMC429Motor`: the shared TMC42x motor core
  (:class:`axes.chips.tmc42x.engine.MotorEngine`: axis registers, switches, latch, interrupts, ramp and
  pulse engine, identical to the TMC4210's) plus the motor's own board, its driver (a
  :class:`axes.chips.tmc42x.tmc262.TMC262` or nothing) and its own time ``t``.  A write to one motor's
  registers never touches another; the chip pushes what its global registers mean for a
  motor (Step/Dir or chain, switch layout, ``inv_ref``, position compare, power-down) into
  the motor as wiring attributes.
* ``chip.motor(i)`` *is* a :class:`axes.core.ChipModel` for one axis: ``spi`` goes to the
  shared chip, while ``run``, ``clone``, ``at_rest``, ``t``, ``motor_position`` and
  ``set_pins`` concern that motor only.  Motors move independently, each at its own pace:
  running motor 0 to tick 10**6 leaves motor 1 where it was.  A global write acts on every
  motor at the tick that motor has reached, so a firmware that wants a global change to
  happen at one instant for all motors brings them to that instant first (``advance``).
* Looking ahead: ``motor.clone()`` copies the whole chip (the twin's other motors are
  snapshots) and returns the twin's motor; running it moves nothing in the real chip.
  Nothing a motor does while running touches chip-level state, so ``motor.adopt(twin)``
  can copy the twin's state (and its driver's) into the live motor; it refuses a twin that
  is stale (a global register, or this motor's registers, were written since the clone, or
  the twin was written to, or it is behind the live motor).
* The driver chain (``en_sd = 0``, the power-on mode) is materialised only when the host can
  see it: a cover datagram is sent at once (the chain is idle at frame granularity) and
  configures the drivers; the read-back registers capture the drivers' answers at a cover
  datagram, or at the first frame after a re-arm while a chain motor moves or
  ``continuous_update`` is set.  The datagram's bits come from the RAM configuration words
  and the microstep sequencer of each motor, exactly as §5 and §6 describe.
* In Step/Dir mode (``en_sd = 1``, how the TMCL modules run it) a motor's driver is reached
  by the microcontroller directly: ``chip.motor(i).driver.spi(frame)`` (20-bit TMC262 frames).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from enum import IntEnum
from math import floor, pi, sin

from axes.chips.tmc42x.engine import MotorEngine
from axes.chips.tmc42x.registers import (
    DEFAULT_CLOCK_HZ,
    MASK24,
    Reg,
    datagram,
    shallow_copy,
)
from axes.chips.tmc42x.tmc262 import DATAGRAM_BITS, STANDSTILL_CLOCKS, TMC262, UNLOADED
from axes.core import Board, StaleLookahead, Stop

TYPE_VERSION = 0x429101
NUMBER_OF_MOTORS = 3
SMGP_POWER_ON = 0x000F00  # CLK2_DIV = 15, everything else 0
SMGP_MASK = 0x31FFFF
IF_CONFIG_MASK = 0x1FF
#: IS_AGTAT 22..20, IS_ALEAT 18..16, IS_V0 14..12, A_THRESHOLD 10..0.
A_THRESHOLD_MASK = 0x7777FF
RAM_WORDS = 128
CHAIN_CONFIG_WORDS = 64
#: Ticks of continuous rest after which the driver's STST shows (driver clock = chip clock).
STANDSTILL_TICKS = STANDSTILL_CLOCKS // 32
MASK48 = (1 << 48) - 1




def motor_address(motor: int, reg: Reg | int) -> int:
    """The 7-bit address of axis register ``reg`` of motor 0..2 (``SMDA << 4 | IDX``)."""
    if not 0 <= motor < NUMBER_OF_MOTORS:
        raise ValueError(f"motor {motor} outside 0..{NUMBER_OF_MOTORS - 1}")
    return motor << 4 | reg


RAM_ADDRESS = 0x40  # 7-bit address of RAM word pair 0; pair A holds words 2A (bits 5..0), 2A+1 (13..8)

# IF_CONFIGURATION bits.
INV_REF = 1 << 0
SDO_INT = 1 << 1
STEP_HALF = 1 << 2
INV_STP = 1 << 3
INV_DIR = 1 << 4
EN_SD = 1 << 5
POS_COMP_SEL_SHIFT = 6
EN_REFR = 1 << 8
# SMGP bits.
LSMD_MASK = 3
POLARITY_PH_AB = 1 << 4
POLARITY_FD_AB = 1 << 5
POLARITY_DAC_AB = 1 << 6
CONTINUOUS_UPDATE = 1 << 16
REFMUX = 1 << 20
MOT1R = 1 << 21
# COVER_POS_LEN fields.
COVER_LEN_MASK = 0x1F
COVER_POS_SHIFT = 8
COVER_POS_MASK = 0x3F
COVER_WAITING = 1 << 23


class Signal(IntEnum):
    """The 5-bit signal codes of a driver-chain configuration word (§5.2)."""

    DAC_A0 = 0x00  # .. DAC_A5 = 0x05
    PH_A = 0x06
    FD_A = 0x07
    DAC_B0 = 0x08  # .. DAC_B5 = 0x0D
    PH_B = 0x0E
    FD_B = 0x0F
    ZERO = 0x10
    ONE = 0x11
    DIRECTION = 0x12
    STEP = 0x13


NXM = 1 << 5  # a configuration word's "last bit of this motor" flag

#: Power-on chain configuration (§6.4): per driver, the 12-bit TMC236/239/246/249 datagram
#: ``MDA CA3 CA2 CA1 CA0 PHA MDB CB3 CB2 CB1 CB0 PHB``, three times; words 36..63 are 0.
POR_CHAIN_WORDS = (0x11, 0x05, 0x04, 0x03, 0x02, 0x06, 0x11, 0x0D, 0x0C, 0x0B, 0x0A, 0x2E) * 3

#: Power-on microstep table (§6.3: the datasheet's standard sine; its "sine with offset" POR
#: values are not given): floor(0.5 + 64 sin(2 pi i / 256)), clamped to 63.
POR_SINE_TABLE = tuple(min(63, floor(0.5 + 64 * sin(2 * pi * i / 256))) for i in range(64))

#: (ph_a, ph_b, fd_a, fd_b) per quadrant of the 256-step electrical period (§6.2).
QUADRANT_BITS = ((1, 1, 0, 1), (1, 0, 1, 0), (0, 0, 0, 1), (0, 1, 1, 0))

#: Significant DAC bits per USRS (§6.1): microstep resolutions below 64 drop low bits.
DAC_MASK = {usrs: (0x3F << (6 - usrs)) & 0x3F for usrs in range(1, 7)}


class StaleTwin(StaleLookahead):
    """``adopt`` was given a twin computed from a chip state that no longer holds."""


class TMC429Motor(MotorEngine):
    """One motor of a TMC429, and the :class:`axes.core.ChipModel` of its axis."""

    a_threshold_mask = A_THRESHOLD_MASK

    def __init__(self, chip: TMC429, index: int, board: Board | None = None,
                 driver: TMC262 | None = None) -> None:
        self.chip = chip
        self.index = index
        self.driver = driver
        #: SPI writes to this motor's registers (a lookahead twin must not miss one).
        self.writes = 0
        self._origin_writes = 0
        #: Tick at which the motor last came to rest (None while it moves).
        self.rest_since: int | None = 0
        super().__init__(chip.clock_hz, board)
        if driver is not None:
            driver.attach(self)

    # == the ChipModel of one axis =============================================================

    def spi(self, frame: int) -> int:
        """A datagram to the chip (any register: the SPI interface is shared)."""
        return self.chip.spi(frame)

    def spi_data(self, frame: int) -> int:
        """The 24 data bits of the chip's answer to a datagram (the driver's reads)."""
        return self.chip.spi_data(frame)

    def reads_are_quiet(self) -> bool:
        """A frame wakes every motor of the chip and ends a cover or capture under way (CDGW:
        a frame may send the chain datagram, :meth:`TMC429._service_chain`)."""
        chip = self.chip
        return not chip.cdgw and not any(motor.powered_down for motor in chip.motors)

    def read(self, reg: Reg | int) -> int:
        """Convenience: the 24 data bits of one of this motor's axis registers."""
        return self.chip.read(motor_address(self.index, reg))

    def write(self, reg: Reg | int, data: int) -> None:
        self.chip.write(motor_address(self.index, reg), data)

    def run(self, until: int, budget: int | None = None) -> Stop | None:
        """Advance this motor (only) to tick ``until``; return early at a notable instant
        (or, with a work ``budget``, short of ``until`` when it runs out: MotorEngine.run)."""
        moving = self.v != 0
        x_before = self.x_actual
        stop = super().run(until, budget)
        if self.v:
            self.rest_since = None
        elif moving or self.x_actual != x_before or self.rest_since is None:
            self.rest_since = self.t  # run() returns at the instant a motion ends
        return stop

    def driver_spi(self, frame: int) -> int:
        """A 20-bit datagram on the microcontroller's own SPI to this motor's driver (the
        Step/Dir modules); its answer.  A write that changes a driver register counts as a
        write to this motor (a lookahead twin made before it is stale)."""
        driver = self.driver
        if driver is None:
            return 0
        before = driver.registers()
        answer = driver.spi(frame)
        if driver.registers() != before:
            self.writes += 1
        return answer

    def set_pins(self, ref_l: bool, ref_r: bool, gp_in: bool = False) -> None:
        """Drive this motor's (left, right, home) switch levels; the layout decides which count."""
        super().set_pins(ref_l, ref_r, gp_in)
        self.note_rest()

    def clone(self) -> TMC429Motor:
        """This motor of a copy of the whole chip: run it to look ahead."""
        return self.chip.clone().motors[self.index]

    def adopt(self, twin: TMC429Motor) -> TMC429Motor:
        """Continue with the state a lookahead twin (made by :meth:`clone`) reached.

        The twin's motor state (and its driver's) is copied into this live motor, so every
        reference to the motor and its driver stays valid; returns ``self``.  Raises
        :class:`StaleTwin` if the chip's global registers or RAM, or this motor's registers,
        were written since the clone, if the twin was written to, or if it is behind.
        """
        chip = self.chip
        origin = twin.chip
        if (twin.index != self.index or origin._origin_chip is not chip
                or origin.revision != origin._origin_revision or origin._origin_revision != chip.revision
                or twin.writes != twin._origin_writes or twin._origin_writes != self.writes
                or twin.t < self.t):
            raise StaleTwin(f"motor {self.index}: the chip changed since the lookahead was cloned")
        driver = self.driver
        state = dict(twin.__dict__)
        state["chip"] = chip
        state["driver"] = driver
        self.__dict__.update(state)
        if driver is not None and twin.driver is not None:
            driver.__dict__.update(twin.driver.__dict__)
            driver.sense = self
        return self

    def _clone_into(self, chip: TMC429, continued: bool) -> TMC429Motor:
        """This motor in ``chip``, a copy of its chip (``continued``: a copy of an unchanged
        copy, which names the same origin: then its writes are counted from that one's, and a
        written copy's copy never fits)."""
        twin = shallow_copy(self)
        twin.chip = chip
        if not continued:
            twin._origin_writes = self.writes
        elif self.writes != self._origin_writes:
            twin._origin_writes = -1
        if self.driver is not None:
            twin.driver = self.driver.clone()
            twin.driver.sense = twin
        return twin

    # == rest, sensing =========================================================================

    def note_rest(self) -> None:
        """Keep ``rest_since`` after a change that did not come from :meth:`run`."""
        if self.v:
            self.rest_since = None
        elif self.rest_since is None:
            self.rest_since = self.t

    def sensed_steps(self) -> int:
        return self.motor_position

    def sensed_standstill(self) -> bool:
        return self.v == 0 and self.rest_since is not None and self.t - self.rest_since >= STANDSTILL_TICKS

    def sensed_load(self, steps: int) -> int:
        load = getattr(self.board, "load", None)
        return load(steps) if load is not None else UNLOADED

    def sequencer_units(self) -> int:
        """1/256 microsteps per step of the TMC429's sequencer (USRS: 2**USRS steps per full step)."""
        return 256 >> min(self.usrs, 6)

    # == current scaling (SPI mode, §7) ========================================================

    def i_scale(self) -> int:
        """I_SCALE (0 = 8/8, 1..7 = n/8) the sequencer applies now."""
        is_agtat = self.a_threshold >> 20 & 7
        is_aleat = self.a_threshold >> 16 & 7
        if self.v == 0:
            settled = self.rest_since is not None and self.t - self.rest_since >= 255 << self.ramp_div
            if settled and is_agtat and is_aleat:
                return self.a_threshold >> 12 & 7
            return is_aleat
        return is_agtat if abs(self.a_actual) > self.a_threshold & 0x7FF else is_aleat

    def sequencer_bits(self, table: Sequence[int], smgp: int) -> dict[int, int]:
        """The value of every signal code for this motor now (§5.2, §6.2)."""
        w = self.ustep_count
        quadrant, r = w >> 6, w & 63

        def lut(i: int) -> int:
            return 63 if i == 64 else table[i]

        if self.usrs == 0:
            dac_a = dac_b = 63  # [inferred] full step: constant amplitude
        elif quadrant % 2 == 0:
            dac_a, dac_b = lut(r), lut(64 - r)
        else:
            dac_a, dac_b = lut(64 - r), lut(r)
        factor = self.i_scale() or 8
        mask = DAC_MASK.get(min(self.usrs, 6), 0x3F)
        dac_a = (dac_a * factor >> 3) & mask
        dac_b = (dac_b * factor >> 3) & mask
        if smgp & POLARITY_DAC_AB:
            dac_a ^= 0x3F
            dac_b ^= 0x3F
        ph_a, ph_b, fd_a, fd_b = QUADRANT_BITS[quadrant]
        if smgp & POLARITY_PH_AB:
            ph_a, ph_b = ph_a ^ 1, ph_b ^ 1
        if smgp & POLARITY_FD_AB:
            fd_a, fd_b = fd_a ^ 1, fd_b ^ 1
        bits = {Signal.DAC_A0 + k: dac_a >> k & 1 for k in range(6)}
        bits.update({Signal.DAC_B0 + k: dac_b >> k & 1 for k in range(6)})
        bits.update({Signal.PH_A: ph_a, Signal.PH_B: ph_b, Signal.FD_A: fd_a, Signal.FD_B: fd_b,
                     Signal.ZERO: 0, Signal.ONE: 1, Signal.DIRECTION: int(self.v < 0),
                     Signal.STEP: 0})
        return bits


class TMC429:
    """The chip: three :class:`TMC429Motor` and the global registers behind one :meth:`spi`."""

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, boards: Sequence[Board | None] = (),
                 drivers: Sequence[TMC262 | None] = ()) -> None:
        if clock_hz <= 0:
            raise ValueError("clock frequency must be positive")
        if len(boards) > NUMBER_OF_MOTORS or len(drivers) > NUMBER_OF_MOTORS:
            raise ValueError(f"a TMC429 has {NUMBER_OF_MOTORS} motors")
        self.clock_hz = clock_hz
        #: Global writes so far (a lookahead twin must not miss one).
        self.revision = 0
        self._origin_revision = 0
        self._origin_chip: TMC429 | None = None
        boards = [*boards, *[None] * (NUMBER_OF_MOTORS - len(boards))]
        drivers = [*drivers, *[None] * (NUMBER_OF_MOTORS - len(drivers))]
        self.motors = [TMC429Motor(self, i, boards[i], drivers[i]) for i in range(NUMBER_OF_MOTORS)]
        self.power_on()

    def motor(self, index: int) -> TMC429Motor:
        """Motor 0..2: the ChipModel of one axis (the same object for the chip's lifetime)."""
        return self.motors[index]

    # == power-on ==============================================================================

    def power_on(self) -> None:
        """All registers 0 except CLK2_DIV = 15 (SPI mode, one driver); RAM with its defaults."""
        self.if_config = 0
        self.smgp = SMGP_POWER_ON
        self.pos_comp = 0
        self.pos_comp_mask = False
        self.ram = [*POR_CHAIN_WORDS, *[0] * (CHAIN_CONFIG_WORDS - len(POR_CHAIN_WORDS)),
                    *POR_SINE_TABLE]
        self.cover_pos = 0
        self.cover_len = 0
        self.cover_datagram = 0
        self.cover_pending = False  # written, not yet sent (no chain in Step/Dir mode)
        self.capture = 0  # DATAGRAM_HIGH:DATAGRAM_LOW, a 48-bit shift register
        self.capture_armed = False
        self._cover_echo = False  # sent at once: CDGW still shows in the next frame
        self._capture_echo = False
        for motor in self.motors:
            motor.powered_down = False
            motor.pos_comp_flag = False
            motor.reset_motor()
            motor.rest_since = motor.t
        self._wire()

    def clone(self) -> TMC429:
        """An independent copy of the chip, its motors and drivers."""
        twin = shallow_copy(self)
        twin.ram = list(self.ram)
        # a copy of an unchanged copy continues the same chip: adopted by that one (F9 in
        # axes/forecast.py: the chip goes on from a copy of its look-ahead's copy)
        continued = self._origin_chip is not None and self.revision == self._origin_revision
        if not continued:
            twin._origin_revision = self.revision
            twin._origin_chip = self
        twin.motors = [motor._clone_into(twin, continued) for motor in self.motors]
        return twin

    def advance(self, until: int) -> list[tuple[int, int, Stop]]:
        """Run every motor to tick ``until``; the notable instants on the way as (motor, tick, why)."""
        seen = []
        for motor in self.motors:
            while motor.t < until:
                stop = motor.run(until)
                if stop is not None:
                    seen.append((motor.index, motor.t, stop))
        return seen

    # == derived state =========================================================================

    @property
    def en_sd(self) -> bool:
        return bool(self.if_config & EN_SD)

    @property
    def lsmd(self) -> int:
        """Index of the last motor in the driver chain (LSMD %11 is forbidden: taken as 2)."""
        return min(self.smgp & LSMD_MASK, 2)

    @property
    def interrupt(self) -> bool:
        return (any(m.int_flags for m in self.motors)
                or (self.pos_comp_mask and any(m.pos_comp_flag for m in self.motors)))

    @property
    def nint(self) -> bool:
        """The nINT pin (low active; with ``sdo_int`` on the QFN32 package it is nINT_SDO_C)."""
        return not self.interrupt

    @property
    def cdgw(self) -> bool:
        return self.cover_pending or self.capture_armed or self._cover_echo or self._capture_echo

    def status_byte(self) -> int:
        status = self.interrupt << 7 | self.cdgw << 6
        for motor in self.motors:
            status |= (motor.left_active << 1 | motor.at_target) << 2 * motor.index
        return status

    def reference_switches(self) -> int:
        """REFERENCE_SWITCHES: per motor m, r at bit 2m and l at bit 2m+1 (active, wired)."""
        value = 0
        for motor in self.motors:
            value |= (motor.right_active | motor.left_active << 1) << 2 * motor.index
        return value

    def _wire(self) -> None:
        """Tell each motor what the global registers mean for it (§9.1, §11)."""
        en_sd = self.en_sd
        refmux = bool(self.smgp & REFMUX) and not en_sd  # the mux select is nSCS_S: SPI mode only
        both = refmux or bool(self.if_config & EN_REFR)
        mot1r = bool(self.smgp & MOT1R)
        selected = self.if_config >> POS_COMP_SEL_SHIFT & 3
        lsmd = self.lsmd
        for i, motor in enumerate(self.motors):
            if both:
                left, right = True, True
            elif mot1r:  # "two-one-zero": REF3 is motor 1's right switch
                left, right = i < 2, i == 0
            else:
                left, right = True, False
            motor.pos_comp = self.pos_comp
            motor.rewire(steps_out=en_sd or i <= lsmd, inv_ref=bool(self.if_config & INV_REF),
                         left_wired=left, right_wired=right,
                         pos_comp_on=self.pos_comp_mask and selected == i)
            motor.note_rest()

    # == SPI ===================================================================================

    def spi(self, frame: int) -> int:
        """Exchange one 32-bit datagram; returns the chip's 32-bit answer.

        Status and read data are sampled at the start of the frame and a write takes effect
        at its end (nSCS rising edge).  A frame wakes the chip from power-down.  SDO_C (SDOZ_C)
        always carries the answer: on the QFN32 package ``sdo_int`` only moves nINT to its pin.
        """
        for motor in self.motors:
            motor.powered_down = False
        return self.status_byte() << 24 | self._exchange(frame)

    def spi_data(self, frame: int) -> int:
        """The 24 data bits of ``spi(frame)``'s answer: the same frame with the same effects,
        without sampling the status byte (the firmware's reads ignore it; a program's GAP 1
        reads the position through here every time)."""
        for motor in self.motors:
            motor.powered_down = False
        return self._exchange(frame) & MASK24

    def _exchange(self, frame: int) -> int:
        """What a frame does after the status byte is sampled; its 24 answer bits."""
        cover_waiting = self.cover_pending or self._cover_echo
        self._cover_echo = self._capture_echo = False
        self._service_chain()
        read = bool(frame >> 24 & 1)
        data = frame & MASK24
        address = frame >> 25 & 0x7F
        answer = 0
        if address & 0x40:
            word = 2 * (address & 0x3F)
            if read:
                answer = self.ram[word] | self.ram[word + 1] << 8
            else:
                self.ram[word] = data & 0x3F
                self.ram[word + 1] = data >> 8 & 0x3F
                self.revision += 1
        elif address < 0x30:
            motor = self.motors[address >> 4]
            if read:
                answer = motor.read_motor(address & 0xF)
            else:
                motor.write_motor(address & 0xF, data)
                motor.writes += 1
                motor.note_rest()
        elif read:
            answer = self._read(address, cover_waiting)
        else:
            self._write(address, data)
            self.revision += 1
        return answer

    def read(self, reg: int) -> int:
        """Convenience: the 24 data bits of a register read."""
        return self.spi(datagram(reg, read=True)) & MASK24

    def write(self, reg: int, data: int) -> None:
        self.spi(datagram(reg, data))

    def _read(self, address: int, cover_waiting: bool) -> int:
        if address == Reg.COVER_POS_LEN:
            return (cover_waiting << 23
                    | ((self.cover_pos + 1) & COVER_POS_MASK) << COVER_POS_SHIFT | self.cover_len)
        read = _GLOBAL_READS.get(address)
        return 0 if read is None else read(self)

    def _write(self, address: int, data: int) -> None:
        write = _GLOBAL_WRITES.get(address)
        if write is not None:
            write(self, data)

    def _arm_capture(self, data: int) -> None:
        """DATAGRAM_LOW/HIGH written: the capture is re-armed (and completes at once while
        datagrams flow)."""
        self.capture = 0
        self.capture_armed = True
        if self._chain_busy():
            self._transmit()
            self._capture_echo = True

    def _write_cover_pos_len(self, data: int) -> None:
        self.cover_pos = data >> COVER_POS_SHIFT & COVER_POS_MASK
        self.cover_len = data & COVER_LEN_MASK

    def _write_cover_datagram(self, data: int) -> None:
        self.cover_datagram = data
        self.cover_pending = True
        if not self.en_sd:  # "sent immediately" (the chain is idle at frame granularity)
            self._transmit()
            self._cover_echo = True

    def _write_if_configuration(self, data: int) -> None:
        self.if_config = data & IF_CONFIG_MASK
        self._wire()
        if not self.en_sd and self.cover_pending:
            self._transmit()
            self._cover_echo = True

    def _write_pos_comp(self, data: int) -> None:
        self.pos_comp = data & MASK24
        for motor in self.motors:
            motor.pos_comp = self.pos_comp

    def _write_pos_comp_int(self, data: int) -> None:
        self.pos_comp_mask = bool(data >> 8 & 1)
        if data & 1 or not self.pos_comp_mask:
            for motor in self.motors:
                motor.pos_comp_flag = False
        selected = self.if_config >> POS_COMP_SEL_SHIFT & 3
        for motor in self.motors:
            motor.pos_comp_on = self.pos_comp_mask and selected == motor.index

    def _power_down(self, data: int) -> None:
        for motor in self.motors:
            motor.powered_down = True

    def _write_smgp(self, data: int) -> None:
        self.smgp = data & SMGP_MASK
        self._wire()

    # == the driver chain (§5) =================================================================

    def _chain_busy(self) -> bool:
        """Datagrams are flowing: SPI mode and a chain motor moving, or continuous update."""
        if self.en_sd:
            return False
        if self.smgp & CONTINUOUS_UPDATE:
            return True
        return any(m.v != 0 for m in self.motors[:self.lsmd + 1])

    def _service_chain(self) -> None:
        """At a frame: a re-armed capture completes if datagrams are flowing."""
        if self.capture_armed and self._chain_busy():
            self._transmit()

    def chain_datagram(self) -> list[int]:
        """The bits the chain would be sent now, in transmission order (without a cover)."""
        table = self.ram[CHAIN_CONFIG_WORDS:]
        signals = [motor.sequencer_bits(table, self.smgp) for motor in self.motors]
        bits = []
        motor = 0
        for word in self.ram[:CHAIN_CONFIG_WORDS]:
            bits.append(signals[motor].get(word & 0x1F, 0))
            if word & NXM:
                if motor >= self.lsmd:
                    break
                motor += 1
        return bits  # no NxM reaching LSMD: the chip would send endlessly; 64 bits here

    def _transmit(self) -> None:
        """Send one chain datagram (with the pending cover datagram spliced in) and capture."""
        bits = self.chain_datagram()
        if self.cover_pending:
            for k in range(self.cover_len):
                position = self.cover_pos + k
                if position < len(bits):
                    bits[position] = self.cover_datagram >> (self.cover_len - 1 - k) & 1
            self.cover_pending = False
        received = self._shift_through_drivers(bits)
        for bit in received:
            self.capture = (self.capture << 1 | bit) & MASK48
        self.capture_armed = False

    def _shift_through_drivers(self, bits: list[int]) -> list[int]:
        """Shift ``bits`` through the daisy chain; returns what arrives back on SDI_S.

        SDO_S feeds the driver of the highest motor; motor 0's driver is last and answers
        first.  Each driver loaded its status word when the transfer began; after the
        transfer each keeps the last 20 bits that reached it.
        """
        chain = [m.driver for m in self.motors if m.driver is not None]
        if not chain:
            return [0] * len(bits)
        register: list[int] = []
        for driver in chain:  # from the output end (motor 0) towards SDO_S
            word = driver.status_word()
            register += [word >> (DATAGRAM_BITS - 1 - k) & 1 for k in range(DATAGRAM_BITS)]
        stream = register + bits
        received = stream[:len(bits)]
        kept = stream[len(bits):]
        for k, driver in enumerate(chain):
            word = 0
            for bit in kept[k * DATAGRAM_BITS:(k + 1) * DATAGRAM_BITS]:
                word = word << 1 | bit
            driver.write(word)
        return received


#: The global registers' reads but COVER_POS_LEN (an address not here reads 0).
_GLOBAL_READS: dict[int, Callable[[TMC429], int]] = {
    Reg.DATAGRAM_LOW: lambda chip: chip.capture & MASK24,
    Reg.DATAGRAM_HIGH: lambda chip: chip.capture >> 24 & MASK24,
    Reg.COVER_DATAGRAM: lambda chip: chip.cover_datagram,
    Reg.IF_CONFIGURATION: lambda chip: chip.if_config,
    Reg.POS_COMP: lambda chip: chip.pos_comp,
    Reg.POS_COMP_INT: lambda chip: (chip.pos_comp_mask << 8
                                          | any(m.pos_comp_flag for m in chip.motors)),
    Reg.TYPE_VERSION: lambda chip: TYPE_VERSION,
    Reg.REFERENCE_SWITCHES: TMC429.reference_switches,
    Reg.SMGP: lambda chip: chip.smgp,
}

#: The global registers' writes (an address not here ignores them: TYPE_VERSION, ...).
_GLOBAL_WRITES: dict[int, Callable[[TMC429, int], None]] = {
    Reg.DATAGRAM_LOW: TMC429._arm_capture,
    Reg.DATAGRAM_HIGH: TMC429._arm_capture,
    Reg.COVER_POS_LEN: TMC429._write_cover_pos_len,
    Reg.COVER_DATAGRAM: TMC429._write_cover_datagram,
    Reg.IF_CONFIGURATION: TMC429._write_if_configuration,
    Reg.POS_COMP: TMC429._write_pos_comp,
    Reg.POS_COMP_INT: TMC429._write_pos_comp_int,
    Reg.POWER_DOWN: TMC429._power_down,
    Reg.SMGP: TMC429._write_smgp,
}
