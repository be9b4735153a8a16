"""Module-level tables of the TMCM-6212 firmware manual as data.

Status codes (Table 4), global parameters of banks 0, 2 and 3 (Tables 16-20), the firmware
version and the I/O port map.  Axis parameters live with the axes (axes/parameters.py) and
opcodes with the instruction set (interpreter/isa.py); this file re-exports both so a reader
finds every manual table from here.
"""

from __future__ import annotations

from enum import IntEnum

from axes.parameters import AXIS_PARAMETERS, INT32_MAX, NUMBER_OF_AXES, UINT32_MAX, ParamSpec
from interpreter.isa import Opcode

__all__ = [
    "AXIS_PARAMETERS",
    "BANK_PARAMETERS",
    "FIRMWARE_VERSION_STRING",
    "NUMBER_OF_AXES",
    "Opcode",
    "Status",
]


class Status(IntEnum):
    """Reply status codes (Table 4, plus the 138 event status and the extended codes)."""

    OK = 100
    LOADED = 101  # command stored in program memory (download mode)
    WRONG_CHECKSUM = 1
    INVALID_COMMAND = 2
    WRONG_TYPE = 3
    INVALID_VALUE = 4
    EEPROM_LOCKED = 5
    COMMAND_NOT_AVAILABLE = 6
    COMMAND_LOAD_ERROR = 7
    WRITE_PROTECTED = 8  # program memory protected against overwriting (GP 81)
    MAX_EXCEEDED = 9
    DOWNLOAD_NOT_POSSIBLE = 10
    TARGET_REACHED_EVENT = 128


# -- firmware identity (command 136) ------------------------------------------------------

MODULE_TYPE = 6212
FIRMWARE_MAJOR = 1
FIRMWARE_MINOR = 5
FIRMWARE_VERSION_STRING = b"6212V105"
FIRMWARE_VERSION_BINARY = (MODULE_TYPE << 16) | (FIRMWARE_MAJOR << 8) | FIRMWARE_MINOR


# -- global parameters ----------------------------------------------------------------------

def _g(number: int, name: str, access: str, lo: int, hi: int, default: int = 0,
       unsigned: bool = False) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, None, unsigned)


class GP:
    """Bank 0 parameter numbers the firmware itself looks at.

    Plain ints, not an IntEnum: they index dictionaries on every request.
    """

    BAUD_RATE = 65
    SERIAL_ADDRESS = 66
    SERIAL_HEARTBEAT = 68
    CAN_BIT_RATE = 69
    CAN_REPLY_ID = 70
    CAN_ID = 71
    TELEGRAM_PAUSE = 75
    HOST_ADDRESS = 76
    AUTO_START = 77
    CODE_PROTECTION = 81
    CAN_HEARTBEAT = 82
    CAN_SECONDARY_ID = 83
    COORDINATE_STORAGE = 84
    DO_NOT_RESTORE_USER_VARIABLES = 85
    SERIAL_SECONDARY_ADDRESS = 87
    APPLICATION_STATUS = 128
    DOWNLOAD_MODE = 129
    PROGRAM_COUNTER = 130
    TICK_TIMER = 132
    RANDOM_NUMBER = 133
    SUPPRESS_REPLY = 255


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

TRIGGER_TRANSITIONS = ("off", "low-high", "high-low", "both")

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


# -- I/O ports (SIO/GIO, §3.6.12-13) ----------------------------------------------------------

class IOBank(IntEnum):
    DIGITAL_INPUTS = 0
    ANALOG_INPUTS = 1
    OUTPUTS = 2


NUMBER_OF_INPUTS = 4
NUMBER_OF_OUTPUTS = 4
ANALOG_MAX = 65535
#: Digital reading of an ADIN line: the same pin read through a threshold (docs/io.md).
DIGITAL_THRESHOLD = 32768

# -- coordinates (§3.6.22) ---------------------------------------------------------------------

NUMBER_OF_COORDINATES = 21  # 0..20; coordinate 0 is RAM only
MOTOR_ALL = 255  # SCO/GCO motor-255 forms copy between RAM and EEPROM

# -- serial line -------------------------------------------------------------------------------

#: GP 65 index -> bits per second.
BAUD_RATES = (9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200, 230400, 250000,
              500000, 1000000)
