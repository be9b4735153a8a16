"""The TMCL family: what every module of it shares, and the builders of its tables.

Bank 0's settings (as the TMCM-6212 manual's Table 16 lists them, which the TMC429 modules
and the TMCM-1111 extend), the user variables of bank 2, bank 3's timers and triggers, the
reference search modes, the serial baud rates and CAN bit rates, the TMC262 driver's rows,
and the I/O constants of the TMCM-1140 generation.  Neutral ground: a module's profile file
builds on this one and never imports another module's file, and no chip core defaults to a
module's table.  Where each value comes from is said in docs/module.md and docs/modules.md.
"""

from __future__ import annotations

import dataclasses

from tmcl_spec.numbers import INT32_MAX, INT32_MIN, UINT32_MAX
from tmcl_spec.parameters import ACCESS, GP, PROGRAM, SETTING, TIME, Motion, ParamSpec

_BOOL = (0, 1)

def axis_row(number: int, name: str, access: str, motion: Motion, lo: int = INT32_MIN,
             hi: int = INT32_MAX, default: int = 0, allowed: frozenset[int] | None = None,
             firmware_number: int | None = None) -> ParamSpec:
    """One axis-parameter row, its motion column right after the access letters."""
    return ParamSpec(number, name, access, lo, hi, default, allowed,
                     firmware_number=firmware_number, motion=motion)

def global_row(number: int, name: str, access: str, motion: Motion, lo: int, hi: int,
               default: int = 0, unsigned: bool = False) -> ParamSpec:
    """One global-parameter row, its motion column right after the access letters."""
    return ParamSpec(number, name, access, lo, hi, default, None, unsigned, motion=motion)

# -- axis parameters ---------------------------------------------------------------------------

#: Reference search modes: 1..8, +64 for modes 1..4 (right switch), +128 for modes 5..8
#: (inverted home switch).  The manual's examples also quote 129..132 for "mode 5..8 + 128";
#: both spellings are accepted (docs/module.md).
REFERENCE_SEARCH_MODES = frozenset(
    list(range(1, 9)) + [m + 64 for m in range(1, 5)] + [m + 128 for m in range(5, 9)]
    + [129, 130, 131, 132]
)

def tmc262_rows(v_max: int, stallguard: tuple[int, int] = (0, 0)) -> tuple[ParamSpec, ...]:
    """The TMC262 driver's rows (chopper, smartEnergy, stallGuard2), alike in the manual of
    every module built on that driver (the TMC429 modules, the TMCM-1111); ``v_max``: the
    bound of the speeds among them (181, 182) in the module's units; ``stallguard``: the
    power-up filter (AP 173) and threshold (AP 174)."""
    sg_filter, threshold = stallguard
    s = SETTING
    return (
        axis_row(162, "Chopper blank time", "RW", s, 0, 3, 2),
        axis_row(163, "Chopper mode", "RW", s, *_BOOL),
        axis_row(164, "Chopper hysteresis decrement", "RW", s, 0, 3, 0),
        axis_row(165, "Chopper hysteresis end", "RW", s, 0, 15, 2),
        axis_row(166, "Chopper hysteresis start", "RW", s, 0, 8, 3),
        axis_row(167, "Chopper off time", "RW", s, 0, 15, 5),
        axis_row(168, "smartEnergy current minimum", "RW", s, *_BOOL),
        axis_row(169, "smartEnergy current down step", "RW", s, 0, 3, 0),
        axis_row(170, "smartEnergy hysteresis", "RW", s, 0, 15, 0),
        axis_row(171, "smartEnergy current up step", "RW", s, 0, 3, 0),
        axis_row(172, "smartEnergy hysteresis start", "RW", s, 0, 15, 0),
        axis_row(173, "stallGuard2 filter enable", "RW", s, *_BOOL, sg_filter),
        axis_row(174, "stallGuard2 threshold", "RW", s, -64, 63, threshold),
        axis_row(175, "Slope control high side", "RW", s, 0, 3, 3),
        axis_row(176, "Slope control low side", "RW", s, 0, 3, 3),
        axis_row(177, "Short protection disable", "RW", s, *_BOOL),
        axis_row(178, "Short detection timer", "RW", s, 0, 3, 0),
        axis_row(179, "Vsense", "RW", s, *_BOOL, 1),
        axis_row(180, "smartEnergy actual current", "R", Motion.TASKS, 0, 31),
        axis_row(181, "Stop on stall", "RW", s, 0, v_max, 0),
        axis_row(182, "smartEnergy threshold speed", "RW", s, 0, v_max, 0),
        axis_row(183, "smartEnergy slow run current", "RW", s, 0, 255, 0),
        axis_row(184, "Random TOff mode", "RW", s, *_BOOL),
    )

# -- bank 0: module settings (TMCM-6212 manual §4.2, Table 16) ----------------------------------

BANK0_PARAMETERS: dict[int, ParamSpec] = {
    s.number: s
    for s in (
        # Range 0..11: the manual's range column says 0..7 but its own table lists 8..11.
        global_row(GP.BAUD_RATE, "RS485 baud rate", "RWA", SETTING, 0, 11, 0),
        global_row(GP.SERIAL_ADDRESS, "Serial address", "RWA", SETTING, 1, 255, 1),
        global_row(GP.SERIAL_HEARTBEAT, "Serial heartbeat", "RWA", SETTING, 0, 65535, 0),
        global_row(GP.CAN_BIT_RATE, "CAN bit rate", "RWA", SETTING, 2, 8, 8),
        global_row(GP.CAN_REPLY_ID, "CAN reply ID", "RWA", SETTING, 0, 2047, 2),
        global_row(GP.CAN_ID, "CAN ID", "RWA", SETTING, 0, 2047, 1),
        global_row(GP.TELEGRAM_PAUSE, "Telegram pause time", "RWA", SETTING, 0, 255, 0),
        global_row(GP.HOST_ADDRESS, "Serial host address", "RWA", SETTING, 0, 255, 2),
        global_row(GP.AUTO_START, "Auto start mode", "RWA", SETTING, 0, 1, 0),
        global_row(GP.CODE_PROTECTION, "TMCL code protection", "RWA", SETTING, 0, 3, 0),
        global_row(GP.CAN_HEARTBEAT, "CAN heartbeat", "RWA", SETTING, 0, 65535, 0),
        global_row(GP.CAN_SECONDARY_ID, "CAN secondary address", "RWA", SETTING, 0, 2047, 0),
        global_row(GP.COORDINATE_STORAGE, "Coordinate storage", "RWA", SETTING, 0, 1, 0),
        global_row(GP.DO_NOT_RESTORE_USER_VARIABLES, "Do not restore user variables", "RWA",
                   SETTING, 0, 1, 0),
        global_row(GP.SERIAL_SECONDARY_ADDRESS, "Serial secondary address", "RWA", SETTING,
                   0, 255, 0),
        global_row(GP.APPLICATION_STATUS, "TMCL application status", "R", PROGRAM, 0, 3),
        global_row(GP.DOWNLOAD_MODE, "Download mode", "R", PROGRAM, 0, 1),
        global_row(GP.PROGRAM_COUNTER, "TMCL program counter", "R", PROGRAM, 0, INT32_MAX),
        global_row(GP.TICK_TIMER, "TMCL tick timer", "RW", TIME, 0, INT32_MAX),
        global_row(GP.RANDOM_NUMBER, "Random number", "RW", ACCESS, 0, INT32_MAX),
        global_row(GP.SUPPRESS_REPLY, "Suppress reply", "RW", SETTING, 0, 1, 0),
    )
}

def bank0(*extra: ParamSpec) -> dict[int, ParamSpec]:
    """The family's bank 0 and the rows a module adds."""
    return {**BANK0_PARAMETERS, **{spec.number: spec for spec in extra}}

#: Bank-0 rows of the CAN interface (the modules without one keep them hidden, access "").
CAN_PARAMETERS = frozenset({GP.CAN_BIT_RATE, GP.CAN_REPLY_ID, GP.CAN_ID, GP.CAN_HEARTBEAT,
                            GP.CAN_SECONDARY_ID})

def without_can(table: dict[int, ParamSpec]) -> dict[int, ParamSpec]:
    """A bank 0 whose CAN rows are hidden (the module has no CAN interface): GGP/SGP answer
    status 3 for them; the module model still keeps its CAN address inside."""
    return {n: dataclasses.replace(spec, access="") if n in CAN_PARAMETERS else spec
            for n, spec in table.items()}

#: Bank-0 rows of the TMCM-1110 and the TMCM-1140 generation (the TMCM-1111 among them).
IO_MODE = global_row(GP.IO_MODE, "I/O mode", "RWA", SETTING, 0, 255, 0)
LAST_TMCL_ERROR = global_row(GP.LAST_TMCL_ERROR, "Last TMCL error", "R", ACCESS, 0, 255, 0)

# -- bank 2: user variables (Table 18) ----------------------------------------------------------

USER_VARIABLE_COUNT = 256
STORABLE_USER_VARIABLES = 56  # 0..55 can be stored with STGP (Table 18, fw 1.05 note)

BANK2_PARAMETERS: dict[int, ParamSpec] = {
    n: ParamSpec(n, f"User variable #{n}", "RWE" if n < STORABLE_USER_VARIABLES else "RW",
                 motion=SETTING)
    for n in range(USER_VARIABLE_COUNT)
}

# -- bank 3: interrupt set-up (Tables 19-20) ----------------------------------------------------

def bank3(switch_motors: int, inputs: int) -> dict[int, ParamSpec]:
    """Timer periods 0..2, stop switch triggers 27.. (two per motor), input triggers 39.."""
    rows = {n: global_row(n, f"Timer {n} period", "RW", SETTING, 0, UINT32_MAX, 0, unsigned=True)
            for n in range(3)}
    for motor in range(switch_motors):
        for side, number in (("left", 27 + 2 * motor), ("right", 28 + 2 * motor)):
            rows[number] = global_row(number, f"Stop {side} {motor} trigger transition", "RW",
                                      SETTING, 0, 3)
    for port in range(inputs):
        rows[39 + port] = global_row(39 + port, f"Input {port} trigger transition", "RW",
                                     SETTING, 0, 3)
    return rows

# -- the serial line and the CAN bus ------------------------------------------------------------

#: GP 65 value -> bits per second (Table 16).
BAUD_RATES = dict(enumerate((9600, 14400, 19200, 28800, 38400, 57600, 76800, 115200, 230400,
                             250000, 500000, 1000000)))
#: GP 69 (CAN bit rate): index -> bits per second (Table 16).
CAN_BIT_RATES = {2: 20_000, 3: 50_000, 4: 100_000, 5: 125_000, 6: 250_000, 7: 500_000,
                 8: 1_000_000}

# -- I/O of the TMC429 modules and the TMCM-1140 generation (the TMCM-1111 among them) ----------

#: Analogue inputs read 12 bit (0..4095); a line reads 1 from half scale up.
ANALOG_FULL_SCALE = 4095
DIGITAL_THRESHOLD = 2048
PROGRAM_MEMORY = 2048  # TMCL commands (TMCM-6110 manual V1.31 §4)
COORDINATES = 21  # 0..20 as across the TMCL family; coordinate 0 is RAM only

