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
from tmcl_spec.modules import ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN
from tmcl_spec.parameters import AP, GP, ParamSpec
from tmcl_spec.tmcm6212 import BANK0_PARAMETERS as TMCM6212_BANK0
from tmcl_spec.tmcm6212 import BANK2_PARAMETERS, REFERENCE_SEARCH_MODES, STORABLE_USER_VARIABLES
from tmcl_spec.tmcm6212 import BAUD_RATES as TMCM6212_BAUD_RATES
from tmcl_spec.tmcm6212 import CAN_BIT_RATES as TMCM6212_CAN_BIT_RATES

#: The TMC429's velocity and acceleration registers (11 bits): the firmware's units.
V_MAX = 2047
A_MAX = 2047
DIVIDER_MAX = 13
_BOOL = (0, 1)


def _p(number: int, name: str, access: str, lo: int = INT32_MIN, hi: int = INT32_MAX,
       default: int = 0, allowed: frozenset[int] | None = None) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, allowed)


#: Rows every TMC429 module has (pytrinamic names them for all three).  "E": STAP/RSAP store
#: them (PyStepRocker's access letters).
COMMON_AXIS_ROWS: tuple[ParamSpec, ...] = (
    _p(0, "Target (next) position", "RW"),
    _p(1, "Actual position", "RW"),
    _p(2, "Target (next) speed", "RW", -V_MAX, V_MAX),
    _p(3, "Actual speed", "R", -V_MAX, V_MAX),
    _p(4, "Maximum positioning speed", "RWE", 0, V_MAX, 1000),
    _p(5, "Maximum acceleration", "RWE", 0, A_MAX, 500),
    _p(6, "Absolute max. current", "RWE", 0, 255, 255),
    _p(7, "Standby current", "RWE", 0, 255, 32),
    _p(8, "Target position reached", "R", *_BOOL),
    _p(9, "Reference switch status", "R", *_BOOL),
    _p(10, "Right limit switch status", "R", *_BOOL),
    _p(11, "Left limit switch status", "R", *_BOOL),
    _p(12, "Right limit switch disable", "RWE", *_BOOL),
    _p(13, "Left limit switch disable", "RWE", *_BOOL),
    _p(130, "Minimum speed", "RWE", 0, V_MAX, 1),
    _p(135, "Actual acceleration", "R", 0, A_MAX),
    _p(138, "Ramp mode", "RWE", 0, 2, 0),
    _p(140, "Microstep resolution", "RWE", 0, 8, 8),
    _p(141, "Reference switch tolerance", "RW", 0, 4095, 0),
    _p(149, "Soft stop flag", "RWE", *_BOOL),
    _p(150, "End switch power down mode", "RWE", *_BOOL),
    _p(153, "Ramp divisor", "RWE", 0, DIVIDER_MAX, 3),
    _p(154, "Pulse divisor", "RWE", 0, DIVIDER_MAX, 2),
    _p(160, "Step interpolation enable", "RW", *_BOOL),
    _p(161, "Double step enable", "RW", *_BOOL),
    _p(162, "Chopper blank time", "RW", 0, 3, 2),
    _p(163, "Chopper mode", "RW", *_BOOL),
    _p(164, "Chopper hysteresis decrement", "RW", 0, 3, 0),
    _p(165, "Chopper hysteresis end", "RW", 0, 15, 2),
    _p(166, "Chopper hysteresis start", "RW", 0, 8, 3),
    _p(167, "Chopper off time", "RW", 0, 15, 5),
    _p(168, "smartEnergy current minimum", "RW", *_BOOL),
    _p(169, "smartEnergy current down step", "RW", 0, 3, 0),
    _p(170, "smartEnergy hysteresis", "RW", 0, 15, 0),
    _p(171, "smartEnergy current up step", "RW", 0, 3, 0),
    _p(172, "smartEnergy hysteresis start", "RW", 0, 15, 0),
    _p(173, "stallGuard2 filter enable", "RW", *_BOOL),
    _p(174, "stallGuard2 threshold", "RW", -64, 63, 0),
    _p(175, "Slope control high side", "RW", 0, 3, 3),
    _p(176, "Slope control low side", "RW", 0, 3, 3),
    _p(177, "Short protection disable", "RW", *_BOOL),
    _p(178, "Short detection timer", "RW", 0, 3, 0),
    _p(179, "Vsense", "RW", *_BOOL, 1),
    _p(180, "smartEnergy actual current", "R", 0, 31),
    _p(181, "Stop on stall", "RW", 0, V_MAX, 0),
    _p(182, "smartEnergy threshold speed", "RW", 0, V_MAX, 0),
    _p(183, "smartEnergy slow run current", "RW", 0, 255, 0),
    _p(184, "Random TOff mode", "RW", *_BOOL),
    _p(193, "Reference search mode", "RWE", 1, 136, 1, REFERENCE_SEARCH_MODES),
    _p(194, "Reference search speed", "RWE", 0, V_MAX, 500),
    _p(195, "Reference switch speed", "RWE", 0, V_MAX, 50),
    _p(196, "Distance end switches", "R"),
    _p(204, "Freewheeling delay", "RWE", 0, 65535, 0),
    _p(206, "Actual load value", "R", 0, 1023),
    _p(207, "Extended error flags", "R", 0, 3),
    _p(208, "TMC262 driver error flags", "R", 0, 255),
    _p(213, "Group index", "RW", 0, 255, 0),
    _p(214, "Power down delay", "RWE", 1, 65535, 200),
    # Not a parameter of these modules: MVP REL counts from the actual position (the
    # stepRocker firmware and the TMCL reference), i.e. the TMCM-6212's AP 127 = 1.
    _p(AP.RELATIVE_POSITIONING_OPTION, "(fixed) MVP REL from the actual position", "", 1, 1, 1),
)

#: Rows only some modules have (as their pytrinamic classes name them).
LAST_REFERENCE = _p(197, "Last reference switch position", "R")
BOOST_CURRENT = _p(200, "Boost current", "RWE", 0, 255, 0)
ENCODER_MODE = _p(201, "Encoder mode", "RWE", 0, 255, 0)
ENCODER_ROWS = (
    _p(209, "Encoder position", "RW"),
    # AP 209 = encoder counts * prescaler / 512; 512: the counts themselves (docs/modules.md).
    _p(210, "Encoder prescaler", "RWE", 0, 65535, 512),
    _p(212, "Maximum encoder deviation", "RWE", 0, 65535, 0),
)
STEP_DIRECTION_MODE = _p(254, "Step/direction mode", "RWE", 0, 2, 0)


def axis_table(*extra: ParamSpec) -> dict[int, ParamSpec]:
    """The common rows and ``extra``, by number."""
    return {spec.number: spec for spec in (*COMMON_AXIS_ROWS, *extra)}


def storable(table: dict[int, ParamSpec]) -> frozenset[int]:
    return frozenset(n for n, spec in table.items() if spec.storable)


AXIS_PARAMETERS_1110 = axis_table(*ENCODER_ROWS, STEP_DIRECTION_MODE)
AXIS_PARAMETERS_3110 = axis_table(LAST_REFERENCE, BOOST_CURRENT, ENCODER_MODE, *ENCODER_ROWS,
                                  STEP_DIRECTION_MODE)
AXIS_PARAMETERS_6110 = axis_table(LAST_REFERENCE, BOOST_CURRENT)


# -- global parameters -------------------------------------------------------------------------

def global_row(number: int, name: str, access: str, lo: int, hi: int, default: int = 0,
               unsigned: bool = False) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, None, unsigned)


def bank0(*extra: ParamSpec) -> dict[int, ParamSpec]:
    """The TMCL family's bank 0 (as on the TMCM-6212) and the rows these modules add."""
    return {**TMCM6212_BANK0, **{spec.number: spec for spec in extra}}


#: Bank 0 rows of the TMC429 modules beyond the TMCM-6212's (pytrinamic's GP0 names).
END_SWITCH_POLARITY = global_row(GP.END_SWITCH_POLARITY, "End switch polarity", "RWA", 0, 1, 0)
REVERSE_SHAFT = global_row(GP.REVERSE_SHAFT_DIRECTION, "Reverse shaft direction", "RWA", 0, 1, 0)
IO_MODE = global_row(GP.IO_MODE, "I/O mode", "RWA", 0, 255, 0)


def bank3(switch_motors: int, inputs: int) -> dict[int, ParamSpec]:
    """Timer periods 0..2, stop switch triggers 27.. (two per motor), input triggers 39.."""
    rows = {n: global_row(n, f"Timer {n} period", "RW", 0, 2**32 - 1, 0, unsigned=True)
            for n in range(3)}
    for motor in range(switch_motors):
        for side, number in (("left", 27 + 2 * motor), ("right", 28 + 2 * motor)):
            rows[number] = global_row(number, f"Stop {side} {motor} trigger transition", "RW", 0, 3)
    for port in range(inputs):
        rows[39 + port] = global_row(39 + port, f"Input {port} trigger transition", "RW", 0, 3)
    return rows


# -- I/O --------------------------------------------------------------------------------------

#: Analogue inputs read 12 bit (0..4095) on these modules; a line reads 1 from half scale up.
ANALOG_FULL_SCALE = 4095
DIGITAL_THRESHOLD = 2048
#: ``GIO 8, 1``: the supply voltage in 0.1 V (pytrinamic's ``VIN = 8``, TMCM-Lib's TMCM-3110).
SUPPLY_VOLTAGE_CHANNEL = 8
NOMINAL_SUPPLY_VOLTAGE = 24.0
PROGRAM_MEMORY = 2048  # TMCL commands (TMCM-6110 manual V1.31 §4)
COORDINATES = 21  # 0..20 as across the TMCL family; coordinate 0 is RAM only


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
    baud_rates=TMCM6212_BAUD_RATES,  # the TMCL family's GP 65 and GP 69 (inferred)
    can_bit_rates=TMCM6212_CAN_BIT_RATES,
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
