"""The decoder: compact parameter names from the tables, frames as text, dumps and captures."""

from __future__ import annotations

import inspect
import itertools
import json
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import can
import pytest

from tests.conftest import Bench
from tests.tmcl_server.test_cli import ServerProcess
from tmcl_server.decode import (
    Conversation,
    Frame,
    decode_text,
    describe_request,
    parse_capture,
    parse_hex,
    read_capture,
)
from tmcl_server.protocol import Request
from tmcl_server.tool import main as tmcl
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


# -- hex dumps of real tools and CAN logs of python-can, made at test time -----------------------

DUMPS = {
    "hexdump -C": ["hexdump", "-C"],
    "hexdump": ["hexdump"],  # 16-bit words, little-endian; an odd last byte shown as a word
    "od -A x -t x1z": ["od", "-A", "x", "-t", "x1z"],
    "od -t x1": ["od", "-t", "x1"],  # octal offsets
    "od -A d -t x1": ["od", "-A", "d", "-t", "x1"],
    "od -x": ["od", "-x"],
    "xxd": ["xxd"],
    "xxd -g1": ["xxd", "-g1"],
    "xxd -a": ["xxd", "-a"],  # squeezes repeated lines too
    "xxd -p": ["xxd", "-p"],
    "xxd -i": ["xxd", "-i"],
}


def _dump(command: list[str], path: Path) -> str:
    if shutil.which(command[0]) is None:
        pytest.skip(f"{command[0]} is not installed")
    return subprocess.run([*command, str(path)], capture_output=True, text=True, check=True,
                          timeout=30).stdout


@pytest.mark.parametrize("name", list(DUMPS))
def test_dumps_of_hexdump_od_and_xxd_decode_without_inventing_torn_frames(bench: Bench, tmp_path: Path,
                                                                          name: str) -> None:
    stream = _conversation(bench)
    # repeated 16-byte lines, which hexdump, od and xxd -a print as one line and a '*'
    stream += bytes(9 * 8) + Request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0).encode()[:3]
    capture = tmp_path / "serial.bin"
    capture.write_bytes(stream)
    text = _dump(DUMPS[name], capture)
    assert parse_hex(text) == stream, text
    decoded = decode_text(text)
    assert decoded == decode_text(stream.hex(" "))
    assert [d.kind for d in decoded].count("incomplete") == 1  # the 3 bytes really torn off
    whole = tmp_path / "whole.bin"
    whole.write_bytes(stream[:-3])
    assert "incomplete" not in [d.kind for d in decode_text(_dump(DUMPS[name], whole))]


def _can_conversation(bench: Bench) -> list[can.Message]:
    """Requests to CAN id 1 and the module's replies (id 2), as python-can messages."""
    messages = []
    t = 1_700_000_000.0
    for request in (Request(1, Opcode.SAP, AP.MAX_SPEED, 0, 51200),
                    Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0),
                    Request(1, Opcode.GGP, GP.SERIAL_ADDRESS, 0, 0)):
        (module, reply), = bench.simulation.handle_can_request(request)
        for can_id, data in ((request.address, request.encode_can()),
                             (module.can_reply_id, reply.encode_can())):
            t += 0.001
            messages.append(can.Message(timestamp=t, arbitration_id=can_id, is_extended_id=False,
                                        data=data, channel="can0"))
    return messages


EXPECTED_CAN = [
    "id 001  05 04 00 00 00 c8 00        request  to id 001: SAP 4 MaxPositioningSpeed m0 = 51200",
    "id 002  01 64 05 00 00 c8 00        reply    module 1 → id 002: SAP 4 MaxPositioningSpeed m0 = 51200 "
    "→ 100 OK",
    "id 001  06 04 00 00 00 00 00        request  to id 001: GAP 4 MaxPositioningSpeed m0",
    "id 002  01 64 06 00 00 c8 00        reply    module 1 → id 002: GAP 4 MaxPositioningSpeed m0 → 100 OK "
    "= 51200",
    "id 001  0a 42 00 00 00 00 00        request  to id 001: GGP 66 SerialAddress b0",
    "id 002  01 64 0a 00 00 00 01        reply    module 1 → id 002: GGP 66 SerialAddress b0 → 100 OK = 1",
]


@pytest.mark.parametrize("suffix", [".asc", ".blf", ".csv", ".log", ".trc", ".txt", ".db", ".asc.gz"])
def test_can_logs_written_by_python_can(bench: Bench, tmp_path: Path, suffix: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    log = tmp_path / f"capture{suffix}"
    with can.Logger(str(log)) as writer:  # what `python -m can.logger -f FILE` writes through
        for message in _can_conversation(bench):
            writer.on_message_received(message)
    assert tmcl(["decode", "--file", str(log)]) == 0
    stamps, lines = _stamped(capsys.readouterr().out)
    assert lines == EXPECTED_CAN
    # each frame keeps the log's time (.asc counts from its start, the others are absolute)
    assert [round(b - a, 6) for a, b in itertools.pairwise(stamps)] == [0.001] * 5
    assert stamps[0] in (0.0, 1_700_000_000.001)


def _stamped(out: str) -> tuple[list[float], list[str]]:
    """The timestamps ``tmcl decode`` put before each line, and the lines without them."""
    pairs = [line.split("  ", 1) for line in out.splitlines()]
    return [float(stamp) for stamp, _ in pairs], [rest for _, rest in pairs]


def test_what_python_can_logger_prints_live(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m can.logger`` on the simulator's socketcand bus, its output piped to a file."""
    server = ServerProcess(tmp_path, "--no-tcp", "--socketcand", "127.0.0.1:0")
    logger = None
    try:
        host, port = server.endpoints["socketcand"][0].rsplit(":", 1)
        logger = subprocess.Popen(
            [sys.executable, "-u", "-m", "can.logger", "-i", "socketcand", "-c", "can0",
             "--bus-kwargs", f"host={host}", f"port={port}"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert logger.stdout is not None
        while "Can Logger" not in (line := logger.stdout.readline()):  # it listens now
            assert line, logger.communicate(timeout=10)
        with can.Bus(interface="socketcand", host=host, port=int(port), channel="can0") as bus:
            for request in (Request(1, Opcode.SAP, AP.MAX_SPEED, 0, 51200),
                            Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0)):
                bus.send(can.Message(arbitration_id=1, is_extended_id=False, data=request.encode_can()))
                assert bus.recv(10) is not None
        lines = [logger.stdout.readline() for _ in range(4)]
    finally:
        if logger is not None:
            logger.send_signal(signal.SIGINT)
            logger.communicate(timeout=10)
        server.stop()
    capture = tmp_path / "logger.txt"
    capture.write_text("".join(lines))
    assert tmcl(["decode", "--file", str(capture)]) == 0
    stamps, decoded = _stamped(capsys.readouterr().out)
    assert decoded == EXPECTED_CAN[:4]
    assert stamps == sorted(stamps) and stamps[0] > 1_700_000_000  # the logger's, kept


def test_decode_keeps_the_captures_timestamps_in_text_and_json(capsys: pytest.CaptureFixture[str],
                                                              tmp_path: Path) -> None:
    """Issue 37, item 8: candump's, and a serial log's leading times (a frame has its first
    byte's line's), in the text and in --json."""
    capture = tmp_path / "capture.txt"
    capture.write_text("(1700000000.000100) can0 001#0604000000000000\n"
                       "(1700000000.000200) can0 002#0164060000c800\n"
                       "12:00:01.5 TX: 01 06 04 00 00\n"
                       "12:00:01.6 TX: 00 00 00 0b\n"
                       "[12.750] 02 01 64 06 00 00 c8 00 35\n")
    assert tmcl(["decode", "--file", str(capture)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split("  ")[0] for line in out] == [
        "1700000000.000100", "1700000000.000200", "12:00:01.5", "12.750"]
    assert out[2] == ("12:00:01.5  01 06 04 00 00 00 00 00 0b  request  to 1: GAP 4 "
                      "MaxPositioningSpeed m0")
    assert tmcl(["decode", "--json", "--file", str(capture)]) == 0
    decoded = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [d["timestamp"] for d in decoded] == ["1700000000.000100", "1700000000.000200",
                                                 "12:00:01.5", "12.750"]
    assert decoded[3]["kind"] == "reply" and decoded[3]["value"] == 51200


def test_decode_streams_a_long_capture(tmp_path: Path) -> None:
    """Frames come out while the input is read: the reader holds a line, not the file."""
    frame = Request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0).encode()
    lines = (frame.hex(" ") for _ in range(100_000))
    reader = read_capture(lines)
    first = next(reader)
    assert first.data == frame
    assert inspect.getgeneratorstate(lines) == inspect.GEN_SUSPENDED  # not read to the end
