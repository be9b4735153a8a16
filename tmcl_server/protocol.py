"""TMCL wire codec: 9-byte serial frames, the 7/8-byte CAN payload, and byte-stream framing.

Serial request  ``[address][opcode][type][motor][value MSB..LSB][checksum]``
Serial reply    ``[host][module][status][opcode][value MSB..LSB][checksum]``
CAN request     ``[opcode][type][motor][value x4]`` (+ one pad byte from some hosts)
CAN reply       ``[module CAN id & 0xFF][status][opcode][value x4]``
Checksum        8-bit sum of the preceding bytes (manual §3.1.1).
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from typing import NamedTuple

from tmcl_spec.numbers import to_int32

FRAME_LENGTH = 9
CAN_PAYLOAD_LENGTH = 7
#: A partial frame older than this (gap between bytes) is discarded, as real modules do.
RESYNC_GAP_NS = 5_000_000

_FRAME = struct.Struct(">BBBBiB")
_BODY = struct.Struct(">BBBBi")
_BODY_UNSIGNED = struct.Struct(">BBBBI")
_CAN = struct.Struct(">BBBi")
_CAN_REPLY_TAIL = struct.Struct(">BBi")


def checksum(data: bytes | bytearray | memoryview) -> int:
    return sum(data) & 0xFF


class Request(NamedTuple):
    """One TMCL command as it arrives (address is the serial target address or CAN id).

    A NamedTuple rather than a dataclass: it is built for every request on the hot path.
    """

    address: int
    opcode: int
    type: int
    motor: int
    value: int  # signed 32-bit

    def encode(self) -> bytes:
        body = _BODY.pack(self.address & 0xFF, self.opcode, self.type, self.motor,
                          to_int32(self.value))
        return body + bytes((checksum(body),))

    def encode_can(self) -> bytes:
        return _CAN.pack(self.opcode, self.type, self.motor, to_int32(self.value))


class Reply(NamedTuple):
    host: int
    module: int
    status: int
    opcode: int
    value: int  # signed 32-bit

    def encode(self) -> bytes:
        body = _BODY_UNSIGNED.pack(self.host & 0xFF, self.module & 0xFF, self.status,
                                   self.opcode & 0xFF, self.value & 0xFFFFFFFF)
        return body + bytes((sum(body) & 0xFF,))

    def encode_can(self) -> bytes:
        """CAN payload: the module's id byte replaces host+module, no checksum."""
        return bytes((self.module & 0xFF,)) + _CAN_REPLY_TAIL.pack(
            self.status, self.opcode & 0xFF, to_int32(self.value))


@dataclass(frozen=True, slots=True)
class RawReply:
    """A reply with a special layout (command 136 type 0, command 134) sent as-is."""

    data: bytes
    can_data: bytes = b""

    def encode(self) -> bytes:
        return self.data

    def encode_can(self) -> bytes:
        return self.can_data or self.data[1:FRAME_LENGTH]


AnyReply = Reply | RawReply


class ChecksumError(ValueError):
    """A complete frame whose checksum byte does not match."""

    def __init__(self, address: int, frame: bytes) -> None:
        super().__init__(f"wrong checksum in frame {frame.hex(' ')}")
        self.address = address
        self.frame = frame


def decode_request(frame: bytes | bytearray | memoryview) -> Request:
    """Parse a 9-byte frame; raise ChecksumError (with the address) if the checksum is wrong."""
    if len(frame) != FRAME_LENGTH:
        raise ValueError(f"a TMCL frame has {FRAME_LENGTH} bytes, got {len(frame)}")
    fields = _FRAME.unpack(frame)
    if sum(frame[:8]) & 0xFF != fields[5]:
        raise ChecksumError(fields[0], bytes(frame))
    return tuple.__new__(Request, fields[:5])  # skips the NamedTuple's Python-level __new__


def decode_reply(frame: bytes | bytearray) -> Reply:
    host, module, status, opcode, value, check = _FRAME.unpack(frame)
    if checksum(frame[:8]) != check:
        raise ChecksumError(host, bytes(frame))
    return Reply(host, module, status, opcode, value)


def decode_can_request(can_id: int, data: bytes | bytearray) -> Request:
    """Parse a CAN payload of 7 bytes (or 8: pytrinamic appends a pad byte)."""
    if len(data) not in (CAN_PAYLOAD_LENGTH, CAN_PAYLOAD_LENGTH + 1):
        raise ValueError(f"a TMCL CAN request has 7 or 8 data bytes, got {len(data)}")
    opcode, type_, motor, value = _CAN.unpack_from(data)
    return Request(can_id, opcode, type_, motor, value)


def decode_can_reply(data: bytes | bytearray) -> Reply:
    module = data[0]
    status, opcode, value = _CAN_REPLY_TAIL.unpack_from(data, 1)
    return Reply(0, module, status, opcode, value)


class FrameAssembler:
    """Cut a byte stream into 9-byte frames, discarding a partial frame after a 5 ms gap.

    Time is passed in by the caller (monotonic nanoseconds of the *wire*, not the simulated
    clock), so the rule is deterministic under test.  A caller that cannot know when bytes
    arrived (a socket read late because the server was busy) feeds without a time and decides
    the pause itself, then calls :meth:`drop` (transports/base.py, :class:`StreamSession`).
    """

    __slots__ = ("buffer", "gap_ns", "last_byte_ns")

    def __init__(self, gap_ns: int = RESYNC_GAP_NS) -> None:
        #: Bytes of an incomplete frame.  Empty means a whole 9-byte read is a frame by
        #: itself: stream sessions check this and skip :meth:`feed` on their hot path.
        self.buffer = bytearray()
        self.last_byte_ns: int | None = None
        self.gap_ns = gap_ns

    @property
    def pending(self) -> int:
        """Number of bytes of an incomplete frame held back."""
        return len(self.buffer)

    def expired(self, now_ns: int) -> bool:
        """Whether the partial frame held back is older than the pause and will be dropped."""
        last = self.last_byte_ns
        return bool(self.buffer) and last is not None and now_ns - last > self.gap_ns

    def drop(self) -> bytes:
        """Discard the partial frame (the line paused); returns its bytes."""
        data = bytes(self.buffer)
        self.buffer.clear()
        return data

    def feed(self, data: bytes, now_ns: int | None = None) -> Iterator[bytes]:
        """The frames ``data`` completes.  With ``now_ns``, a partial frame whose last byte is
        more than the gap older is dropped first; without, no time rule applies here."""
        buffer = self.buffer
        if now_ns is not None:
            if self.expired(now_ns):
                buffer.clear()
            self.last_byte_ns = now_ns
        if not buffer and len(data) == FRAME_LENGTH:
            yield bytes(data)
            return
        buffer += data
        while len(buffer) >= FRAME_LENGTH:
            frame = bytes(buffer[:FRAME_LENGTH])
            del buffer[:FRAME_LENGTH]
            yield frame
