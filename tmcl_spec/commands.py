"""Commands, their operands and their replies (firmware manual §3, Tables 4, 5 and 13).

The single home of opcode numbers and mnemonics, the symbolic operand names the assembler
accepts (ABS/REL/COORD, ADD..SWAP, ZE..EPO, ...), the reply status codes and the I/O banks.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple


class Opcode(IntEnum):
    """Command numbers; names are the TMCL mnemonics (control commands have none in TMCL)."""

    ROR = 1
    ROL = 2
    MST = 3
    MVP = 4
    SAP = 5
    GAP = 6
    STAP = 7
    RSAP = 8
    SGP = 9
    GGP = 10
    STGP = 11
    RSGP = 12
    RFS = 13
    SIO = 14
    GIO = 15
    CALC = 19
    COMP = 20
    JC = 21
    JA = 22
    CSUB = 23
    RSUB = 24
    EI = 25
    DI = 26
    WAIT = 27
    STOP = 28
    SCO = 30
    GCO = 31
    CCO = 32
    CALCX = 33
    AAP = 34
    AGP = 35
    CLE = 36
    VECT = 37
    RETI = 38
    ACO = 39
    # Customer-specific extensions (§3.6.34): "user defined"
    UF0 = 64
    UF1 = 65
    UF2 = 66
    UF3 = 67
    UF4 = 68
    UF5 = 69
    UF6 = 70
    UF7 = 71
    # TMCL control commands (direct mode only, Table 13)
    STOP_APPLICATION = 128
    RUN_APPLICATION = 129
    STEP_APPLICATION = 130
    RESET_APPLICATION = 131
    ENTER_DOWNLOAD_MODE = 132
    EXIT_DOWNLOAD_MODE = 133
    READ_PROGRAM_MEMORY = 134
    GET_APPLICATION_STATUS = 135
    GET_FIRMWARE_VERSION = 136
    RESTORE_FACTORY_SETTINGS = 137
    TARGET_REACHED_EVENT = 138
    # Motion-controller register access for debugging (issue 3)
    WRITE_MC = 146
    READ_MC = 147
    READ_MC_PYTRINAMIC = 148


class MoveType(IntEnum):
    ABS = 0
    REL = 1
    COORD = 2


class RfsType(IntEnum):
    START = 0
    STOP = 1
    STATUS = 2


class CalcOp(IntEnum):
    """CALC types 0..9 and CALCX types 0..10 (SWAP is CALCX only)."""

    ADD = 0
    SUB = 1
    MUL = 2
    DIV = 3
    MOD = 4
    AND = 5
    OR = 6
    XOR = 7
    NOT = 8
    LOAD = 9
    SWAP = 10


class Condition(IntEnum):
    """JC conditions."""

    ZE = 0
    NZ = 1
    EQ = 2
    NE = 3
    GT = 4
    GE = 5
    LT = 6
    LE = 7
    ETO = 8
    EAL = 9
    EDV = 10
    EPO = 11
    ESD = 12


class WaitCondition(IntEnum):
    TICKS = 0
    POS = 1
    REFSW = 2
    LIMSW = 3
    RFS = 4


class ErrorFlag(IntEnum):
    """CLE operands."""

    ALL = 0
    ETO = 1
    EAL = 2
    EDV = 3
    EPO = 4
    ESD = 5


class ApplicationStatus(IntEnum):
    """GP 128 / command 135: what the standalone program is doing."""

    STOP = 0
    RUN = 1
    STEP = 2
    RESET = 3


class CodeProtection(IntEnum):
    """GP 81 bits: protect the stored program against read-back and/or overwriting."""

    READ = 1
    WRITE = 2


#: Command 137 restores the factory defaults only with this value (§3.6.33).
FACTORY_RESET_KEY = 1234
#: SCO/GCO with motor 255: the forms that copy coordinates between RAM and EEPROM (§3.6.22).
MOTOR_ALL = 255
#: MVP COORD's motor field (0..255, §3.6.4): with this bit set, bits 0..5 are a motor mask.
COORD_MOTOR_MASK_FLAG = 0x80
#: The user functions UF0..UF7 (§3.6.34).
USER_FUNCTIONS = frozenset(range(Opcode.UF0, Opcode.UF7 + 1))
#: Commands whose replies GP 255 never suppresses (§5.1).
ALWAYS_REPLIED = frozenset({Opcode.GAP, Opcode.GGP, Opcode.GIO})
#: Commands whose type is an axis parameter number (the motor field names the axis) and
#: whose type is a global parameter number (the motor field names the bank).
AXIS_PARAMETER_COMMANDS = frozenset({Opcode.SAP, Opcode.GAP, Opcode.STAP, Opcode.RSAP, Opcode.AAP})
GLOBAL_PARAMETER_COMMANDS = frozenset({Opcode.SGP, Opcode.GGP, Opcode.STGP, Opcode.RSGP,
                                       Opcode.AGP})
#: Commands that only read: they store nothing and cannot create or move an internal event.
READ_ONLY_OPCODES = frozenset({int(Opcode.GAP), int(Opcode.GGP), int(Opcode.GIO),
                               int(Opcode.GET_FIRMWARE_VERSION)})


#: Reply status of a successful command, as a plain int for hot paths.
STATUS_OK = 100


class Status(IntEnum):
    """Reply status codes: Table 4 (1..6, 100, 101), the 138 event status (128), and the codes
    Trinamic's TMCL firmware uses beyond Table 4 (7..10; why: docs/protocol.md)."""

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
    DELAYED = 128  # the evaluation firmware's REPLY_DELAYED: not finished yet (an alias)


class IOBank(IntEnum):
    DIGITAL_INPUTS = 0
    ANALOG_INPUTS = 1
    OUTPUTS = 2


# -- operand syntax (assembler and disassembler) --------------------------------------------

class Field(NamedTuple):
    """One source operand: which instruction field it fills and which symbols it accepts."""

    slot: str  # "type", "motor" or "value"
    symbols: type[IntEnum] | None = None
    address: bool = False  # a program address: labels make sense here


_TYPE = Field("type")
_MOTOR = Field("motor")
_VALUE = Field("value")
_ADDRESS = Field("value", address=True)

#: Operands of each mnemonic in source order (fields not listed are 0).
OPERANDS: dict[Opcode, tuple[Field, ...]] = {
    Opcode.ROR: (_MOTOR, _VALUE),
    Opcode.ROL: (_MOTOR, _VALUE),
    Opcode.MST: (_MOTOR,),
    Opcode.MVP: (Field("type", MoveType), _MOTOR, _VALUE),
    Opcode.SAP: (_TYPE, _MOTOR, _VALUE),
    Opcode.GAP: (_TYPE, _MOTOR),
    Opcode.STAP: (_TYPE, _MOTOR),
    Opcode.RSAP: (_TYPE, _MOTOR),
    Opcode.SGP: (_TYPE, _MOTOR, _VALUE),
    Opcode.GGP: (_TYPE, _MOTOR),
    Opcode.STGP: (_TYPE, _MOTOR),
    Opcode.RSGP: (_TYPE, _MOTOR),
    Opcode.RFS: (Field("type", RfsType), _MOTOR),
    Opcode.SIO: (_TYPE, _MOTOR, _VALUE),
    Opcode.GIO: (_TYPE, _MOTOR),
    Opcode.CALC: (Field("type", CalcOp), _VALUE),
    Opcode.COMP: (_VALUE,),
    Opcode.JC: (Field("type", Condition), _ADDRESS),
    Opcode.JA: (_ADDRESS,),
    Opcode.CSUB: (_ADDRESS,),
    Opcode.RSUB: (),
    Opcode.EI: (_TYPE,),
    Opcode.DI: (_TYPE,),
    Opcode.WAIT: (Field("type", WaitCondition), _MOTOR, _VALUE),
    Opcode.STOP: (),
    Opcode.SCO: (_TYPE, _MOTOR, _VALUE),
    Opcode.GCO: (_TYPE, _MOTOR),
    Opcode.CCO: (_TYPE, _MOTOR),
    Opcode.CALCX: (Field("type", CalcOp),),
    Opcode.AAP: (_TYPE, _MOTOR),
    Opcode.AGP: (_TYPE, _MOTOR),
    Opcode.CLE: (Field("type", ErrorFlag),),
    Opcode.VECT: (_TYPE, _ADDRESS),
    Opcode.RETI: (),
    Opcode.ACO: (_TYPE, _MOTOR),
    **{opcode: (_TYPE, _MOTOR, _VALUE) for opcode in (
        Opcode.UF0, Opcode.UF1, Opcode.UF2, Opcode.UF3,
        Opcode.UF4, Opcode.UF5, Opcode.UF6, Opcode.UF7)},
}

#: The symbolic names of the type field, per command that has them (MVP: ABS/REL/COORD, ...).
TYPE_SYMBOLS: dict[int, type[IntEnum]] = {
    opcode: f.symbols for opcode, fields in OPERANDS.items()
    for f in fields if f.slot == "type" and f.symbols is not None
}

#: CALC accepts ADD..LOAD only; SWAP exists for CALCX alone.
CALC_MAX_OPERATION = CalcOp.LOAD

#: The operands as the manual's "Mnemonic:" lines name them (§3.6), in source order; STAP and
#: RSAP (no section of their own in this manual) follow STGP/RSGP, ACO its siblings.  Messages
#: and ``--help`` quote them; :data:`OPERANDS` says which field each fills.
OPERAND_NAMES: dict[Opcode, tuple[str, ...]] = {
    Opcode.ROR: ("axis", "velocity"),
    Opcode.ROL: ("axis", "velocity"),
    Opcode.MST: ("axis",),
    Opcode.MVP: ("ABS|REL|COORD", "axis", "position|offset|coordinate"),
    Opcode.SAP: ("parameter number", "axis", "value"),
    Opcode.GAP: ("parameter number", "axis"),
    Opcode.STAP: ("parameter number", "axis"),
    Opcode.RSAP: ("parameter number", "axis"),
    Opcode.SGP: ("parameter number", "bank", "value"),
    Opcode.GGP: ("parameter number", "bank"),
    Opcode.STGP: ("parameter number", "bank"),
    Opcode.RSGP: ("parameter number", "bank"),
    Opcode.RFS: ("START|STOP|STATUS", "motor"),
    Opcode.SIO: ("port number", "bank number", "value"),
    Opcode.GIO: ("port number", "bank number"),
    Opcode.CALC: ("operation", "operand"),
    Opcode.COMP: ("operand",),
    Opcode.JC: ("condition", "label"),
    Opcode.JA: ("label",),
    Opcode.CSUB: ("label",),
    Opcode.RSUB: (),
    Opcode.EI: ("interrupt number",),
    Opcode.DI: ("interrupt number",),
    Opcode.WAIT: ("condition", "motor number", "ticks"),
    Opcode.STOP: (),
    Opcode.SCO: ("coordinate number", "motor number", "position"),
    Opcode.GCO: ("coordinate number", "motor number"),
    Opcode.CCO: ("coordinate number", "motor number"),
    Opcode.CALCX: ("operation",),
    Opcode.AAP: ("parameter number", "motor number"),
    Opcode.AGP: ("parameter number", "bank number"),
    Opcode.CLE: ("flags",),
    Opcode.VECT: ("interrupt number", "label"),
    Opcode.RETI: (),
    Opcode.ACO: ("coordinate number", "motor number"),
    **{opcode: ("type", "motor/bank", "value") for opcode in (
        Opcode.UF0, Opcode.UF1, Opcode.UF2, Opcode.UF3,
        Opcode.UF4, Opcode.UF5, Opcode.UF6, Opcode.UF7)},
}


def mnemonic_syntax(opcode: Opcode) -> str:
    """The manual's form of a command, e.g. ``ROR <axis>, <velocity>``."""
    names = OPERAND_NAMES[opcode]
    return opcode.name + (" " + ", ".join(f"<{name}>" for name in names) if names else "")
