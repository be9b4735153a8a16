"""The TMC429 core: the TMCL firmware's TMC429 and TMC262 routines, and the axes built on them.

The TMC429 modules (TMCM-1110 stepRocker, TMCM-3110, TMCM-6110) run the TMC429 in Step/Dir
mode and reach each motor's TMC262 driver over the microcontroller's own SPI, not through the
TMC429's driver chain (the stepRocker's open-source firmware does so; docs/modules.md).

* :class:`TMC429Driver` is the chip-specific half of an axis's firmware
  (:class:`axes.core.ChipDriver`): the TMC42x routines it shares with the TMC4210 core
  (:class:`axes.chips.tmc42x.firmware.TMC42xDriver`) on its motor's registers (``motor << 4 | IDX``),
  the TMC429's set-up and its switch register.  It talks to the chip only through 32-bit SPI
  datagrams to the chip all its axes share.
* :class:`TMC262Link` is the firmware's TMC262 routines for one axis
  (:class:`axes.core.MotorDriverLink`): the microstep, current, chopper, stallGuard2 and coolStep
  parameters are written to the TMC262 as 20-bit datagrams, AP 206/180/208 are read back from
  its status word.  stallGuard2 and coolStep are therefore the TMC262 model's
  (axes/chips/tmc42x/tmc262.py, which regulates with the law of axes/stallguard.py): one implementation.
* :class:`TMC429Axis` joins a driver to :class:`axes.firmware.AxisFirmware`;
  :meth:`TMC429Axis.build_axes` builds a module's axes three to a chip.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from axes.board import AxisBoard
from axes.chips.tmc42x.firmware import TMC42xDriver
from axes.chips.tmc42x.registers import DEFAULT_CLOCK_HZ, HALF24
from axes.chips.tmc42x.tmc262 import TMC262, DriverFlag, DrvReg, ReadSelect, drv_datagram
from axes.chips.tmc42x.tmc429 import EN_REFR, EN_SD, NUMBER_OF_MOTORS, SDO_INT, TMC429, Reg, TMC429Motor
from axes.core import ChipModel, MotorDriverLink
from axes.firmware import AxisFirmware
from axes.interface import Axis
from axes.world import AxisWorld
from tmcl_spec.numbers import to_signed
from tmcl_spec.parameters import AP, ParamSpec

#: IF_CONFIGURATION at power-up: Step/Dir outputs, a right switch input per motor (REFR1..3),
#: nINT on its own pin (the stepRocker firmware's Init429).
IF_CONFIGURATION_FIRMWARE = EN_SD | EN_REFR | SDO_INT
#: SMGP at power-up: LSMD = 2 (three motors), as the stepRocker firmware writes it.
SMGP_FIRMWARE = 0x000002
#: The firmware reads the TMC262's stallGuard2 value (RDSEL = 1) between its other reads.
READ_SELECT = ReadSelect.SG
#: V_TARGET is a 12-bit two's complement register.
V_TARGET_BITS = 12


class TMC262Link(MotorDriverLink):
    """The firmware's TMC262 routines for one axis: software copies in, datagrams out.

    The registers are composed from the axis parameters (the firmware keeps them as its
    software copies) and sent over the microcontroller's SPI (:meth:`TMC429Motor.driver_spi`);
    every answer is the driver's status word.
    """

    #: AP -> the TMC262 register it is a field of.
    REGISTER_OF: dict[int, DrvReg] = {
        AP.MICROSTEPS: DrvReg.DRVCTRL, AP.STEP_INTERPOLATION: DrvReg.DRVCTRL,
        AP.DOUBLE_STEP: DrvReg.DRVCTRL,
        **dict.fromkeys((AP.CHOPPER_BLANK_TIME, AP.CONSTANT_TOFF_MODE,
                         AP.DISABLE_FAST_DECAY_COMPARATOR, AP.CHOPPER_HYSTERESIS_END,
                         AP.CHOPPER_HYSTERESIS_START, AP.CHOPPER_OFF_TIME, AP.RANDOM_TOFF_MODE),
                        DrvReg.CHOPCONF),
        **dict.fromkeys((AP.SMARTENERGY_CURRENT_MINIMUM, AP.SMARTENERGY_CURRENT_DOWN_STEP,
                         AP.SMARTENERGY_HYSTERESIS, AP.SMARTENERGY_CURRENT_UP_STEP,
                         AP.SMARTENERGY_HYSTERESIS_START), DrvReg.SMARTEN),
        AP.STALLGUARD_FILTER: DrvReg.SGCSCONF, AP.STALLGUARD_THRESHOLD: DrvReg.SGCSCONF,
        **dict.fromkeys((AP.SLOPE_CONTROL_HIGH_SIDE, AP.SLOPE_CONTROL_LOW_SIDE,
                         AP.SHORT_PROTECTION_DISABLE, AP.SHORT_DETECTION_TIMER, AP.VSENSE),
                        DrvReg.DRVCONF),
    }

    def __init__(self, params: Mapping[int, int], motor: TMC429Motor) -> None:
        self.params = params
        self.motor = motor
        self.parameters = frozenset(self.REGISTER_OF)
        #: coolStep is switched on (SEMIN is written as AP 172; else 0: off).
        self.regulating = False
        self._current = 0  # CS as last written
        #: What the firmware's last pass read from the driver: SG, SE, flags (Read262State).
        self._sampled = (0, 0, 0)

    def _get(self, number: int) -> int:
        return self.params.get(number, 0)

    def _send(self, reg: DrvReg) -> int:
        return self.motor.driver_spi(drv_datagram(reg, self._data(reg)))

    def _data(self, reg: DrvReg) -> int:
        """The register's contents from the software copies (the TMC26x datasheet's fields)."""
        get = self._get
        if reg == DrvReg.DRVCTRL:  # Step/Dir mode: INTPOL, DEDGE, MRES = 8 - AP 140
            return get(AP.STEP_INTERPOLATION) << 9 | get(AP.DOUBLE_STEP) << 8 | (8 - get(AP.MICROSTEPS))
        if reg == DrvReg.CHOPCONF:
            return (get(AP.CHOPPER_BLANK_TIME) << 15 | get(AP.CONSTANT_TOFF_MODE) << 14
                    | get(AP.RANDOM_TOFF_MODE) << 13 | get(AP.DISABLE_FAST_DECAY_COMPARATOR) << 11
                    | get(AP.CHOPPER_HYSTERESIS_END) << 7
                    | min(get(AP.CHOPPER_HYSTERESIS_START), 7) << 4 | get(AP.CHOPPER_OFF_TIME))
        if reg == DrvReg.SMARTEN:
            semin = get(AP.SMARTENERGY_HYSTERESIS_START) if self.regulating else 0
            return (get(AP.SMARTENERGY_CURRENT_MINIMUM) << 15
                    | get(AP.SMARTENERGY_CURRENT_DOWN_STEP) << 13 | get(AP.SMARTENERGY_HYSTERESIS) << 8
                    | get(AP.SMARTENERGY_CURRENT_UP_STEP) << 5 | semin)
        if reg == DrvReg.SGCSCONF:
            return (get(AP.STALLGUARD_FILTER) << 16 | (get(AP.STALLGUARD_THRESHOLD) & 0x7F) << 8
                    | self._current)
        return (get(AP.SLOPE_CONTROL_HIGH_SIDE) << 14 | get(AP.SLOPE_CONTROL_LOW_SIDE) << 12
                | get(AP.SHORT_PROTECTION_DISABLE) << 10 | get(AP.SHORT_DETECTION_TIMER) << 8
                | get(AP.VSENSE) << 6 | READ_SELECT << 4)

    # == MotorDriverLink =======================================================================

    def configure(self, number: int | None = None) -> None:
        """Write the register ``number`` belongs to, or (None) all five in the stepRocker
        firmware's order: SMARTEN, SGCSCONF, DRVCONF, DRVCTRL, CHOPCONF."""
        if number is None:
            self._current = self._get(AP.MAX_CURRENT) >> 3
            for reg in (DrvReg.SMARTEN, DrvReg.SGCSCONF, DrvReg.DRVCONF, DrvReg.DRVCTRL,
                        DrvReg.CHOPCONF):
                self._send(reg)
            return
        self._send(self.REGISTER_OF[number])

    def set_current(self, value: int) -> None:
        """CS = current / 8 (0..255 -> 0..31), as the stepRocker firmware scales AP 6."""
        if value >> 3 != self._current:
            self._current = value >> 3
            self._send(DrvReg.SGCSCONF)

    def switch_coolstep(self, on: bool) -> None:
        if on != self.regulating:
            self.regulating = on
            self._send(DrvReg.SMARTEN)

    def _poll(self) -> int:
        """A datagram that changes nothing (DRVCONF again), for the status word it answers."""
        return self._send(DrvReg.DRVCONF)

    def observe(self) -> None:
        """The model's driver measures when it is looked at (tmc262.py): a datagram that
        changes nothing makes it catch up (the real one measures as the motor goes)."""
        self._poll()

    def sample(self, chip: ChipModel | None = None) -> None:
        """SG and the flags (RDSEL = 1), then SE with RDSEL = 2 for one datagram (then back)."""
        own = self.motor
        if isinstance(chip, TMC429Motor):
            self.motor = chip  # a copy of this motor (axes/tasks.py, T2)
        try:
            word = self._poll()
            drvconf = self._data(DrvReg.DRVCONF) & ~(3 << 4)
            self.motor.driver_spi(drv_datagram(DrvReg.DRVCONF, drvconf | ReadSelect.SG_SE << 4))
            se = self._send(DrvReg.DRVCONF) >> 10 & 0x1F
        finally:
            self.motor = own
        self._sampled = (word >> 10, se, word & 0xFF)

    def load(self) -> int:
        return self._sampled[0]

    def flags(self) -> int:
        return self._sampled[2]

    def stalled(self) -> bool:
        return bool(self._poll() & DriverFlag.SG)

    def current_scale(self) -> int:
        return self._sampled[1]


class TMC429Driver(TMC42xDriver):
    """The firmware's routines for one motor of a TMC429 (an :class:`axes.core.ChipDriver`)."""

    chip_name = "TMC429"
    #: AP 0 and AP 1 are the chip's 24-bit X_TARGET and X_ACTUAL, sign-extended (TMCL-LITE-1110
    #: Commands.c lines 488-496, 734-741: ``Read429Int``/``Write429Int``): positions wrap at
    #: +-2**23, as the TMC429 modules' manuals give their range (docs/modules.md).
    position_bits = 24

    def __init__(self, index: int, params: Mapping[int, int], board: AxisBoard, chip: TMC429,
                 motor: int) -> None:
        model = chip.motor(motor)
        model.board = board  # the motor's switches and mechanics are this axis's
        model.set_pins(*board.pins(model.motor_position))
        super().__init__(index, params, board, model, motor)
        #: The axis's TMC262, on the microcontroller's SPI (None: a Step/Dir output only).
        self.motor_driver = TMC262Link(params, model) if model.driver is not None else None

    def read_position(self) -> int:
        """AP 1: X_ACTUAL as it is, sign-extended from 24 bits (no 32-bit count)."""
        x = self.chip.spi_data(self._read_x_actual)
        self._x_last = x
        self.position = x - ((x & HALF24) << 1)
        return self.position

    def _counted(self, xs: list[int]) -> list[int]:
        """AP 1 after each of the X_ACTUAL reads ``xs``: each sign-extended, the last kept."""
        positions = [x - ((x & HALF24) << 1) for x in xs]
        self._x_last, self.position = xs[-1], positions[-1]
        return positions

    def register_access(self, address: int, value: int | None = None) -> int:
        """Commands 146/147 on a TMC429 axis: addresses 0x00..0x0F are this axis's own motor
        registers (IDX); 0x10..0x7F go to its chip unchanged (the other motors' registers,
        the global registers, the RAM), as the SPI address says (docs/modules.md)."""
        if address < 0x10:
            address |= self._base
        return super().register_access(address, value)

    def setup_chip(self) -> None:
        """Step/Dir, right switches on REFR, nINT on its own pin; the TMC262 configured."""
        self._write_global(Reg.IF_CONFIGURATION, IF_CONFIGURATION_FIRMWARE)
        self._write_global(Reg.SMGP, SMGP_FIRMWARE)
        if self.motor_driver is not None:
            self.motor_driver.configure()

    def levels(self) -> tuple[bool, bool, bool]:
        """(left, right) from REFERENCE_SWITCHES (motor m: r at bit 2m, l at 2m + 1); the
        home switch is not a TMC429 input: the microcontroller reads it from its own pin."""
        switches = self._read_global(Reg.REFERENCE_SWITCHES) >> 2 * self.motor
        home = self.board.pins(self.chip.motor_position)[2]
        return bool(switches & 2), bool(switches & 1), home


class TMC429Axis(AxisFirmware):
    """One axis of a TMC429 module: the TMCL firmware layer over a TMC429 motor and its TMC262."""

    def __init__(self, index: int, parameters: Mapping[int, ParamSpec],
                 world: AxisWorld | None = None, clock_hz: int | None = None, *,
                 chip: TMC429 | None = None, motor: int | None = None) -> None:
        if chip is None:  # an axis of its own: motor 0 of a chip with one TMC262
            clock = DEFAULT_CLOCK_HZ if clock_hz is None else clock_hz
            chip, motor = TMC429(clock, drivers=[TMC262()]), 0
        slot = index % NUMBER_OF_MOTORS if motor is None else motor
        super().__init__(index, parameters, world,
                         lambda params, board: TMC429Driver(index, params, board, chip, slot))

    @classmethod
    def build_axes(cls, count: int, parameters: Mapping[int, ParamSpec],
                   clock_hz: int | None = None) -> list[Axis]:
        """A module's ``count`` axes, three to a TMC429 (two chips for six), each with a TMC262."""
        clock = DEFAULT_CLOCK_HZ if clock_hz is None else clock_hz
        chips: Sequence[TMC429] = [
            TMC429(clock, drivers=[TMC262() for _ in range(min(NUMBER_OF_MOTORS, count - first))])
            for first in range(0, count, NUMBER_OF_MOTORS)]
        return [cls(index, parameters, chip=chips[index // NUMBER_OF_MOTORS],
                    motor=index % NUMBER_OF_MOTORS) for index in range(count)]

    def rotate(self, velocity: int) -> bool:
        """ROR/ROL in the chip's units (no unit mode) write the 12-bit V_TARGET as it is
        (TMCL-LITE-1110 Commands.c lines 401 and 420: ``Write429Short(IDX_VTARGET, value)``),
        so ROR 3000 runs left at 1096 and AP 2 reads -1096 (docs/modules.md, "ROR beyond
        2047")."""
        if not self._params[AP.UNIT_MODE]:
            velocity = to_signed(velocity, V_TARGET_BITS)
        return super().rotate(velocity)

    def get_parameter(self, number: int) -> int:
        """AP 9 is the reference switch status: the left switch, the one the TMC429 calls
        the reference switch (as AP 11), not a home input (docs/modules.md, "AP 9")."""
        return super().get_parameter(AP.LEFT_SWITCH if number == AP.HOME_SWITCH else number)
