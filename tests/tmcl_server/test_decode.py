"""The decoder: compact parameter names from the tables, frames as text, dumps and captures."""

from __future__ import annotations

import pytest

from tests.conftest import Bench
from tmcl_server.decode import Conversation, Frame, decode_text, describe_request, parse_capture, parse_hex
from tmcl_server.protocol import Request
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.modules import MODULE_TYPES, module_type
from tmcl_spec.names import compact_name, names_of
from tmcl_spec.parameters import AP, GP


def test_compact_names_are_derived_from_the_manuals_names() -> None:
    assert compact_name("Maximum positioning speed") == "MaxPositioningSpeed"
    assert compact_name("Chopper off time (TOff)") == "ChopperOffTime"
    assert compact_name("Speed threshold for coolStep / fullstep") == "SpeedThresholdForCoolStep"
    assert compact_name("User variable #17") == "UserVariable17"
    assert compact_name("Velocity VSTART") == "VelocityVSTART"


@pytest.mark.parametrize("key", sorted(MODULE_TYPES))
def test_every_table_of_every_module_type_names_each_row_once(key: str) -> None:
    kind = module_type(key)
    for table in (kind.axis_parameters, *kind.global_parameters.values()):
        names = names_of(table)
        spelled = [name.lower() for _, name in names]
        assert len(set(spelled)) == len(spelled) == len(table)
        for number, name in names:
            assert names.number(name) == number  # the name leads back to its row
            assert names.number(name.upper()) == number  # whatever the case
            assert names.number(table[number].name) == number  # the manual's wording too
            assert names.number(str(number)) == number


def test_requests_read_like_the_manual() -> None:
    assert describe_request(Opcode.SAP, AP.MAX_SPEED, 0, 51200) == "SAP 4 MaxPositioningSpeed m0 = 51200"
    assert describe_request(Opcode.GAP, AP.ACTUAL_POSITION, 3, 0) == "GAP 1 ActualPosition m3"
    assert describe_request(Opcode.SGP, GP.SERIAL_ADDRESS, 0, 3) == "SGP 66 SerialAddress b0 = 3"
    assert describe_request(Opcode.GGP, 7, 2, 0) == "GGP 7 UserVariable7 b2"
    assert describe_request(Opcode.MVP, 1, 2, -200) == "MVP REL m2 -200"
    assert describe_request(Opcode.WAIT, 1, 0, 0) == "WAIT POS m0 0"
    assert describe_request(Opcode.JC, 0, 0, 12) == "JC ZE 12"
    assert describe_request(Opcode.SAP, 99, 0, 5) == "SAP 99 m0 = 5"  # no such row: no name
    assert describe_request(Opcode.RUN_APPLICATION, 1, 0, 7) == "RUN_APPLICATION from 7"
    assert describe_request(Opcode.TARGET_REACHED_EVENT, 0, 0, 0b101) == \
        "TARGET_REACHED_EVENT next move axes 0,2"
    assert describe_request(200, 1, 2, 3) == "opcode 200 type 1 motor 2 value 3"


def _conversation(bench: Bench) -> bytes:
    """Real requests and the module's real replies, as a host's log would show them."""
    stream = b""
    for request in (Request(1, Opcode.SAP, AP.MAX_SPEED, 0, 51200),
                    Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0),
                    Request(1, Opcode.GET_FIRMWARE_VERSION, 0, 0, 0),
                    Request(1, Opcode.GET_FIRMWARE_VERSION, 1, 0, 0),
                    Request(1, Opcode.SAP, 200, 0, 0),
                    Request(1, Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0),
                    Request(1, Opcode.MVP, 0, 1, 1000),
                    Request(1, Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0),
                    Request(1, Opcode.READ_PROGRAM_MEMORY, 0, 0, 0)):
        frame = request.encode()
        (_, reply), = bench.simulation.handle_serial_frame(frame, bench.sink)
        stream += frame + reply.encode()
    torn = Request(1, Opcode.GAP, 1, 0, 0).encode()[:8] + b"\x00"  # a wrong checksum
    (_, reply), = bench.simulation.handle_serial_frame(torn, bench.sink)
    return stream + torn + reply.encode()


def test_a_real_conversation_decodes_request_by_reply(bench: Bench) -> None:
    stream = _conversation(bench)
    decoded = decode_text(stream.hex(" "))
    assert [d.kind for d in decoded] == [
        "request", "reply", "request", "reply", "request", "version", "request", "reply",
        "request", "reply", "request", "reply", "request", "reply", "request", "reply",
        "request", "program", "bad-checksum", "reply"]
    texts = [d.text for d in decoded]
    assert texts[1] == "module 1 → host 2: SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK"
    assert texts[3].endswith("GAP 4 MaxPositioningSpeed m0 → 100 OK = 51200")
    assert texts[5].endswith('→ "6212V105"')
    assert texts[7].endswith(f"→ 100 OK = {6212 << 16 | 1 << 8 | 5} (6212 V1.05)")
    assert texts[9].endswith("SAP 200 m0 = 0 → 3 WRONG_TYPE")
    assert texts[13].endswith("MVP ABS m1 1000 → 101 LOADED")
    assert texts[17].endswith("→ @0: MVP ABS m1 1000")
    assert "should be 0x" in texts[18]
    assert texts[19].endswith("GAP 1 ActualPosition m0 → 1 WRONG_CHECKSUM")
    assert decoded[1].fields["status"] == Status.OK


def test_hex_in_any_usual_spelling() -> None:
    frame = bytes([1, 6, 4, 0, 0, 0, 0, 0, 11])
    for text in ("01 06 04 00 00 00 00 00 0b", "0x01,0x06,0x04,0x00,0x00,0x00,0x00,0x00,0x0B",
                 "010604000000000b", "12:00:01.5 TX: 01 06 04 00 00 00 00 00 0b",
                 "00000000  01 06 04 00 00 00 00 00  0b  |.........|"):
        assert parse_hex(text.replace("010604000000000b", "01060400000000000b")) == frame, text


def test_candump_lines_are_can_frames_with_their_ids() -> None:
    capture = ("  can0  001   [8]  06 04 00 00 00 00 00 00\n"
               "  can0  002   [8]  01 64 06 00 00 c8 00 00\n"
               "(1700000000.000100) can0 001#0601000000000000\n"
               "(1700000000.000200) can0 002#01640600000064\n"
               "(1700000000.000300) can0 002#01808a00000001\n")
    frames = parse_capture(capture)
    assert [f.can_id for f in frames] == [1, 2, 1, 2, 2]
    decoded = list(Conversation().decode(frames))
    assert [d.kind for d in decoded] == ["request", "reply", "request", "reply", "event"]
    assert decoded[1].text == "module 1 → id 002: GAP 4 MaxPositioningSpeed m0 → 100 OK = 51200"
    assert decoded[3].text.endswith("GAP 1 ActualPosition m0 → 100 OK = 100")
    assert decoded[4].text.endswith("→ 128 TARGET_REACHED_EVENT axes 0")


def test_leftover_bytes_are_reported_not_swallowed() -> None:
    decoded = list(Conversation().decode([Frame(bytes([1, 6, 4, 0, 0, 0, 0, 0, 11, 1, 6]))]))
    assert [d.kind for d in decoded] == ["request", "incomplete"]
