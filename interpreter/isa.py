"""TMCL programs as stored: one instruction, the TMCL-IDE's 8-byte binary record, memory limits.

Opcodes and operand names are vocabulary of the whole product: :mod:`tmcl_spec.commands`.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from tmcl_spec.commands import Opcode
from tmcl_spec.numbers import to_int32

# -- program memory ---------------------------------------------------------------------------

PROGRAM_MEMORY_SIZE = 6144  # TMCL commands the TMCM-6212 can store (manual §1, "Software")
CALL_STACK_DEPTH = 8  # CSUB nesting (§3.6.18)
WAIT_TICK_NS = 10_000_000  # one WAIT tick is 10 ms (§3.6.20 footnote)
RECORD_LENGTH = 8  # one stored command in a .bin file: opcode, type, motor, value x4, checksum

_RECORD = struct.Struct(">BBBi")

# -- opcodes as plain ints, for the dispatch loop (interpreter.machine) and the pass analysis
# (interpreter.skipping), which compare them on every instruction -------------------------------

OP_CALC, OP_COMP, OP_JC, OP_JA = Opcode.CALC.value, Opcode.COMP.value, Opcode.JC.value, Opcode.JA.value
OP_CALCX, OP_CSUB, OP_RSUB = Opcode.CALCX.value, Opcode.CSUB.value, Opcode.RSUB.value
OP_STOP, OP_WAIT = Opcode.STOP.value, Opcode.WAIT.value
OP_AAP, OP_AGP, OP_ACO = Opcode.AAP.value, Opcode.AGP.value, Opcode.ACO.value
OP_SAP, OP_SGP, OP_SCO = Opcode.SAP.value, Opcode.SGP.value, Opcode.SCO.value
OP_GCO, OP_RFS, OP_GAP = Opcode.GCO.value, Opcode.RFS.value, Opcode.GAP.value
#: The opcodes the interpreter executes itself (the rest go to the module through its port):
#: empty memory and STOP end a program, WAIT waits, and the ones that only touch the
#: interpreter's own state.
INTERNAL_OPCODES = frozenset({0, OP_STOP, OP_WAIT, *(int(op) for op in (
    Opcode.CALCX, Opcode.CSUB, Opcode.RSUB, Opcode.EI, Opcode.DI, Opcode.VECT, Opcode.RETI,
    Opcode.CLE))})

# -- how a batch of executed instructions ended (machine and skipping share these) -------------

CONTINUE = 0  # keep going
YIELD = 1  # a module command may have moved an event: let the caller re-plan
STOPPED = 2  # STOP or end of program
WAITING = 3  # a WAIT is in progress
INTERRUPTS = 4  # interrupt state changed: check for a dispatch before the next instruction
LOOP = 5  # a backward jump reached a loop head: see whether its passes can be skipped


class Instruction(NamedTuple):
    """One stored TMCL command: the 7 bytes of a request without address and checksum."""

    opcode: int
    type: int = 0
    motor: int = 0
    value: int = 0

    def encode(self) -> bytes:
        """The TMCL-IDE's 8-byte binary record (checksum = 8-bit sum of the first 7 bytes)."""
        body = _RECORD.pack(self.opcode, self.type, self.motor, to_int32(self.value))
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
    program = []
    for index, offset in enumerate(range(0, len(data), RECORD_LENGTH)):
        try:
            program.append(Instruction.decode(data[offset:offset + RECORD_LENGTH]))
        except ValueError as exc:
            last = offset + RECORD_LENGTH - 1
            raise ValueError(f"record {index} (bytes {offset}..{last}): {exc}") from None
    return program
