"""The TMCM-1111 (stepRocker servo): one axis, a TMC4361 motion controller and a TMC262
driver, as data.

Its firmware belongs to the TMCL family but numbers many axis parameters its own way, after
the TMC4361's registers: AP 14 is the ramp type, 15..21 the ramp's start velocity, start
acceleration, deceleration, break velocity, final deceleration, stop velocity and stop
deceleration, 22..25 the bows, 26..29 the virtual stops, 33/34 swap switches and soft stop,
108..138 the closed loop.  Rows whose meaning the firmware layer knows under another number
say so (``ParamSpec.firmware_number``): the axes run on the TMC4361A core with these
numbers translated.  Speeds are pps, accelerations pps^2 (unit mode 1; in unit mode 0 the
TMC4361's own register values: 1/256 pps, 1/4 pps^2).

The firmware manual (V1.05) is not among the project's references; sources, per row, are in
docs/modules.md ("TMCM-1111"): the numbers and names are pytrinamic's ``TMCM1111`` class
(0.2.26); what each does, its defaults and its limits come from Trinamic's open-source
TMCL-LITE-1111 firmware for this module (``Commands.c``, ``Globals.c``, ``TMC4361.c``), read
to learn facts, not copied.
"""

from __future__ import annotations

from tmcl_spec.commands import Opcode
from tmcl_spec.family import (
    ANALOG_FULL_SCALE,
    BANK2_PARAMETERS,
    BAUD_RATES,
    CAN_BIT_RATES,
    COORDINATES,
    DIGITAL_THRESHOLD,
    IO_MODE,
    LAST_TMCL_ERROR,
    PROGRAM_MEMORY,
    REFERENCE_SEARCH_MODES,
    STORABLE_USER_VARIABLES,
    axis_row,
    bank0,
    bank3,
    tmc262_rows,
)
from tmcl_spec.modules import FirmwareClock, ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN
from tmcl_spec.parameters import ACCESS, AP, AXIS, EVENTS, SETTING, Motion, ParamSpec

#: VMAX is 24.8 fixed point, signed 32 bit: the largest whole pps it holds (the firmware
#: shifts the pps value left by 8, TMCL-LITE-1111 ``ConvertVelocityUserToInternal``).
V_MAX = 2**23 - 1
#: Accelerations above 4 194 303 pps^2 (the 22.2 registers' limit) are written as direct
#: values (f^2 / 2^37 pps^2 each, at most 2^20 at 16 MHz): the largest is this.
A_MAX = 1_953_125_000
#: BOW1..BOW4: 24-bit registers, written raw.
BOW_MAX = 0xFF_FFFF
_BOOL = (0, 1)


def _p(number: int, name: str, access: str, motion: Motion, lo: int = INT32_MIN,
       hi: int = INT32_MAX, default: int = 0, firmware_number: int | None = None,
       allowed: frozenset[int] | None = None) -> ParamSpec:
    return axis_row(number, name, access, motion, lo, hi, default, allowed, firmware_number)


def _stored(number: int, name: str, access: str = "RW", lo: int = INT32_MIN,
            hi: int = INT32_MAX, default: int = 0) -> ParamSpec:
    """A row stored and read back whose number means something else to the firmware layer
    (the TMCM-6212's numbering): kept apart under ``AP.STORED + number``."""
    return _p(number, name, access, SETTING, lo, hi, default, AP.STORED + number)


AXIS_PARAMETERS: dict[int, ParamSpec] = {
    spec.number: spec
    for spec in (
        _p(0, "Target position", "RW", EVENTS),
        _p(1, "Actual position", "RW", AXIS),
        _p(2, "Target speed", "RW", SETTING, -V_MAX, V_MAX),
        _p(3, "Actual speed", "R", AXIS, -V_MAX, V_MAX),
        _p(4, "Maximum positioning speed", "RW", SETTING, 0, V_MAX, 51200),
        _p(5, "Maximum acceleration", "RW", SETTING, 0, A_MAX, 51200),
        _p(6, "Maximum current", "RW", SETTING, 0, 255, 128),
        _p(7, "Standby current", "RW", SETTING, 0, 255, 32),
        _p(8, "Position reached flag", "R", AXIS, *_BOOL),
        _p(9, "Home switch state", "R", EVENTS, *_BOOL),
        _p(10, "Right limit switch state", "R", EVENTS, *_BOOL),
        _p(11, "Left limit switch state", "R", EVENTS, *_BOOL),
        # bit 0: the switch stops the motor, bit 1: its polarity inverted; 0 at power-up
        _p(12, "Right limit switch enable / polarity", "RW", SETTING, 0, 3, 0, AP.RIGHT_LIMIT_SWITCH),
        _p(13, "Left limit switch enable / polarity", "RW", SETTING, 0, 3, 0, AP.LEFT_LIMIT_SWITCH),
        _p(14, "Ramp type (0 trapezoid, 1 S-shaped)", "RW", SETTING, *_BOOL, 0, AP.RAMP_TYPE),
        _p(15, "Start velocity", "RW", SETTING, 0, V_MAX, 0, AP.VSTART),
        _p(16, "Start acceleration", "RW", SETTING, 0, A_MAX, 25600, AP.A1),
        _p(17, "Maximum deceleration", "RW", SETTING, 0, A_MAX, 51200),
        _p(18, "Break velocity", "RW", SETTING, 0, V_MAX, 0, AP.V1),
        _p(19, "Final deceleration", "RW", SETTING, 0, A_MAX, 25600, AP.D1),
        _p(20, "Stop velocity", "RW", SETTING, 0, V_MAX, 0),
        _p(21, "Stop deceleration", "RW", SETTING, 0, A_MAX, 10000, AP.STOP_DECELERATION),
        _p(22, "Bow 1", "RW", SETTING, 0, BOW_MAX, 0, AP.BOW1),
        _p(23, "Bow 2", "RW", SETTING, 0, BOW_MAX, 0, AP.BOW2),
        _p(24, "Bow 3", "RW", SETTING, 0, BOW_MAX, 0, AP.BOW3),
        _p(25, "Bow 4", "RW", SETTING, 0, BOW_MAX, 0, AP.BOW4),
        _p(26, "Virtual stop left", "RW", SETTING, firmware_number=AP.VIRTUAL_STOP_LEFT),
        _p(27, "Virtual stop right", "RW", SETTING, firmware_number=AP.VIRTUAL_STOP_RIGHT),
        _p(28, "Virtual stop enable (bit 0 left, bit 1 right)", "RW", SETTING, 0, 3, 0,
           AP.VIRTUAL_STOP_ENABLE),
        _p(29, "Virtual stop mode", "RW", SETTING, 0, 3, 0, AP.VIRTUAL_STOP_MODE),
        _p(33, "Swap stop switches", "RW", SETTING, *_BOOL, 0, AP.SWAP_SWITCHES),
        _p(34, "Soft stop enable", "RW", SETTING, *_BOOL, 0, AP.SOFT_STOP),
        _p(35, "Bow scaling factor", "RW", SETTING, 0, 255, 0),
        _p(50, "Torque (closed loop)", "RW", SETTING),
        _p(108, "Closed loop gamma VMin", "RW", SETTING, 0, 0xFF_FFFF, 300000),
        _p(109, "Closed loop gamma VMax", "RW", SETTING, 0, 0xFF_FFFF, 600000),
        _p(110, "Closed loop maximum gamma", "RW", SETTING, 0, 255, 255),
        _p(111, "Closed loop beta", "RW", SETTING, 0, 511, 255),
        _p(112, "Closed loop offset", "RW", SETTING),
        _p(113, "Closed loop current scaler minimum", "RW", SETTING, 0, 255, 100),
        _p(114, "Closed loop current scaler maximum", "RW", SETTING, 0, 255, 240),
        _p(115, "Closed loop correction velocity P", "RW", SETTING, 0, INT32_MAX, 10000),
        _p(116, "Closed loop correction velocity I", "RW", SETTING, 0, INT32_MAX, 20),
        _p(117, "Closed loop correction velocity I clipping", "RW", SETTING, 0, 65535, 10),
        _p(118, "Closed loop correction velocity DV clock", "RW", SETTING, 0, 255, 0),
        _p(119, "Closed loop correction velocity DV clipping", "RW", SETTING, 0, INT32_MAX, 1073741823),
        _p(120, "Closed loop upscale delay", "RW", SETTING, 0, 0xFF_FFFF, 1000),
        _p(121, "Closed loop downscale delay", "RW", SETTING, 0, 0xFF_FFFF, 10000),
        _p(123, "Actual scaler value", "R", SETTING, 0, 255),
        _p(124, "Closed loop correction position P", "RW", SETTING, 0, INT32_MAX, 65536),
        _p(125, "Closed loop max. correction tolerance", "RW", SETTING, 0, INT32_MAX, 100),
        _p(126, "Closed loop start up current scaler", "RW", SETTING, 0, 255, 0),
        _p(127, "Relative positioning option", "RW", SETTING, 0, 2, 0),
        _p(129, "Closed loop mode", "RW", SETTING, *_BOOL),
        # the encoder velocity (V_ENC_MEAN / V_ENC): with the world's encoder on the motor
        # shaft, the motor's velocity
        _p(131, "Measured speed", "R", AXIS, -V_MAX, V_MAX, 0, AP.ACTUAL_SPEED),
        _p(132, "Current measured speed", "R", AXIS, -V_MAX, V_MAX, 0, AP.ACTUAL_SPEED),
        _p(133, "Closed loop init flag", "R", SETTING, *_BOOL),
        _p(134, "Positioning window", "RW", SETTING, 0, INT32_MAX, 100),
        _p(136, "Encoder mean wait", "RW", SETTING, 0, 255, 0),
        _p(137, "Encoder mean filter", "RW", SETTING, 0, 15, 7),
        _stored(138, "Encoder mean interval", "RW", 0, 65535, 500),
        _p(140, "Microstep resolution", "RW", SETTING, 0, 8, 8),
        _stored(150, "Encoder input sample rate", "RW", 0, 7, 0),
        _p(151, "Encoder input filter length", "RW", SETTING, 0, 7, 0),
        # the lite firmware's power-up stallGuard2: filter on, threshold 5 (TMC262.c lines
        # 310-311, as TMCL-LITE-1110's lines 256-257)
        *tmc262_rows(V_MAX, stallguard=(1, 5)),
        _p(193, "Reference search mode", "RW", SETTING, 1, 136, 1, allowed=REFERENCE_SEARCH_MODES),
        _p(194, "Reference search speed", "RW", SETTING, 0, V_MAX, 51200),
        _p(195, "Reference switch speed", "RW", SETTING, 0, V_MAX, 5120),
        _p(196, "End switch distance", "R", EVENTS),
        _p(197, "Last reference position", "R", EVENTS),
        _p(200, "Boost current", "RW", SETTING, 0, 255, 128),
        _p(201, "Encoder mode", "RW", SETTING, 0, 255, 0),
        _p(202, "Motor full step resolution", "RW", SETTING, 0, 65535, 200),
        _p(206, "Actual load value", "R", AXIS, 0, 1023),
        _p(207, "Error flags", "R", ACCESS, 0, 3),
        _p(208, "TMC262 status flags", "R", AXIS, 0, 255),
        _p(209, "Encoder position", "RW", AXIS),
        _p(210, "Encoder resolution", "RW", SETTING, 0, 65535, 4096),
        _p(212, "Maximum position encoder deviation", "RW", SETTING, 0, 65535, 0),
        _p(213, "Maximum velocity encoder deviation", "RW", SETTING, 0, INT32_MAX, 0),
        # STDBY_DELAY = value * 160000 clocks (10 ms units) must fit the 32-bit register
        _p(214, "Power down delay", "RW", SETTING, 0, 13421, 0),
        _p(251, "Reverse shaft", "RW", SETTING, *_BOOL),
        _p(253, "Step/direction gear ratio", "RW", SETTING),
        _p(254, "Step/direction mode", "RW", SETTING, 0, 15, 0),
        # 1: pps; 0: the TMC4361's own register units (TMCL-LITE-1111 Commands.c 1074-1097)
        _p(255, "Unit mode", "RW", SETTING, *_BOOL, 1),
    )
}

#: STAP/RSAP: the configuration rows (not positions, speeds being commanded, or readings).
STORABLE_AXIS_PARAMETERS = frozenset(
    n for n, spec in AXIS_PARAMETERS.items()
    if spec.writable and n not in (AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.TARGET_SPEED,
                                   AP.ENCODER_POSITION)
)

NUMBER_OF_INPUTS = 7  # IN0..IN6 (pytrinamic's IO names, as the stepRocker's)
NUMBER_OF_OUTPUTS = 8  # OUT0..OUT7
#: The encoder AP 209 counts when the world file names none: an ABN encoder of the
#: firmware's factory encoder resolution (AP 210 = 4096).
ENCODER_COUNTS_PER_REV = 4096

TMCM_1111 = ModuleType(
    key="tmcm-1111",
    name="TMCM-1111",
    module_number=1111,
    firmware=(1, 5),  # TMCM-1111 TMCL firmware manual V1.05 (2016)
    number_of_axes=1,
    axis_parameters=AXIS_PARAMETERS,
    global_parameters={0: bank0(IO_MODE, LAST_TMCL_ERROR), 2: BANK2_PARAMETERS,
                       3: bank3(switch_motors=1, inputs=NUMBER_OF_INPUTS)},
    storable_axis_parameters=STORABLE_AXIS_PARAMETERS,
    storable_user_variables=STORABLE_USER_VARIABLES,
    digital_inputs=NUMBER_OF_INPUTS,
    analog_inputs=NUMBER_OF_INPUTS,
    outputs=NUMBER_OF_OUTPUTS,
    coordinates=COORDINATES,
    program_memory=PROGRAM_MEMORY,
    chip_core="tmc4361a",
    commands=frozenset(Opcode),
    analog_full_scale=ANALOG_FULL_SCALE,
    digital_threshold=DIGITAL_THRESHOLD,
    supply_voltage_channel=None,
    encoder_counts_per_rev=ENCODER_COUNTS_PER_REV,
    baud_rates=BAUD_RATES,
    can_bit_rates=CAN_BIT_RATES,
    # TMCL-LITE-1111: the TMC4361 switches the current itself (STDBY_DELAY, Commands.c lines
    # 1048-1050), and its SystemControl leaves coolStep as AP 172 wrote it (lines 191-293).
    firmware_clock=FirmwareClock(current_in_pass=False, coolstep_by_speed=False),
)
