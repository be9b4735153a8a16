"""Parameters: one row of a table (:class:`ParamSpec`), and the numbers the firmware names.

The tables themselves belong to a module type (:mod:`tmcl_spec.tmcm6212`); the numbers below
mean the same on every TMCL module of the family, so firmware code names them here instead
of writing the numbers.  Plain ints, not IntEnums: they index dictionaries on every request.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from tmcl_spec.numbers import INT32_MAX, INT32_MIN, UINT32_MAX


class Motion(Enum):
    """How a parameter's value changes while no command writes it: what loop skipping may
    assume of a value the program read before (interpreter/skipping.py, axes/forecast.py).
    Every row of every table says it; a row that does not is refused when its module type is
    built (``ModuleType``), never taken as steady."""

    #: Changes only when written, by a command (SAP, SGP, a host's or the program's).
    SETTING = "setting"
    #: Follows the axis, but changes only at its notable instants (a switch edge, arrival,
    #: a reference search's end): the switch levels, AP 0 after a rotation, AP 196/197.
    EVENTS = "changes at events"
    #: Changes while the axis moves (position, speed, load, encoder, coolStep's current).
    AXIS = "moves with the axis"
    #: Changes only at the firmware's own periodic pass over the axes (axes/tasks.py): what
    #: the pass reads from the motor driver (AP 180, and on the TMC262 modules AP 206/208).
    TASKS = "changes at the firmware's pass"
    #: Changes with the clock alone: the millisecond tick (GP 132).
    TIME = "moves with time"
    #: Reading it may change it: the random number, the last command error, error flags
    #: that a read clears.
    ACCESS = "changes on access"
    #: Follows the program itself (status, download mode, program counter): the same at the
    #: same instruction of a program.
    PROGRAM = "follows the program"


SETTING, EVENTS, AXIS, TASKS, TIME, ACCESS, PROGRAM = (
    Motion.SETTING, Motion.EVENTS, Motion.AXIS, Motion.TASKS, Motion.TIME, Motion.ACCESS,
    Motion.PROGRAM)


@dataclass(frozen=True, slots=True)
class ParamSpec:
    """One row of a parameter table.

    ``access`` uses the manual's letters: R readable, W writable, E storable with
    STGP/RSGP (or STAP/RSAP), A automatically stored in EEPROM when written.
    ``allowed`` restricts the value to a set when the range is not contiguous.
    ``unsigned`` means the 32-bit wire value is read as unsigned before the range check.
    ``firmware_number`` maps a module's own numbering onto the firmware's (docs/modules.md,
    "TMCM-1111").  ``motion``: how the value changes by itself (:class:`Motion`); required of
    every row a module type lists.
    """

    number: int
    name: str
    access: str
    minimum: int = INT32_MIN
    maximum: int = INT32_MAX
    default: int = 0
    allowed: frozenset[int] | None = None
    unsigned: bool = False
    #: The number the firmware layer knows this row by (a name of :class:`AP`), where the
    #: module numbers it otherwise (the TMCM-1111's AP 15 is the TMCM-6212's VSTART, 19);
    #: None: its own number.  Keys above 255 never appear on the wire.
    firmware_number: int | None = None
    #: How the value changes while no command writes it (None only before a table says).
    motion: Motion | None = None

    #: The access letters as flags, worked out once (they are asked on every request).
    readable: bool = field(init=False, repr=False, compare=False)
    writable: bool = field(init=False, repr=False, compare=False)
    storable: bool = field(init=False, repr=False, compare=False)
    auto_stored: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for flag, letter in (("readable", "R"), ("writable", "W"), ("storable", "E"),
                             ("auto_stored", "A")):
            object.__setattr__(self, flag, letter in self.access)

    def accepts(self, value: int) -> bool:
        """True if a (signed 32-bit wire) value is valid for this parameter."""
        if self.unsigned:
            value &= UINT32_MAX
        if self.allowed is not None:
            return value in self.allowed
        return self.minimum <= value <= self.maximum

    def normalise(self, value: int) -> int:
        """Wire value as stored (unsigned parameters keep their unsigned meaning)."""
        return value & UINT32_MAX if self.unsigned else value


class AP:
    """Axis parameter numbers (TMCM-6212 manual §4.1, Table 14, and the TMC429 modules'
    parameters 130..154, 160/161, 175..179, 183, 200, 213, 254: tmcl_spec/tmc429_modules.py)."""

    TARGET_POSITION = 0
    ACTUAL_POSITION = 1
    TARGET_SPEED = 2
    ACTUAL_SPEED = 3
    MAX_SPEED = 4
    MAX_ACCELERATION = 5
    MAX_CURRENT = 6
    STANDBY_CURRENT = 7
    POSITION_REACHED = 8
    HOME_SWITCH = 9
    RIGHT_SWITCH = 10
    LEFT_SWITCH = 11
    RIGHT_DISABLE = 12
    LEFT_DISABLE = 13
    SWAP_SWITCHES = 14
    A1 = 15
    V1 = 16
    MAX_DECELERATION = 17
    D1 = 18
    VSTART = 19
    VSTOP = 20
    RAMP_WAIT = 21
    COOLSTEP_THRESHOLD_SPEED = 22
    DCSTEP_MIN_SPEED = 23
    RIGHT_POLARITY = 24
    LEFT_POLARITY = 25
    SOFT_STOP = 26
    HIGH_SPEED_CHOPPER = 27
    HIGH_SPEED_FULLSTEP = 28
    MEASURED_SPEED = 29
    POWER_DOWN_RAMP = 31
    DCSTEP_TIME = 32
    DCSTEP_STALLGUARD = 33
    RELATIVE_POSITIONING_OPTION = 127
    MINIMUM_SPEED = 130
    ACTUAL_ACCELERATION = 135
    RAMP_MODE = 138
    MICROSTEPS = 140
    REFERENCE_SWITCH_TOLERANCE = 141
    SOFT_STOP_FLAG = 149
    END_SWITCH_POWER_DOWN = 150
    RAMP_DIVISOR = 153
    PULSE_DIVISOR = 154
    STEP_INTERPOLATION = 160
    DOUBLE_STEP = 161
    CHOPPER_BLANK_TIME = 162
    CONSTANT_TOFF_MODE = 163
    DISABLE_FAST_DECAY_COMPARATOR = 164
    CHOPPER_HYSTERESIS_END = 165
    CHOPPER_HYSTERESIS_START = 166
    CHOPPER_OFF_TIME = 167
    SMARTENERGY_CURRENT_MINIMUM = 168
    SMARTENERGY_CURRENT_DOWN_STEP = 169
    SMARTENERGY_HYSTERESIS = 170
    SMARTENERGY_CURRENT_UP_STEP = 171
    SMARTENERGY_HYSTERESIS_START = 172
    STALLGUARD_FILTER = 173
    STALLGUARD_THRESHOLD = 174
    SMARTENERGY_ACTUAL_CURRENT = 180
    SLOPE_CONTROL_HIGH_SIDE = 175
    SLOPE_CONTROL_LOW_SIDE = 176
    SHORT_PROTECTION_DISABLE = 177
    SHORT_DETECTION_TIMER = 178
    VSENSE = 179
    STOP_ON_STALL = 181
    SMARTENERGY_THRESHOLD_SPEED = 182
    SMARTENERGY_SLOW_RUN_CURRENT = 183
    RANDOM_TOFF_MODE = 184
    CHOPPER_SYNCHRONIZATION = 185
    PWM_THRESHOLD_SPEED = 186
    PWM_GRADIENT = 187
    PWM_AMPLITUDE = 188
    RFS_MODE = 193
    RFS_SPEED = 194
    RFS_SWITCH_SPEED = 195
    SWITCH_DISTANCE = 196
    LAST_REFERENCE = 197
    BOOST_CURRENT = 200
    ENCODER_MODE = 201
    FULLSTEPS = 202
    FREEWHEELING = 204
    LOAD = 206
    ERROR_FLAGS = 207
    DRIVER_ERROR_FLAGS = 208
    ENCODER_POSITION = 209
    ENCODER_RESOLUTION = 210
    MAX_DEVIATION = 212
    GROUP_INDEX = 213
    POWER_DOWN_DELAY = 214
    ABSOLUTE_ENCODER = 215  # sensOstep modules: the rotor angle, one turn
    EXTERNAL_ENCODER_POSITION = 216
    EXTERNAL_ENCODER_PRESCALER = 217
    EXTERNAL_ENCODER_MAX_DEVIATION = 218
    STEP_DIRECTION_MODE = 254
    UNIT_MODE = 255

    # -- keys above 255: what only another numbering has (ParamSpec.firmware_number) --------
    #: The TMC4361 modules' (TMCM-1111) ramp type: 0 trapezoid, 1 S-shaped.
    RAMP_TYPE = 0x100
    #: Their BOW1..BOW4 (pps^3) and DSTOP (pps^2, the soft stop's deceleration).
    BOW1 = 0x101
    BOW2 = 0x102
    BOW3 = 0x103
    BOW4 = 0x104
    STOP_DECELERATION = 0x105
    #: Their virtual stop switches: positions, enable bits (0 left, 1 right), mode (0..3).
    VIRTUAL_STOP_LEFT = 0x106
    VIRTUAL_STOP_RIGHT = 0x107
    VIRTUAL_STOP_ENABLE = 0x108
    VIRTUAL_STOP_MODE = 0x109
    #: Their limit switch settings: bit 0 the switch enabled, bit 1 its polarity inverted
    #: (the firmware derives RIGHT/LEFT_DISABLE and RIGHT/LEFT_POLARITY from them).
    RIGHT_LIMIT_SWITCH = 0x10A
    LEFT_LIMIT_SWITCH = 0x10B
    #: Rows stored and read back that share a number with a parameter the firmware acts on:
    #: ``STORED + number`` keeps them apart.
    STORED = 0x1000


class GP:
    """Global parameter numbers of bank 0 (manual §4.2, Table 16) the firmware looks at."""

    BAUD_RATE = 65
    SERIAL_ADDRESS = 66
    ASCII_MODE = 67  # TMCM-1141/1160: stored only (no ASCII interface, docs/modules.md)
    SERIAL_HEARTBEAT = 68
    CAN_BIT_RATE = 69
    CAN_REPLY_ID = 70
    CAN_ID = 71
    TELEGRAM_PAUSE = 75
    HOST_ADDRESS = 76
    AUTO_START = 77
    IO_MODE = 78  # TMCM-1110
    END_SWITCH_POLARITY = 79  # TMC429 modules
    CODE_PROTECTION = 81
    CAN_HEARTBEAT = 82
    CAN_SECONDARY_ID = 83
    COORDINATE_STORAGE = 84
    DO_NOT_RESTORE_USER_VARIABLES = 85
    SERIAL_SECONDARY_ADDRESS = 87
    REVERSE_SHAFT_DIRECTION = 90  # TMC429 modules
    APPLICATION_STATUS = 128
    DOWNLOAD_MODE = 129
    PROGRAM_COUNTER = 130
    LAST_TMCL_ERROR = 131  # TMC429 modules of the 1140 generation
    TICK_TIMER = 132
    RANDOM_NUMBER = 133
    SUPPRESS_REPLY = 255


class EvalGP:
    """Global parameters of Trinamic's evaluation firmware (the Landungsbruecke: a different
    numbering from the modules'; pytrinamic's ``Landungsbruecke.GP``)."""

    ERROR_MASK = 1
    DRIVERS_ENABLE = 2
    DEBUG_MODE = 3
    BOARD_ASSIGNMENT = 4
    HARDWARE_ID = 5


#: The banks of global parameters (§4.2): 0 module settings, 2 user variables, 3 interrupts.
BANK_MODULE = 0
BANK_USER_VARIABLES = 2
BANK_INTERRUPTS = 3

#: Names of an axis's switches, as the world file, the MQTT topics and the API spell them.
SWITCH_NAMES = ("left", "right", "home")
