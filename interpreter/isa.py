"""The TMCL instruction set of the TMCM-6212 (firmware manual §3.4, Table 5 and Table 13).

This is the single home of opcode numbers, mnemonics and the symbolic operand names that the
assembler accepts (ABS/REL/COORD, ADD..SWAP, ZE..EPO, ...).  The module model imports it to
dispatch direct-mode commands; the interpreter and the assembler use it for programs.
"""

from __future__ import annotations

from enum import IntEnum


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


#: Opcodes that are control commands: never stored in download mode, never in a program.
CONTROL_OPCODES: frozenset[int] = frozenset(range(128, 139))

#: Opcodes that may appear in a stored TMCL program (everything that has a mnemonic).
PROGRAM_OPCODES: frozenset[int] = frozenset(op for op in Opcode if op < 128)


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
