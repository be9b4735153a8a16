"""The TMC429 modules: TMCM-1110 (stepRocker), TMCM-3110, TMCM-6110, as data.

One TMC429 motion controller (two on the TMCM-6110) and one TMC262 driver per axis.  Their
firmware belongs to the TMCL family of the TMCM-6212 (same commands, same bank 0/2/3
layout) but is of the TMC429 generation: speeds and accelerations are the chip's own register
values (0..2047, no unit mode), PULSE_DIV and RAMP_DIV are axis parameters (AP 154 / 153),
and the TMC262's settings are axis parameters 160..184.

None of the three firmware manuals is among the project's references.  Sources, per row and
field, are listed in docs/modules.md: the parameter numbers and names come from pytrinamic's
``TMCM1110``/``TMCM3110``/``TMCM6110`` classes; ranges and access letters from the stepRocker
host library ``ap--/PyStepRocker`` (``TMCL.py``, taken from the TMCM-1110 manual) and the
stepRocker's open-source firmware (``emgab/stepRocker-Library``); defaults from that firmware
where it has them.  The tables are shared; each module adds or leaves out the rows its
pytrinamic class names.
"""

from __future__ import annotations

from typing import Any

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
    global_row,
    tmc262_rows,
    without_can,
)
from tmcl_spec.modules import FirmwareClock, ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN
from tmcl_spec.parameters import ACCESS, AP, AXIS, EVENTS, GP, SETTING, TASKS, Motion, ParamSpec

#: The TMC429's velocity and acceleration registers (11 bits): the firmware's units.
V_MAX = 2047
#: Its position registers (X_TARGET, X_ACTUAL) are 24 bits: AP 0/1's range (docs/modules.md).
POSITION_MAX = 2**23 - 1
A_MAX = 2047
DIVIDER_MAX = 13
_BOOL = (0, 1)


def _p(number: int, name: str, access: str, motion: Motion, lo: int = INT32_MIN,
       hi: int = INT32_MAX, default: int = 0, allowed: frozenset[int] | None = None) -> ParamSpec:
    return axis_row(number, name, access, motion, lo, hi, default, allowed)


#: Rows every TMC429 module has (pytrinamic names them for all three).  "E": STAP/RSAP store
#: them (PyStepRocker's access letters).
COMMON_AXIS_ROWS: tuple[ParamSpec, ...] = (
    _p(0, "Target (next) position", "RW", EVENTS, -POSITION_MAX, POSITION_MAX),
    _p(1, "Actual position", "RW", AXIS, -POSITION_MAX, POSITION_MAX),
    _p(2, "Target (next) speed", "RW", SETTING, -V_MAX, V_MAX),
    _p(3, "Actual speed", "R", AXIS, -V_MAX, V_MAX),
    _p(4, "Maximum positioning speed", "RWE", SETTING, 0, V_MAX, 1000),
    _p(5, "Maximum acceleration", "RWE", SETTING, 0, A_MAX, 500),
    _p(6, "Absolute max. current", "RWE", SETTING, 0, 255, 255),
    _p(7, "Standby current", "RWE", SETTING, 0, 255, 32),
    _p(8, "Target position reached", "R", AXIS, *_BOOL),
    _p(9, "Reference switch status", "R", EVENTS, *_BOOL),
    _p(10, "Right limit switch status", "R", EVENTS, *_BOOL),
    _p(11, "Left limit switch status", "R", EVENTS, *_BOOL),
    _p(12, "Right limit switch disable", "RWE", SETTING, *_BOOL),
    _p(13, "Left limit switch disable", "RWE", SETTING, *_BOOL),
    _p(130, "Minimum speed", "RWE", SETTING, 0, V_MAX, 1),
    _p(135, "Actual acceleration", "R", AXIS, 0, A_MAX),
    _p(138, "Ramp mode", "RWE", AXIS, 0, 2, 0),
    _p(140, "Microstep resolution", "RWE", SETTING, 0, 8, 8),
    _p(141, "Reference switch tolerance", "RW", SETTING, 0, 4095, 0),
    _p(149, "Soft stop flag", "RWE", SETTING, *_BOOL),
    _p(150, "End switch power down mode", "RWE", SETTING, *_BOOL),
    _p(153, "Ramp divisor", "RWE", SETTING, 0, DIVIDER_MAX, 3),
    _p(154, "Pulse divisor", "RWE", SETTING, 0, DIVIDER_MAX, 2),
    _p(160, "Step interpolation enable", "RW", SETTING, *_BOOL),
    _p(161, "Double step enable", "RW", SETTING, *_BOOL),
    *tmc262_rows(V_MAX),
    _p(193, "Reference search mode", "RWE", SETTING, 1, 136, 1, REFERENCE_SEARCH_MODES),
    _p(194, "Reference search speed", "RWE", SETTING, 0, V_MAX, 500),
    _p(195, "Reference switch speed", "RWE", SETTING, 0, V_MAX, 50),
    _p(196, "Distance end switches", "R", EVENTS),
    _p(204, "Freewheeling delay", "RWE", SETTING, 0, 65535, 0),
    _p(206, "Actual load value", "R", TASKS, 0, 1023),  # read in the pass
    _p(207, "Extended error flags", "R", ACCESS, 0, 3),
    _p(208, "TMC262 driver error flags", "R", TASKS, 0, 255),
    _p(213, "Group index", "RW", SETTING, 0, 255, 0),
    _p(214, "Power down delay", "RWE", SETTING, 1, 65535, 200),
    # Not a parameter of these modules: MVP REL counts from the actual position (the
    # stepRocker firmware and the TMCL reference), i.e. the TMCM-6212's AP 127 = 1.
    _p(AP.RELATIVE_POSITIONING_OPTION, "(fixed) MVP REL from the actual position", "",
       SETTING, 1, 1, 1),
)

#: Rows only some modules have (as their pytrinamic classes name them).
LAST_REFERENCE = _p(197, "Last reference switch position", "R", EVENTS)
BOOST_CURRENT = _p(200, "Boost current", "RWE", SETTING, 0, 255, 0)
ENCODER_MODE = _p(201, "Encoder mode", "RWE", SETTING, 0, 255, 0)
ENCODER_ROWS = (
    _p(209, "Encoder position", "RW", AXIS),
    # AP 209 = encoder counts * prescaler / 512; 512: the counts themselves (docs/modules.md).
    # The whole positive 32-bit value: published programs for the TMCM-3110 write 4674113.
    _p(210, "Encoder prescaler", "RWE", SETTING, 0, INT32_MAX, 512),
    _p(212, "Maximum encoder deviation", "RWE", SETTING, 0, 65535, 0),
)
STEP_DIRECTION_MODE = _p(254, "Step/direction mode", "RWE", SETTING, 0, 2, 0)
#: The sensOstep encoder of the TMCM-1140/1160/1161: 1024 counts per turn, AP 209 counts
#: AP 210 / 512 per count, 25600 (50) by default: AP 209 in microsteps at 256 microsteps
#: (TMCM-1161 manual V1.19 §6.2, TMCM-1021 manual V1.42 §6.2.1).
SENSOSTEP_COUNTS_PER_REV = 1024
SENSOSTEP_ROWS = (
    _p(209, "Encoder position", "RW", AXIS),
    _p(210, "Encoder prescaler", "RWE", SETTING, 0, 65535, 25600),
    _p(212, "Maximum encoder deviation", "RWE", SETTING, 0, 65535, 0),
    _p(AP.ABSOLUTE_ENCODER, "Absolute resolver value", "R", AXIS, 0,
       SENSOSTEP_COUNTS_PER_REV - 1),
)
#: An external encoder's rows (TMCM-1140/1160): stored and read back, no encoder behind them.
EXTERNAL_ENCODER_ROWS = (
    _p(AP.EXTERNAL_ENCODER_POSITION, "External encoder position", "RW", SETTING),
    _p(AP.EXTERNAL_ENCODER_PRESCALER, "External encoder prescaler", "RWE", SETTING, 0, 65535,
       512),
    _p(AP.EXTERNAL_ENCODER_MAX_DEVIATION, "External encoder max. deviation", "RWE", SETTING,
       0, 65535, 0),
)


def axis_table(*extra: ParamSpec, without: frozenset[int] = frozenset()) -> dict[int, ParamSpec]:
    """The common rows and ``extra``, by number, except the rows ``without``."""
    return {spec.number: spec for spec in (*COMMON_AXIS_ROWS, *extra) if spec.number not in without}


def storable(table: dict[int, ParamSpec]) -> frozenset[int]:
    return frozenset(n for n, spec in table.items() if spec.storable)


AXIS_PARAMETERS_1110 = axis_table(*ENCODER_ROWS, STEP_DIRECTION_MODE)
AXIS_PARAMETERS_3110 = axis_table(LAST_REFERENCE, BOOST_CURRENT, ENCODER_MODE, *ENCODER_ROWS,
                                  STEP_DIRECTION_MODE)
AXIS_PARAMETERS_6110 = axis_table(LAST_REFERENCE, BOOST_CURRENT)
#: The one-axis modules of the TMCM-1140 generation have no group index (neither pytrinamic
#: nor the TMCL-IDE-derived lists name AP 213 for them).
_NO_GROUP = frozenset({AP.GROUP_INDEX})
AXIS_PARAMETERS_1140 = axis_table(LAST_REFERENCE, BOOST_CURRENT, *SENSOSTEP_ROWS,
                                  *EXTERNAL_ENCODER_ROWS, without=_NO_GROUP)
AXIS_PARAMETERS_1160 = axis_table(LAST_REFERENCE, BOOST_CURRENT, *SENSOSTEP_ROWS,
                                  *EXTERNAL_ENCODER_ROWS, STEP_DIRECTION_MODE, without=_NO_GROUP)
AXIS_PARAMETERS_1161 = axis_table(LAST_REFERENCE, BOOST_CURRENT, *SENSOSTEP_ROWS,
                                  STEP_DIRECTION_MODE, without=_NO_GROUP)
AXIS_PARAMETERS_1141 = axis_table(LAST_REFERENCE, BOOST_CURRENT, STEP_DIRECTION_MODE,
                                  without=_NO_GROUP)


# -- global parameters -------------------------------------------------------------------------

#: Bank 0 rows of the TMC429 modules beyond the TMCM-6212's (pytrinamic's GP0 names).
END_SWITCH_POLARITY = global_row(GP.END_SWITCH_POLARITY, "End switch polarity", "RWA", SETTING,
                                 0, 1, 0)
REVERSE_SHAFT = global_row(GP.REVERSE_SHAFT_DIRECTION, "Reverse shaft direction", "RWA",
                           SETTING, 0, 1, 0)
#: The 1140 generation's (TMCM-1140/1141/1160/1161): the ASCII interface chosen for the next
#: power-up (stored only: no ASCII interface here); with the family's last command error.
ASCII_MODE = global_row(GP.ASCII_MODE, "ASCII mode", "RWA", SETTING, 0, 1, 0)


# -- I/O --------------------------------------------------------------------------------------

#: ``GIO 8, 1``: the supply voltage in 0.1 V (pytrinamic's ``VIN = 8``, TMCM-Lib's TMCM-3110).
SUPPLY_VOLTAGE_CHANNEL = 8
NOMINAL_SUPPLY_VOLTAGE = 24.0
#: The TMCM-1160's supply: "up to 48 V" (manual V1.47's title page).
NOMINAL_SUPPLY_VOLTAGE_1160 = 48.0


# -- the profiles ------------------------------------------------------------------------------

#: What the three modules have in common (each profile adds its own).
_FAMILY: dict[str, Any] = dict(
    storable_user_variables=STORABLE_USER_VARIABLES,
    outputs=8,
    coordinates=COORDINATES,
    program_memory=PROGRAM_MEMORY,
    chip_core="tmc429",
    commands=frozenset(Opcode),
    analog_full_scale=ANALOG_FULL_SCALE,
    digital_threshold=DIGITAL_THRESHOLD,
    nominal_supply_voltage=NOMINAL_SUPPLY_VOLTAGE,
    baud_rates=BAUD_RATES,  # the TMCL family's GP 65 and GP 69 (inferred)
    can_bit_rates=CAN_BIT_RATES,
    # The stepRocker's firmware (TMCL-LITE-1110): the pass also stops a stalled motor, from
    # the TMC262's stall output (SysControl.c lines 106-114).
    firmware_clock=FirmwareClock(stall_in_pass=True),
)

TMCM_1110 = ModuleType(
    key="tmcm-1110",
    name="TMCM-1110",
    module_number=1110,
    firmware=(1, 9),  # TMCM-1110 TMCL firmware manual V1.09
    number_of_axes=1,
    axis_parameters=AXIS_PARAMETERS_1110,
    global_parameters={0: bank0(IO_MODE, END_SWITCH_POLARITY, REVERSE_SHAFT), 2: BANK2_PARAMETERS,
                       3: bank3(switch_motors=3, inputs=7)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_1110),
    digital_inputs=7,
    analog_inputs=7,
    supply_voltage_channel=SUPPLY_VOLTAGE_CHANNEL,  # as the family (docs/modules.md)
    **_FAMILY,
)

TMCM_3110 = ModuleType(
    key="tmcm-3110",
    name="TMCM-3110",
    module_number=3110,
    firmware=(1, 14),  # the manual TMCM-Lib's TMCM-3110 class was written against
    number_of_axes=3,
    axis_parameters=AXIS_PARAMETERS_3110,
    global_parameters={0: bank0(END_SWITCH_POLARITY, REVERSE_SHAFT), 2: BANK2_PARAMETERS,
                       3: bank3(switch_motors=3, inputs=8)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_3110),
    digital_inputs=8,
    analog_inputs=8,
    analog_channels=frozenset({0, 4}),  # AIN0, AIN4
    pullup_ports=1,  # SIO 0, 0, 0|1: the limit switches' pull-ups (TMCM-Lib)
    supply_voltage_channel=SUPPLY_VOLTAGE_CHANNEL,
    **_FAMILY,
)

TMCM_6110 = ModuleType(
    key="tmcm-6110",
    name="TMCM-6110",
    module_number=6110,
    firmware=(1, 46),  # TMCM-6110 TMCL firmware manual V1.46 (2021)
    number_of_axes=6,
    axis_parameters=AXIS_PARAMETERS_6110,
    global_parameters={0: bank0(END_SWITCH_POLARITY, REVERSE_SHAFT), 2: BANK2_PARAMETERS,
                       3: bank3(switch_motors=6, inputs=8)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_6110),
    digital_inputs=8,
    analog_inputs=8,
    analog_channels=frozenset({0, 4}),  # AIN0, AIN4
    pullup_ports=1,
    supply_voltage_channel=SUPPLY_VOLTAGE_CHANNEL,
    **_FAMILY,
)


# -- the 1140 generation: one axis, a TMC429 and a TMC262, sensOstep encoder ----------------

#: Bank 0 of the one-axis modules of the TMCM-1140 generation (pytrinamic's GP0 names, and
#: the TMCL-IDE-derived lists of ``analogdevicesinc/tmcl_ros``: GP 67 and 131).
BANK0_1140 = bank0(END_SWITCH_POLARITY, REVERSE_SHAFT, ASCII_MODE, LAST_TMCL_ERROR)

#: What the four have in common (one axis on a TMC429, pull-ups, the supply on GIO 8, 1).
_ONE_AXIS: dict[str, Any] = dict(
    _FAMILY,
    number_of_axes=1,
    outputs=2,  # OUT0, OUT1
    pullup_ports=1,  # SIO 0, 0, 0|1: the stop switches' pull-ups
    supply_voltage_channel=SUPPLY_VOLTAGE_CHANNEL,
)

TMCM_1140 = ModuleType(
    key="tmcm-1140",
    name="TMCM-1140",
    module_number=1140,
    firmware=(1, 27),  # TMCM-1140 TMCL firmware manual V1.27 (2013/2015)
    axis_parameters=AXIS_PARAMETERS_1140,
    global_parameters={0: BANK0_1140, 2: BANK2_PARAMETERS, 3: bank3(switch_motors=1, inputs=4)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_1140),
    digital_inputs=4,  # IN0..IN3
    analog_inputs=4,
    encoder_counts_per_rev=SENSOSTEP_COUNTS_PER_REV,
    **_ONE_AXIS,
)

TMCM_1160 = ModuleType(
    key="tmcm-1160",
    name="TMCM-1160",
    module_number=1160,
    firmware=(1, 47),  # TMCM-1160 TMCL firmware manual V1.47 (2021)
    axis_parameters=AXIS_PARAMETERS_1160,
    global_parameters={0: BANK0_1140, 2: BANK2_PARAMETERS, 3: bank3(switch_motors=1, inputs=2)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_1160),
    digital_inputs=2,  # IN0, IN1
    analog_inputs=2,
    encoder_counts_per_rev=SENSOSTEP_COUNTS_PER_REV,
    **{**_ONE_AXIS, "nominal_supply_voltage": NOMINAL_SUPPLY_VOLTAGE_1160},
)

TMCM_1141 = ModuleType(
    key="tmcm-1141",
    name="TMCM-1141",
    module_number=1141,
    firmware=(1, 19),  # TMCM-1141 TMCL firmware manual V1.19 (2012)
    axis_parameters=AXIS_PARAMETERS_1141,
    global_parameters={0: without_can(BANK0_1140), 2: BANK2_PARAMETERS,
                       3: bank3(switch_motors=1, inputs=4)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_1141),
    digital_inputs=4,
    analog_inputs=4,
    # IN3 is GIO port 4 (pytrinamic's TMCM1141.IO: IN0..IN2 = 0..2, IN3 = 4, where its 1140
    # and 1161 classes say 3; docs/modules.md, "TMCM-1141: IN3")
    input_ports=(0, 1, 2, 4),
    has_can=False,  # USB, RS485 and Step/Dir (hardware manual's title)
    **_ONE_AXIS,
)

TMCM_1161 = ModuleType(
    key="tmcm-1161",
    name="TMCM-1161",
    module_number=1161,
    firmware=(1, 24),  # TMCM-1161 TMCL firmware manual V1.24 (2013)
    axis_parameters=AXIS_PARAMETERS_1161,
    global_parameters={0: without_can(BANK0_1140), 2: BANK2_PARAMETERS,
                       3: bank3(switch_motors=1, inputs=4)},
    storable_axis_parameters=storable(AXIS_PARAMETERS_1161),
    digital_inputs=4,
    analog_inputs=4,
    has_can=False,  # USB, RS485 and RS232 (manual's title)
    encoder_counts_per_rev=SENSOSTEP_COUNTS_PER_REV,
    **_ONE_AXIS,
)
