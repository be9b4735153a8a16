"""The TMCM-6212 (firmware V1.05): its tables from the firmware manual, and its profile.

Axis parameters (§4.1, Table 14), global parameters of banks 0, 2 and 3 (§4.2, Tables 16-20),
the I/O ports (§3.6.12-13), coordinates (§3.6.22) and the firmware identity (command 136).
The manual gives ranges but no factory defaults; the defaults chosen here are explained in
docs/module.md.
"""

from __future__ import annotations

from tmcl_spec.commands import Opcode
from tmcl_spec.modules import ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN, UINT32_MAX
from tmcl_spec.parameters import AP, GP, ParamSpec

MAX_VELOCITY_PPS = 7_999_774
MAX_ACCELERATION_PPS2 = 7_629_278


# -- axis parameters ---------------------------------------------------------------------------

def _p(number: int, name: str, access: str, lo: int = INT32_MIN, hi: int = INT32_MAX,
       default: int = 0, allowed: frozenset[int] | None = None) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, allowed)


_V = MAX_VELOCITY_PPS
_A = MAX_ACCELERATION_PPS2
_BOOL = (0, 1)

#: Reference search modes: 1..8, +64 for modes 1..4 (right switch), +128 for modes 5..8
#: (inverted home switch).  The manual's examples also quote 129..132 for "mode 5..8 + 128";
#: both spellings are accepted (docs/module.md).
REFERENCE_SEARCH_MODES = frozenset(
    list(range(1, 9)) + [m + 64 for m in range(1, 5)] + [m + 128 for m in range(5, 9)]
    + [129, 130, 131, 132]
)

AXIS_PARAMETERS: dict[int, ParamSpec] = {
    spec.number: spec
    for spec in (
        _p(0, "Target position", "RW"),
        _p(1, "Actual position", "RW"),
        _p(2, "Target speed", "RW", -_V, _V),
        _p(3, "Actual speed", "R", -_V, _V),
        _p(4, "Maximum positioning speed", "RW", 0, _V, 51200),
        _p(5, "Maximum acceleration", "RW", 0, _A, 51200),
        _p(6, "Maximum current", "RW", 0, 255, 128),
        _p(7, "Standby current", "RW", 0, 255, 8),
        _p(8, "Position reached flag", "R", *_BOOL),
        _p(9, "Home switch state", "R", *_BOOL),
        _p(10, "Right limit switch state", "R", *_BOOL),
        _p(11, "Left limit switch state", "R", *_BOOL),
        _p(12, "Right limit switch disable", "RW", *_BOOL),
        _p(13, "Left limit switch disable", "RW", *_BOOL),
        _p(14, "Swap limit switches", "RW", *_BOOL),
        _p(15, "Acceleration A1", "RW", 0, _A, 51200),
        _p(16, "Velocity V1", "RW", 0, 1_000_000, 0),
        _p(17, "Maximum deceleration", "RW", 0, _A, 51200),
        _p(18, "Deceleration D1", "RW", 0, _A, 51200),
        _p(19, "Velocity VSTART", "RW", 0, 249_999, 0),
        _p(20, "Velocity VSTOP", "RW", 0, 249_999, 10),
        _p(21, "Ramp wait time", "RW", 0, 65535, 0),
        _p(22, "Speed threshold for coolStep / fullstep", "RW", 0, _V, 0),
        _p(23, "Minimum speed for dcStep", "RW", 0, _V, 0),
        _p(24, "Right limit switch polarity", "RW", *_BOOL),
        _p(25, "Left limit switch polarity", "RW", *_BOOL),
        _p(26, "Soft stop enable", "RW", *_BOOL),
        _p(27, "High speed chopper mode", "RW", *_BOOL),
        _p(28, "High speed fullstep mode", "RW", *_BOOL),
        _p(29, "Measured speed", "R", 0, _V),
        _p(31, "Power down ramp", "RW", 0, 15, 10),
        _p(32, "dcStep time", "RW", 0, 1023, 0),
        _p(33, "dcStep stallGuard", "RW", 0, 255, 0),
        _p(127, "Relative positioning option", "RW", 0, 2, 0),
        _p(140, "Microstep resolution", "RW", 0, 8, 8),
        _p(162, "Chopper blank time", "RW", 0, 3, 2),
        _p(163, "Constant TOFF mode", "RW", *_BOOL),
        _p(164, "Disable fast decay comparator", "RW", *_BOOL),
        _p(165, "Chopper hysteresis end / fast decay time", "RW", 0, 15, 0),
        _p(166, "Chopper hysteresis start / sine wave offset", "RW", 0, 8, 4),
        _p(167, "Chopper off time (TOff)", "RW", 0, 15, 3),
        _p(168, "smartEnergy current minimum (SEIMIN)", "RW", *_BOOL),
        _p(169, "smartEnergy current down step", "RW", 0, 3, 0),
        _p(170, "smartEnergy hysteresis", "RW", 0, 15, 0),
        _p(171, "smartEnergy current up step", "RW", 0, 3, 0),
        _p(172, "smartEnergy hysteresis start", "RW", 0, 15, 0),
        _p(173, "stallGuard2 filter enable", "RW", *_BOOL),
        _p(174, "stallGuard2 threshold", "RW", -64, 63, 0),
        _p(180, "smartEnergy actual current", "R", 0, 31),
        _p(181, "Stop on stall", "RW", 0, _V, 0),
        _p(182, "smartEnergy threshold speed", "RW", 0, _V, 0),
        _p(184, "Random TOff mode", "RW", *_BOOL),
        _p(185, "Chopper synchronization", "RW", 0, 15, 0),
        _p(186, "PWM threshold speed", "RW", 0, _V, 0),
        _p(187, "PWM gradient", "RW", 0, 15, 0),
        _p(188, "PWM amplitude", "RW", 0, 255, 128),
        _p(193, "Reference search mode", "RW", 1, 136, 1, REFERENCE_SEARCH_MODES),
        _p(194, "Reference search speed", "RW", 0, _V, 51200),
        _p(195, "Reference switch speed", "RW", 0, _V, 5120),
        _p(196, "End switch distance", "R"),
        _p(197, "Last reference position", "R"),
        _p(201, "Encoder mode", "RW", 0, 255, 0),
        _p(202, "Motor full step resolution", "RW", 0, 65535, 200),
        _p(204, "Freewheeling mode", "RW", 0, 3, 0),
        _p(206, "Actual load value", "R", 0, 1023),
        _p(207, "Extended error flags", "R", 0, 3),
        _p(208, "TMC5130 error flags", "R", 0, 255),
        _p(209, "Encoder position", "RW"),
        _p(210, "Encoder resolution", "RW", 0, 65535, 51200),
        _p(212, "Maximum encoder deviation", "RW", 0, 65535, 0),
        _p(214, "Power down delay", "RW", 0, 417, 200),
        _p(255, "Unit mode", "RW", *_BOOL, 1),
    )
}

#: Parameters whose RAM value is kept when STAP stores an axis's configuration.
STORABLE_AXIS_PARAMETERS = frozenset(
    n for n, s in AXIS_PARAMETERS.items()
    if s.writable and n not in (AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.TARGET_SPEED,
                                AP.ENCODER_POSITION)
)


# -- global parameters -------------------------------------------------------------------------

def _g(number: int, name: str, access: str, lo: int, hi: int, default: int = 0,
       unsigned: bool = False) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, None, unsigned)


BANK0_PARAMETERS: dict[int, ParamSpec] = {
    s.number: s
    for s in (
        # Range 0..11: the manual's range column says 0..7 but its own table lists 8..11.
        _g(GP.BAUD_RATE, "RS485 baud rate", "RWA", 0, 11, 0),
        _g(GP.SERIAL_ADDRESS, "Serial address", "RWA", 1, 255, 1),
        _g(GP.SERIAL_HEARTBEAT, "Serial heartbeat", "RWA", 0, 65535, 0),
        _g(GP.CAN_BIT_RATE, "CAN bit rate", "RWA", 2, 8, 8),
        _g(GP.CAN_REPLY_ID, "CAN reply ID", "RWA", 0, 2047, 2),
        _g(GP.CAN_ID, "CAN ID", "RWA", 0, 2047, 1),
        _g(GP.TELEGRAM_PAUSE, "Telegram pause time", "RWA", 0, 255, 0),
        _g(GP.HOST_ADDRESS, "Serial host address", "RWA", 0, 255, 2),
        _g(GP.AUTO_START, "Auto start mode", "RWA", 0, 1, 0),
        _g(GP.CODE_PROTECTION, "TMCL code protection", "RWA", 0, 3, 0),
        _g(GP.CAN_HEARTBEAT, "CAN heartbeat", "RWA", 0, 65535, 0),
        _g(GP.CAN_SECONDARY_ID, "CAN secondary address", "RWA", 0, 2047, 0),
        _g(GP.COORDINATE_STORAGE, "Coordinate storage", "RWA", 0, 1, 0),
        _g(GP.DO_NOT_RESTORE_USER_VARIABLES, "Do not restore user variables", "RWA", 0, 1, 0),
        _g(GP.SERIAL_SECONDARY_ADDRESS, "Serial secondary address", "RWA", 0, 255, 0),
        _g(GP.APPLICATION_STATUS, "TMCL application status", "R", 0, 3),
        _g(GP.DOWNLOAD_MODE, "Download mode", "R", 0, 1),
        _g(GP.PROGRAM_COUNTER, "TMCL program counter", "R", 0, INT32_MAX),
        _g(GP.TICK_TIMER, "TMCL tick timer", "RW", 0, INT32_MAX),
        _g(GP.RANDOM_NUMBER, "Random number", "RW", 0, INT32_MAX),
        _g(GP.SUPPRESS_REPLY, "Suppress reply", "RW", 0, 1, 0),
    )
}

USER_VARIABLE_COUNT = 256
STORABLE_USER_VARIABLES = 56  # 0..55 can be stored with STGP (Table 18, fw 1.05 note)

BANK2_PARAMETERS: dict[int, ParamSpec] = {
    n: ParamSpec(n, f"User variable #{n}", "RWE" if n < STORABLE_USER_VARIABLES else "RW")
    for n in range(USER_VARIABLE_COUNT)
}

BANK3_PARAMETERS: dict[int, ParamSpec] = {
    **{
        n: _g(n, f"Timer {n} period", "RW", 0, UINT32_MAX, 0, unsigned=True)
        for n in range(3)
    },
    **{
        n: _g(n, f"Stop {'left' if n % 2 else 'right'} {(n - 27) // 2} trigger transition",
              "RW", 0, 3)
        for n in range(27, 39)
    },
    **{n: _g(n, f"Input {n - 39} trigger transition", "RW", 0, 3) for n in range(39, 43)},
}

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
#: GP 65 value -> bits per second (Table 16).
BAUD_RATES = dict(enumerate((9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200, 230400,
                             250000, 500000, 1000000)))
#: GP 69 (CAN bit rate): index -> bits per second (Table 16).
CAN_BIT_RATES = {2: 20_000, 3: 50_000, 4: 100_000, 5: 125_000, 6: 250_000, 7: 500_000, 8: 1_000_000}


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
