"""``tmcl`` end to end: a real ``tmcl-server`` process, the tool over TCP, the pty and pytrinamic.

Most calls run the tool's ``main()`` in this process (a real client on a real socket, fast);
a few run the installed console scripts as processes, to cover the entry points themselves.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.tmcl_server.test_cli import ServerProcess
from tmcl_server.protocol import Reply, Request
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServerProcess]:
    tmp = tmp_path_factory.mktemp("tool")
    process = ServerProcess(tmp, "--tcp", "127.0.0.1:0", "--pty", str(tmp / "ttyTOOL"))
    yield process
    process.stop()


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = tmcl(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_send_by_name_or_number_with_the_reply_decoded(server: ServerProcess, capsys) -> None:
    tcp = server.endpoints["tcp"][0]
    assert run(capsys, "--tcp", tcp, "send", "SAP", "MaxPositioningSpeed", "2", "51200") == (
        0, "SAP 4 MaxPositioningSpeed m2 = 51200 → 100 OK\n", "")
    assert run(capsys, "send", "gap", "4", "2", "--tcp", tcp, "--value") == (0, "51200\n", "")
    assert run(capsys, "--tcp", tcp, "send", "MVP", "REL", "2", "-5") == (0, "MVP REL m2 -5 → 100 OK\n", "")
    code, out, _ = run(capsys, "--tcp", tcp, "send", "GET_FIRMWARE_VERSION", "--json")
    assert code == 0 and json.loads(out)["version"] == "6212V105"
    code, out, _ = run(capsys, "--tcp", tcp, "send", "GGP", "UserVariable3", "2", "--json")
    assert code == 0 and json.loads(out) == {"request": "GGP 3 UserVariable3 b2", "status": 100,
                                             "status_name": "OK", "opcode": 10, "value": 0,
                                             "module": 1, "text": "→ 100 OK = 0"}


def test_exit_codes_scripts_can_rely_on(server: ServerProcess, capsys, tmp_path: Path) -> None:
    tcp = server.endpoints["tcp"][0]
    code, out, err = run(capsys, "--tcp", tcp, "send", "SAP", "MaxCurrent", "0", "999")
    assert (code, out) == (1, "SAP 6 MaxCurrent m0 = 999 → 4 INVALID_VALUE\n")
    code, _, err = run(capsys, "--tcp", tcp, "send", "SAP", "MaxCurent", "0", "1")
    assert code == 2 and "unknown parameter 'MaxCurent' (did you mean MaxCurrent" in err
    code, _, err = run(capsys, "--tcp", tcp, "send", "SAPP")
    assert code == 2 and "did you mean SAP" in err
    code, _, err = run(capsys, "--tcp", "127.0.0.1:1", "info")
    assert code == 3 and "cannot reach the module (tcp 127.0.0.1:1)" in err
    code, _, err = run(capsys, "--tcp", tcp, "--address", "9", "--timeout", "0.2", "info")
    assert code == 3 and "no reply from module 9" in err
    bad = tmp_path / "bad.tmc"
    bad.write_text("FLY 1, 2, 3\n")
    code, _, err = run(capsys, "--tcp", tcp, "program", "upload", str(bad))
    assert code == 4 and "FLY" in err
    code, _, err = run(capsys, "--tcp", tcp, "send", "ROR", "3,", "1000", "--wait")
    assert code == 2 and "--wait works with MVP" in err


def test_info_over_the_pty_and_through_pytrinamic(server: ServerProcess, capsys) -> None:
    code, out, _ = run(capsys, "--serial", server.endpoints["pty"][0], "info", "--json")
    info = json.loads(out)
    assert code == 0 and info["version"] == "6212V105" and info["type"] == "TMCM-6212"
    addresses = (info["serial_address"], info["can_id"], info["can_reply_id"], info["host_address"])
    assert addresses == (1, 1, 2, 2)
    connection = f"--interface socket_serial_tmcl --port {server.endpoints['tcp'][0]}"
    code, out, _ = run(capsys, "--connection", connection, "info", "--json")
    assert code == 0 and json.loads(out) == info
    pty = f"--interface serial_tmcl --port {server.endpoints['pty'][0]} --data-rate 115200"
    code, out, _ = run(capsys, "--connection", pty, "send", "GAP", "MaxCurrent", "1")
    assert (code, out) == (0, "GAP 6 MaxCurrent m1 → 100 OK = 128\n")


def test_two_dumps_differ_in_exactly_what_changed(server: ServerProcess, capsys) -> None:
    tcp = server.endpoints["tcp"][0]
    code, before, _ = run(capsys, "--tcp", tcp, "dump", "--json")
    assert code == 0
    assert run(capsys, "--tcp", tcp, "send", "SAP", "StandbyCurrent", "5", "33")[0] == 0
    assert run(capsys, "--tcp", tcp, "send", "SGP", "UserVariable200", "2", "-7")[0] == 0
    code, after, _ = run(capsys, "--tcp", tcp, "dump", "--json")
    old, new = json.loads(before), json.loads(after)
    assert old["type"] == "TMCM-6212" and len(old["axes"]) == 6 and len(old["globals"]["2"]) == 256
    changes = {(section, key, name) for section in ("axes", "globals") for key in old[section]
               for name in old[section][key] if old[section][key][name] != new[section][key][name]}
    volatile = {("globals", "0", "TMCLTickTimer"), ("globals", "0", "RandomNumber"),
                # the actual current: run current until the power-down delay after the last
                # move, then the standby current (a loaded machine's slow dumps span that)
                *{("axes", str(axis), "SmartEnergyActualCurrent") for axis in range(6)}}
    assert changes - volatile == {("axes", "5", "StandbyCurrent"), ("globals", "2", "UserVariable200")}
    code, table, _ = run(capsys, "--tcp", tcp, "dump", "--axes", "5", "--no-user")
    assert "axis 5    7 StandbyCurrent               33" in table.splitlines()
    assert "bank 2" not in table


def test_watch_writes_csv_at_a_rate(server: ServerProcess, capsys) -> None:
    tcp = server.endpoints["tcp"][0]
    code, out, _ = run(capsys, "--tcp", tcp, "watch", "ActualPosition", "4", "--axes", "3,4",
                       "--rate", "50", "--count", "4")
    rows = out.splitlines()
    assert code == 0 and rows[0] == ("t,3.ActualPosition,3.MaxPositioningSpeed,4.ActualPosition,"
                                     "4.MaxPositioningSpeed")
    assert len(rows) == 5 and all(row.split(",")[2] == "51200" for row in rows[1:])
    times = [float(row.split(",")[0]) for row in rows[1:]]
    assert times == sorted(times) and times[-1] >= 0.05  # 50 Hz: 20 ms apart


def test_program_upload_run_status_read(server: ServerProcess, capsys, tmp_path: Path) -> None:
    tcp = server.endpoints["tcp"][0]
    source = tmp_path / "count.tmc"
    source.write_text("    GGP 10, 2\nloop:\n    CALC ADD, 1\n    AGP 10, 2\n    COMP 5\n"
                      "    JC LT, loop\n    STOP\n")
    assert run(capsys, "--tcp", tcp, "program", "upload", str(source), "--verify") == (
        0, f"{source}: 6 commands at 0, verified\n", "")  # no progress bar: stderr is no tty
    assert run(capsys, "--tcp", tcp, "program", "step")[1] == "STEP pc 1  A=0 X=0\n"
    assert run(capsys, "--tcp", tcp, "program", "step", "2")[1] == "STEP pc 3  A=1 X=0\n"
    assert run(capsys, "--tcp", tcp, "program", "run", "--continue", "--wait")[:2] == (
        0, "STOP pc 5  A=5 X=0\n")
    assert run(capsys, "--tcp", tcp, "send", "GGP", "UserVariable10", "2", "--value")[1] == "5\n"
    code, out, _ = run(capsys, "--tcp", tcp, "program", "read")
    assert code == 0 and out.splitlines() == ["    GGP 10, 2", "L1:", "    CALC ADD, 1", "    AGP 10, 2",
                                              "    COMP 5", "    JC LT, L1", "    STOP"]
    code, out, _ = run(capsys, "--tcp", tcp, "program", "status", "--json")
    assert code == 0 and json.loads(out) == {"state": "STOP", "pc": 5, "waiting": False,
                                             "accumulator": 5, "x": 0}
    # from 0 again: it loads user variable 10 (now 5) and counts once more
    assert run(capsys, "--tcp", tcp, "program", "run", "--wait")[1] == "STOP pc 5  A=6 X=0\n"


def test_decode_hex_and_capture_files(capsys, tmp_path: Path) -> None:
    request = Request(1, Opcode.SAP, AP.MAX_SPEED, 0, 51200).encode()
    reply = Reply(2, 1, 100, Opcode.SAP, 51200).encode()
    code, out, _ = run(capsys, "decode", *request.hex(" ").split(), *reply.hex(" ").split())
    assert code == 0 and out.splitlines() == [
        f"{request.hex(' ')}  request  to 1: SAP 4 MaxPositioningSpeed m0 = 51200",
        f"{reply.hex(' ')}  reply    module 1 → host 2: SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK"]
    capture = tmp_path / "candump.log"
    capture.write_text("(0.1) can0 001#0604000000000000\n(0.2) can0 002#0164060000c80000\n")
    code, out, _ = run(capsys, "decode", "--file", str(capture), "--json")
    frames = [json.loads(line) for line in out.splitlines()]
    assert code == 0 and [f["kind"] for f in frames] == ["request", "reply"]
    assert frames[1]["can_id"] == 2 and frames[1]["value"] == 51200
    assert run(capsys, "decode", "--file", str(tmp_path / "missing.txt"))[0] == 4
    assert run(capsys, "decode", "zz")[0] == 4


def test_console_scripts_as_processes(server: ServerProcess, tmp_path: Path) -> None:
    tcp = server.endpoints["tcp"][0]
    version = subprocess.run([BIN / "tmcl", "--version"], capture_output=True, text=True, timeout=30)
    assert version.returncode == 0 and version.stdout.startswith("tmcl 0.")
    helped = subprocess.run([BIN / "tmcl", "--help"], capture_output=True, text=True, timeout=30)
    assert "examples:" in helped.stdout and "exit codes:" in helped.stdout
    source = tmp_path / "two.tmc"
    source.write_text("    SAP 4, 1, 1000\n    STOP\n")
    alias = subprocess.run([BIN / "tmcl-upload", str(source), "--tcp", tcp, "--verify"],
                           capture_output=True, text=True, timeout=30)
    assert (alias.returncode, alias.stdout, alias.stderr) == (0, f"{source}: 2 commands at 0, verified\n", "")
    refused = subprocess.run([BIN / "tmcl", "--tcp", tcp, "send", "SAP", "4", "0", "-1"],
                             capture_output=True, text=True, timeout=30)
    assert refused.returncode == 1 and refused.stdout.strip().endswith("→ 4 INVALID_VALUE")


def test_progress_bar_draws_only_on_a_terminal() -> None:
    import io

    from tmcl_server.tool.progress import Progress

    quiet = io.StringIO()
    with Progress("upload", 4, stream=quiet) as bar:  # StringIO is no terminal
        bar.advance(4)
    assert quiet.getvalue() == ""
    shown = io.StringIO()
    with Progress("upload", 4, stream=shown, enabled=True) as bar:
        bar.advance(4)
    assert "upload [##############################] 4/4" in shown.getvalue()
    assert shown.getvalue().endswith("\r\x1b[K")  # the line is cleared at the end


def test_watch_on_a_terminal_redraws_a_live_table(server: ServerProcess, capsys,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(sys.stdout, "isatty", lambda: True)
    code, out, _ = run(capsys, "--tcp", server.endpoints["tcp"][0], "watch", "MaxCurrent",
                       "--axes", "0", "--rate", "50", "--count", "2")
    assert code == 0
    first, second = out.split("\x1b[2F")  # the second sample moves up over the two lines
    assert "0.MaxCurrent" in first and first.count("128") == 1
    assert second.startswith("t = ") and "\x1b[K" in second
