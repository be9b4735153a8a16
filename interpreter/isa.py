"""TMCL programs as stored: one instruction, the TMCL-IDE's 8-byte binary record, memory limits.

Opcodes and operand names are vocabulary of the whole product: :mod:`tmcl_spec.commands`.
"""

from __future__ import annotations

import struct
from typing import NamedTuple

from tmcl_spec.numbers import to_int32

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
