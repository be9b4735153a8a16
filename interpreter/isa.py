"""The TMCL instruction set of the TMCM-6212 (firmware manual §3.4, Table 5 and Table 13).

This is the single home of opcode numbers, mnemonics and the symbolic operand names that the
assembler accepts (ABS/REL/COORD, ADD..SWAP, ZE..EPO, ...).  The module model imports it to
dispatch direct-mode commands; the interpreter and the assembler use it for programs.
"""

from __future__ import annotations

import struct
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


# -- program memory ---------------------------------------------------------------------------

PROGRAM_MEMORY_SIZE = 6144  # TMCL commands the TMCM-6212 can store (manual §1, "Software")
CALL_STACK_DEPTH = 8  # CSUB nesting (§3.6.18)
WAIT_TICK_NS = 10_000_000  # one WAIT tick is 10 ms (§3.6.20 footnote)
RECORD_LENGTH = 8  # one stored command in a .bin file: opcode, type, motor, value x4, checksum

_RECORD = struct.Struct(">BBBi")


class Instruction(NamedTuple):
    """One stored TMCL command: the 7 bytes of a request without address and checksum."""

    opcode: int
    type: int = 0
    motor: int = 0
    value: int = 0

    def encode(self) -> bytes:
        """The TMCL-IDE's 8-byte binary record (checksum = 8-bit sum of the first 7 bytes)."""
        value = (self.value & 0xFFFF_FFFF) - (1 << 32 if self.value & 0x8000_0000 else 0)
        body = _RECORD.pack(self.opcode, self.type, self.motor, value)
        return body + bytes((sum(body) & 0xFF,))

    @classmethod
    def decode(cls, record: bytes | bytearray | memoryview) -> Instruction:
        """Parse one 8-byte record; ValueError if the checksum does not match."""
        if len(record) != RECORD_LENGTH:
            raise ValueError(f"a program record has {RECORD_LENGTH} bytes, got {len(record)}")
        if sum(record[:7]) & 0xFF != record[7]:
            raise ValueError(f"wrong checksum in program record {bytes(record).hex(' ')}")
        return cls(*_RECORD.unpack_from(record))


EMPTY = Instruction(0)


def encode_program(instructions: list[Instruction]) -> bytes:
    return b"".join(ins.encode() for ins in instructions)


def decode_program(data: bytes) -> list[Instruction]:
    """A .bin file (no header, 8 bytes per command) as instructions."""
    if len(data) % RECORD_LENGTH:
        raise ValueError(f"binary program length {len(data)} is not a multiple of {RECORD_LENGTH}")
    return [Instruction.decode(data[i:i + RECORD_LENGTH]) for i in range(0, len(data), RECORD_LENGTH)]


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
}

#: The symbolic names of the type field, per command that has them (MVP: ABS/REL/COORD, ...).
TYPE_SYMBOLS: dict[Opcode, type[IntEnum]] = {
    opcode: f.symbols for opcode, fields in OPERANDS.items()
    for f in fields if f.slot == "type" and f.symbols is not None
}

#: CALC accepts ADD..LOAD only; SWAP exists for CALCX alone.
CALC_MAX_OPERATION = CalcOp.LOAD
