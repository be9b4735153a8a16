"""The TMCM-6212 (firmware V1.05): its tables from the firmware manual, and its profile.

Axis parameters (§4.1, Table 14), global parameters of banks 0, 2 and 3 (§4.2, Tables 16-20),
the I/O ports (§3.6.12-13), coordinates (§3.6.22) and the firmware identity (command 136).
The manual gives ranges but no factory defaults; the defaults chosen here are explained in
docs/module.md.
"""

from __future__ import annotations

from tmcl_spec.commands import Opcode
from tmcl_spec.family import (
    BANK0_PARAMETERS,
    BANK2_PARAMETERS,
    BAUD_RATES,
    CAN_BIT_RATES,
    REFERENCE_SEARCH_MODES,
    STORABLE_USER_VARIABLES,
    axis_row,
    bank3,
)
from tmcl_spec.modules import ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN
from tmcl_spec.parameters import ACCESS, AP, AXIS, EVENTS, SETTING, TASKS, Motion, ParamSpec

MAX_VELOCITY_PPS = 7_999_774
MAX_ACCELERATION_PPS2 = 7_629_278


# -- axis parameters ---------------------------------------------------------------------------

def _p(number: int, name: str, access: str, motion: Motion, lo: int = INT32_MIN,
       hi: int = INT32_MAX, default: int = 0, allowed: frozenset[int] | None = None) -> ParamSpec:
    return axis_row(number, name, access, motion, lo, hi, default, allowed)


_V = MAX_VELOCITY_PPS
_A = MAX_ACCELERATION_PPS2
_BOOL = (0, 1)

AXIS_PARAMETERS: dict[int, ParamSpec] = {
    spec.number: spec
    for spec in (
        _p(0, "Target position", "RW", EVENTS),
        _p(1, "Actual position", "RW", AXIS),
        _p(2, "Target speed", "RW", SETTING, -_V, _V),
        _p(3, "Actual speed", "R", AXIS, -_V, _V),
        _p(4, "Maximum positioning speed", "RW", SETTING, 0, _V, 51200),
        _p(5, "Maximum acceleration", "RW", SETTING, 0, _A, 51200),
        _p(6, "Maximum current", "RW", SETTING, 0, 255, 128),
        _p(7, "Standby current", "RW", SETTING, 0, 255, 8),
        _p(8, "Position reached flag", "R", AXIS, *_BOOL),
        _p(9, "Home switch state", "R", EVENTS, *_BOOL),
        _p(10, "Right limit switch state", "R", EVENTS, *_BOOL),
        _p(11, "Left limit switch state", "R", EVENTS, *_BOOL),
        _p(12, "Right limit switch disable", "RW", SETTING, *_BOOL),
        _p(13, "Left limit switch disable", "RW", SETTING, *_BOOL),
        _p(14, "Swap limit switches", "RW", SETTING, *_BOOL),
        _p(15, "Acceleration A1", "RW", SETTING, 0, _A, 51200),
        _p(16, "Velocity V1", "RW", SETTING, 0, 1_000_000, 0),
        _p(17, "Maximum deceleration", "RW", SETTING, 0, _A, 51200),
        _p(18, "Deceleration D1", "RW", SETTING, 0, _A, 51200),
        _p(19, "Velocity VSTART", "RW", SETTING, 0, 249_999, 0),
        _p(20, "Velocity VSTOP", "RW", SETTING, 0, 249_999, 10),
        _p(21, "Ramp wait time", "RW", SETTING, 0, 65535, 0),
        _p(22, "Speed threshold for coolStep / fullstep", "RW", SETTING, 0, _V, 0),
        _p(23, "Minimum speed for dcStep", "RW", SETTING, 0, _V, 0),
        _p(24, "Right limit switch polarity", "RW", SETTING, *_BOOL),
        _p(25, "Left limit switch polarity", "RW", SETTING, *_BOOL),
        _p(26, "Soft stop enable", "RW", SETTING, *_BOOL),
        _p(27, "High speed chopper mode", "RW", SETTING, *_BOOL),
        _p(28, "High speed fullstep mode", "RW", SETTING, *_BOOL),
        _p(29, "Measured speed", "R", AXIS, 0, _V),
        _p(31, "Power down ramp", "RW", SETTING, 0, 15, 10),
        _p(32, "dcStep time", "RW", SETTING, 0, 1023, 0),
        _p(33, "dcStep stallGuard", "RW", SETTING, 0, 255, 0),
        _p(127, "Relative positioning option", "RW", SETTING, 0, 2, 0),
        _p(140, "Microstep resolution", "RW", SETTING, 0, 8, 8),
        _p(162, "Chopper blank time", "RW", SETTING, 0, 3, 2),
        _p(163, "Constant TOFF mode", "RW", SETTING, *_BOOL),
        _p(164, "Disable fast decay comparator", "RW", SETTING, *_BOOL),
        _p(165, "Chopper hysteresis end / fast decay time", "RW", SETTING, 0, 15, 0),
        _p(166, "Chopper hysteresis start / sine wave offset", "RW", SETTING, 0, 8, 4),
        _p(167, "Chopper off time (TOff)", "RW", SETTING, 0, 15, 3),
        _p(168, "smartEnergy current minimum (SEIMIN)", "RW", SETTING, *_BOOL),
        _p(169, "smartEnergy current down step", "RW", SETTING, 0, 3, 0),
        _p(170, "smartEnergy hysteresis", "RW", SETTING, 0, 15, 0),
        _p(171, "smartEnergy current up step", "RW", SETTING, 0, 3, 0),
        _p(172, "smartEnergy hysteresis start", "RW", SETTING, 0, 15, 0),
        _p(173, "stallGuard2 filter enable", "RW", SETTING, *_BOOL),
        _p(174, "stallGuard2 threshold", "RW", SETTING, -64, 63, 0),
        _p(180, "smartEnergy actual current", "R", TASKS, 0, 31),
        _p(181, "Stop on stall", "RW", SETTING, 0, _V, 0),
        _p(182, "smartEnergy threshold speed", "RW", SETTING, 0, _V, 0),
        _p(184, "Random TOff mode", "RW", SETTING, *_BOOL),
        _p(185, "Chopper synchronization", "RW", SETTING, 0, 15, 0),
        _p(186, "PWM threshold speed", "RW", SETTING, 0, _V, 0),
        _p(187, "PWM gradient", "RW", SETTING, 0, 15, 0),
        _p(188, "PWM amplitude", "RW", SETTING, 0, 255, 128),
        _p(193, "Reference search mode", "RW", SETTING, 1, 136, 1, REFERENCE_SEARCH_MODES),
        _p(194, "Reference search speed", "RW", SETTING, 0, _V, 51200),
        _p(195, "Reference switch speed", "RW", SETTING, 0, _V, 5120),
        _p(196, "End switch distance", "R", EVENTS),
        _p(197, "Last reference position", "R", EVENTS),
        _p(201, "Encoder mode", "RW", SETTING, 0, 255, 0),
        _p(202, "Motor full step resolution", "RW", SETTING, 0, 65535, 200),
        _p(204, "Freewheeling mode", "RW", SETTING, 0, 3, 0),
        _p(206, "Actual load value", "R", AXIS, 0, 1023),
        _p(207, "Extended error flags", "R", ACCESS, 0, 3),
        _p(208, "TMC5130 error flags", "R", AXIS, 0, 255),
        _p(209, "Encoder position", "RW", AXIS),
        _p(210, "Encoder resolution", "RW", SETTING, 0, 65535, 51200),
        _p(212, "Maximum encoder deviation", "RW", SETTING, 0, 65535, 0),
        _p(214, "Power down delay", "RW", SETTING, 0, 417, 200),
        _p(255, "Unit mode", "RW", SETTING, *_BOOL, 1),
    )
}

#: Parameters whose RAM value is kept when STAP stores an axis's configuration.
STORABLE_AXIS_PARAMETERS = frozenset(
    n for n, s in AXIS_PARAMETERS.items()
    if s.writable and n not in (AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.TARGET_SPEED,
                                AP.ENCODER_POSITION)
)


# -- global parameters: the family's (tmcl_spec/family.py, Tables 16-20) -----------------------

#: Bank 3: timers 0..2, six motors' stop switch triggers 27..38, four inputs' 39..42.
BANK3_PARAMETERS = bank3(switch_motors=6, inputs=4)

BANK_PARAMETERS: dict[int, dict[int, ParamSpec]] = {
    0: BANK0_PARAMETERS,
    2: BANK2_PARAMETERS,
    3: BANK3_PARAMETERS,
}


# -- I/O ports and serial line -----------------------------------------------------------------

NUMBER_OF_INPUTS = 4
NUMBER_OF_OUTPUTS = 4
#: ``GIO 8, 1``: the supply voltage in 0.1 V.  The manual lists IN0..3 for bank 1 but gives the
#: port range as 0..4 and the board monitors its supply; the TMCL-IDE and host drivers of
#: this module family read channel 8 (docs/module.md).
SUPPLY_VOLTAGE_CHANNEL = 8
NOMINAL_SUPPLY_VOLTAGE = 24.0  # the manual's "+24V nominal"


# -- the profile -------------------------------------------------------------------------------

TMCM_6212 = ModuleType(
    key="tmcm-6212",
    name="TMCM-6212",
    module_number=6212,
    firmware=(1, 5),
    number_of_axes=6,
    axis_parameters=AXIS_PARAMETERS,
    global_parameters=BANK_PARAMETERS,
    storable_axis_parameters=STORABLE_AXIS_PARAMETERS,
    storable_user_variables=STORABLE_USER_VARIABLES,
    digital_inputs=NUMBER_OF_INPUTS,
    analog_inputs=NUMBER_OF_INPUTS,
    outputs=NUMBER_OF_OUTPUTS,
    supply_voltage_channel=SUPPLY_VOLTAGE_CHANNEL,
    nominal_supply_voltage=NOMINAL_SUPPLY_VOLTAGE,
    coordinates=21,  # 0..20; coordinate 0 is RAM only
    program_memory=6144,  # TMCL commands it can store (manual §1, "Software")
    chip_core="tmc4210",
    commands=frozenset(Opcode),
    baud_rates=BAUD_RATES,
    can_bit_rates=CAN_BIT_RATES,
)
