"""The codec against every binary example printed in the firmware manual."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmcl_server.protocol import (
    FRAME_LENGTH,
    ChecksumError,
    FrameAssembler,
    Reply,
    Request,
    checksum,
    decode_can_reply,
    decode_can_request,
    decode_reply,
    decode_request,
)

# (mnemonic, opcode, type, motor, value, checksum) from the manual's "Binary Form" tables.
MANUAL_REQUESTS = [
    ("ROR 0, 51200", 1, 0, 0, 51200, 0xCA),
    ("ROL 0, 51200", 2, 0, 0, 51200, 0xCB),
    ("MST 0", 3, 0, 0, 0, 0x04),
    ("MVP ABS, 0, 90000", 4, 0, 0, 90000, 0xF5),
    ("MVP REL, 0, -10000", 4, 1, 0, -10000, 0xCC),
    ("MVP COORD, 0, 8", 4, 2, 0, 8, 0x0F),
    ("SAP 4, 0, 51200", 5, 4, 0, 51200, 0xD2),
    ("GAP 1, 0", 6, 1, 0, 0, 0x08),
    ("SGP 66, 0, 3", 9, 66, 0, 3, 0x4F),
    ("GGP 66, 0", 10, 66, 0, 0, 0x4D),
    ("STGP 42, 2", 11, 42, 2, 0, 0x38),
    ("RSGP 42, 2", 12, 42, 2, 0, 0x39),
    ("RFS START, 0", 13, 0, 0, 0, 0x0E),
    ("SIO 3, 2, 1", 14, 3, 2, 1, 0x15),
    ("GIO 0, 1", 15, 0, 1, 0, 0x11),
    ("CALC MUL, -5000", 19, 2, 0, -5000, 0x78),
    ("COMP 1000", 20, 0, 0, 1000, 0x00),
    ("JC GE, 10", 21, 5, 0, 10, 0x25),
    ("JA 10", 22, 0, 0, 10, 0x21),
    ("CSUB 100", 23, 0, 0, 100, 0x7C),
    ("RSUB", 24, 0, 0, 0, 0x19),
    ("WAIT POS, 0, 0", 27, 1, 0, 0, 0x1D),
    ("STOP", 28, 0, 0, 0, 0x1D),
    ("SCO 1, 0, 1000", 30, 1, 0, 1000, 0x0B),
    ("GCO 1, 0", 31, 1, 0, 0, 0x21),
    ("CCO 3, 0", 32, 1, 0, 0, 0x22),  # the manual prints type 01h for this example
    ("CALCX MUL", 33, 2, 0, 0, 0x24),
    ("AAP 0, 0", 34, 0, 0, 0, 0x23),
    ("AGP 42, 2", 35, 42, 2, 0, 0x50),
    ("CLE ETO", 36, 1, 0, 0, 0x26),
    ("EI 255", 25, 255, 0, 0, 0x19),
    ("DI 255", 26, 255, 0, 0, 0x1A),
    # The manual prints type FFh for VECT and RETI, but its checksums (58h, 27h) are those of
    # type 0: the checksum is right and the type column is a typo.
    ("VECT 0, 50", 37, 0, 0, 50, 0x58),
    ("RETI", 38, 0, 0, 0, 0x27),
    ("ACO 1, 0", 39, 1, 0, 0, 0x29),
    ("138 type 1 mask 5", 138, 1, 0, 5, 0x91),
]


@pytest.mark.parametrize(("name", "opcode", "type_", "motor", "value", "check"), MANUAL_REQUESTS,
                         ids=[r[0] for r in MANUAL_REQUESTS])
def test_manual_request_examples(name, opcode, type_, motor, value, check):
    frame = Request(1, opcode, type_, motor, value).encode()
    assert len(frame) == FRAME_LENGTH
    assert frame[-1] == check
    assert decode_request(frame) == Request(1, opcode, type_, motor, value)


def test_manual_reply_examples():
    gio = Reply(2, 1, 100, 15, 302).encode()
    assert gio.hex() == "020164" "0f" "0000012e" "a5"
    calc = Reply(2, 1, 100, 19, -5000).encode()
    assert calc[4:8] == bytes.fromhex("ffffec78") and calc[-1] == 0xDC
    assert decode_reply(gio) == Reply(2, 1, 100, 15, 302)


def test_ror_bytes_are_exactly_the_manual_table():
    assert Request(1, 1, 0, 0, 51200).encode() == bytes.fromhex("01 01 00 00 00 00 C8 00 CA")


def test_checksum_error_carries_address():
    frame = bytearray(Request(7, 6, 1, 0, 0).encode())
    frame[-1] ^= 0xFF
    with pytest.raises(ChecksumError) as info:
        decode_request(frame)
    assert info.value.address == 7


def test_can_forms():
    req = Request(5, 4, 0, 2, -10000)
    assert req.encode_can() == bytes.fromhex("04 00 02 ff ff d8 f0")
    assert decode_can_request(5, req.encode_can()) == req
    assert decode_can_request(5, req.encode_can() + b"\0") == req
    with pytest.raises(ValueError):
        decode_can_request(5, b"\x01\x02")
    reply = Reply(2, 5, 100, 6, 1234)
    assert reply.encode_can() == bytes.fromhex("05 64 06 00 00 04 d2")
    assert decode_can_reply(reply.encode_can()).value == 1234


@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255),
       st.integers(-(2**31), 2**31 - 1))
def test_request_round_trip(address, opcode, type_, motor, value):
    req = Request(address, opcode, type_, motor, value)
    frame = req.encode()
    assert frame[-1] == checksum(frame[:8])
    assert decode_request(frame) == req


def test_assembler_splits_and_joins():
    frames = [Request(1, 6, n, 0, n).encode() for n in range(3)]
    stream = b"".join(frames)
    asm = FrameAssembler()
    got = []
    for i in range(0, len(stream), 4):  # torn into 4-byte pieces, no pauses
        got.extend(asm.feed(stream[i:i + 4], now_ns=i * 1000))
    assert got == frames


def test_assembler_discards_partial_frame_after_5ms_gap():
    frame = Request(1, 6, 1, 0, 0).encode()
    asm = FrameAssembler()
    assert list(asm.feed(frame[:4], now_ns=0)) == []
    assert asm.pending == 4
    # 5 ms exactly is still the same frame ...
    assert list(asm.feed(frame[4:6], now_ns=5_000_000)) == []
    # ... but a gap of more than 5 ms throws the fragment away and starts afresh.
    assert list(asm.feed(frame, now_ns=10_000_001)) == [frame]
    assert asm.pending == 0
