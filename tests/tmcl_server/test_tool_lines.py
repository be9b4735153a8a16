"""``tmcl`` speaks TMCL as the TMCL-IDE writes it, and says what went wrong (issue 26; the tool
parts of issue 27): IDE-style lines, refusals that send nothing, code protection, a running
program, Ctrl-C during ``--wait``, bad files and options, each in one line.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from interpreter.assembler import assemble
from interpreter.isa import Instruction, encode_program
from tests.conftest import RawClient
from tests.helpers.processes import ServerProcess
from tmcl_server.embed import SimulatorThread
from tmcl_server.record import CSV_COLUMNS
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP, GP

BIN = Path(sys.executable).parent
WAIT_S = 10.0  # fail-safe for a state that is due

LOOP = "Loop:\n  CALC ADD, 1\n  JA Loop\n"


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = tmcl(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def axis(sim: SimulatorThread, number: int, motor: int) -> int:
    return sim.call(lambda: sim.simulation.module(1).axes[motor].get_parameter(number))


def requests(sim: SimulatorThread) -> int:
    return sim.call(lambda: sim.simulation.requests)


# -- IDE-style lines ----------------------------------------------------------------------------

def test_send_takes_the_lines_the_tmcl_ide_writes(tmcl_sim: SimulatorThread, capsys) -> None:
    tcp = tmcl_sim.tcp
    assert run(capsys, "--tcp", tcp, "send", "ROR 0, 3000") == (0, "ROR m0 3000 → 100 OK\n", "")
    assert run(capsys, "--tcp", tcp, "send", "ROR", "1,", "20000") == (0, "ROR m1 20000 → 100 OK\n", "")
    assert axis(tmcl_sim, AP.TARGET_SPEED, 1) == 20000
    assert run(capsys, "--tcp", tcp, "send", "MST", "1")[0] == 0  # motor 1, not motor 0
    assert (axis(tmcl_sim, AP.TARGET_SPEED, 1), axis(tmcl_sim, AP.TARGET_SPEED, 0)) == (0, 3000)
    assert run(capsys, "--tcp", tcp, "send", "SAP 4, 0, 51200")[1] == (
        "SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK\n")
    assert run(capsys, "--tcp", tcp, "send", "SAP", "4", "3", "40000")[0] == 0  # commas optional
    assert axis(tmcl_sim, AP.MAX_SPEED, 3) == 40000
    assert run(capsys, "--tcp", tcp, "send", "MVP ABS, 2, 1000")[1] == "MVP ABS m2 1000 → 100 OK\n"
    assert axis(tmcl_sim, AP.TARGET_POSITION, 2) == 1000
    assert run(capsys, "--tcp", tcp, "send", "GIO", "8,", "1")[1] == "GIO 8 b1 → 100 OK = 240\n"
    assert run(capsys, "--tcp", tcp, "send", "SAP APMaxAcceleration, Motor4, 12345")[0] == 0
    assert axis(tmcl_sim, AP.MAX_ACCELERATION, 4) == 12345
    assert run(capsys, "--tcp", tcp, "send", "GAP", "MaxAcceleration", "4", "--value") == (0, "12345\n", "")


def test_a_line_that_is_not_clear_is_refused_and_nothing_is_sent(tmcl_sim: SimulatorThread, capsys) -> None:
    tcp = tmcl_sim.tcp
    before = requests(tmcl_sim)
    code, out, err = run(capsys, "--tcp", tcp, "send", "ROR", "0", "1", "20000")
    assert (code, out) == (2, "")
    assert err == ("tmcl: ROR takes 2 operand(s), got 3 in 'ROR 0 1 20000'; the manual's form is "
                   "ROR <axis>, <velocity> (as the old TYPE MOTOR VALUE form, this line is ROR 1, 20000)\n")
    code, _, err = run(capsys, "--tcp", tcp, "send", "MVP", "ABS", "0", "4294967396")
    assert code == 2 and err == ("tmcl: 'MVP ABS 0 4294967396', column 11: operand '4294967396' = "
                                 "4294967396 does not fit 32 bits\n")
    code, _, err = run(capsys, "--tcp", tcp, "send", "MST", "0", "1")
    assert code == 2 and "this line is MST 1" in err
    assert requests(tmcl_sim) == before  # not one frame went out
    assert axis(tmcl_sim, AP.TARGET_POSITION, 0) == 0


def test_help_says_how_the_old_form_maps(capsys) -> None:
    with pytest.raises(SystemExit):
        tmcl(["send", "--help"])
    text = capsys.readouterr().out
    assert "ROR <axis>, <velocity>" in text and "was  ROR 0 <axis> <velocity>" in text
    assert "MST <axis>" in text and "was  MST 0 <axis>" in text
    assert "SAP GAP" in text and "TYPE MOTOR VALUE" in text


def test_console_script_with_ide_lines(tmcl_sim: SimulatorThread) -> None:
    result = subprocess.run([BIN / "tmcl", "--tcp", tmcl_sim.tcp, "send", "MVP", "REL,", "5,", "-250"],
                            capture_output=True, text=True, timeout=60)
    assert (result.returncode, result.stdout) == (0, "MVP REL m5 -250 → 100 OK\n"), result.stderr
    assert axis(tmcl_sim, AP.TARGET_POSITION, 5) == -250


# -- code protection and a running program ----------------------------------------------------

def test_read_protection_is_named_not_a_verify_mismatch(tmcl_sim: SimulatorThread, capsys,
                                                        tmp_path: Path) -> None:
    source = tmp_path / "loop.tmc"
    source.write_text(LOOP)
    tcp = tmcl_sim.tcp
    assert run(capsys, "--tcp", tcp, "program", "upload", str(source))[0] == 0
    tmcl_sim.call(lambda: tmcl_sim.simulation.module(1).write_global(GP.CODE_PROTECTION, 0, 1))
    code, _, err = run(capsys, "--tcp", tcp, "program", "upload", str(source), "--verify")
    assert code == 1 and "read-protected (GP 81 = 1)" in err and "holds" not in err
    code, out, err = run(capsys, "--tcp", tcp, "program", "read")
    assert (code, out) == (1, "") and err == (
        "tmcl: module 1's program memory is read-protected (GP 81 = 1): it reads back as empty\n")
    tmcl_sim.call(lambda: tmcl_sim.simulation.module(1).write_global(GP.CODE_PROTECTION, 0, 2))
    code, _, err = run(capsys, "--tcp", tcp, "program", "upload", str(source))
    assert code == 1 and "write-protected (GP 81 bit 1)" in err


def test_an_upload_does_not_stop_a_running_program_unless_forced(tmcl_sim: SimulatorThread, capsys,
                                                                 tmp_path: Path) -> None:
    source = tmp_path / "loop.tmc"
    source.write_text(LOOP)
    tcp = tmcl_sim.tcp
    assert run(capsys, "--tcp", tcp, "program", "upload", str(source), "--run")[0] == 0
    tmcl_sim.advance(0.01)
    pc = tmcl_sim.call(lambda: tmcl_sim.simulation.module(1).program.interpreter.pc)
    code, out, err = run(capsys, "--tcp", tcp, "program", "upload", str(source))
    assert (code, out) == (1, "")
    assert err == (f"tmcl: module 1 runs a TMCL program (at pc {pc}); the upload would stop it: "
                   "add --force to stop it and upload\n")
    assert run(capsys, "--tcp", tcp, "program", "status")[1].startswith("RUN ")
    code, out, _ = run(capsys, "--tcp", tcp, "program", "upload", str(source), "--force")
    assert code == 0 and out == f"{source}: 2 commands at 0 (the program that ran was stopped at pc {pc})\n"
    assert run(capsys, "--tcp", tcp, "program", "status")[1].startswith("STOP ")


# -- Ctrl-C during --wait --------------------------------------------------------------------------

def _interrupt_a_move(tcp: str, *options: str) -> tuple[int, str, RawClient]:
    """Start ``tmcl send MVP ... --wait`` as a process, press Ctrl-C once it waits."""
    client = RawClient(tcp)
    client.request(1, Opcode.SAP, AP.MAX_SPEED, 0, 2000)  # a long, slow move
    client.request(1, Opcode.SAP, AP.ACTUAL_POSITION, 0, 0)
    process = subprocess.Popen([BIN / "tmcl", "--tcp", tcp, "send", "MVP ABS, 0, 1000000", "--wait",
                                *options], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert process.stdout is not None
    assert process.stdout.readline() == "MVP ABS m0 1000000 → 100 OK\n"  # now it waits
    deadline = time.monotonic() + WAIT_S
    while client.request(1, Opcode.GAP, AP.ACTUAL_SPEED, 0).value == 0:  # readiness, with a deadline
        assert time.monotonic() < deadline, "the motor never started"
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=WAIT_S)
    return process.returncode, err, client


def test_ctrl_c_during_wait_says_the_motor_still_runs_or_stops_it(tmp_path: Path) -> None:
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0")
    try:
        tcp = server.endpoints["tcp"][0]
        code, err, client = _interrupt_a_move(tcp)
        assert (code, err) == (130, "tmcl: interrupted: motor 0 still runs on the module (stop it with "
                                    "'tmcl send MST 0', or pass --stop-on-interrupt)\n")
        assert client.request(1, Opcode.GAP, AP.ACTUAL_SPEED, 0).value > 0  # it does
        client.close()
        code, err, client = _interrupt_a_move(tcp, "--stop-on-interrupt")
        assert (code, err) == (130, "tmcl: interrupted: motor 0 stopped (MST 0)\n")
        assert client.request(1, Opcode.GAP, AP.TARGET_SPEED, 0).value == 0  # MST was sent
        client.close()
    finally:
        server.stop()


# -- bad files and options: one line, the right exit status ----------------------------------

def test_upload_sends_program_commands_only(tmcl_sim: SimulatorThread, capsys, tmp_path: Path) -> None:
    binary = tmp_path / "reset.bin"
    binary.write_bytes(encode_program([Instruction(Opcode.SAP, 4, 0, 1000),
                                       Instruction(Opcode.RESTORE_FACTORY_SETTINGS, 0, 0, 1234),
                                       Instruction(Opcode.STOP)]))
    before = requests(tmcl_sim)
    code, out, err = run(capsys, "--tcp", tmcl_sim.tcp, "program", "upload", str(binary))
    assert (code, out) == (4, "") and err == (
        f"tmcl: {binary}: record 1 (bytes 8..15) holds command 137 (RESTORE_FACTORY_SETTINGS), "
        "not a program command: nothing uploaded\n")
    assert requests(tmcl_sim) == before
    good = tmp_path / "good.bin"
    good.write_bytes(assemble(LOOP).binary())
    assert run(capsys, "--tcp", tmcl_sim.tcp, "program", "upload", str(good), "--verify")[0] == 0


def test_several_source_errors_through_upload_each_on_its_line(tmcl_sim: SimulatorThread, capsys,
                                                               tmp_path: Path) -> None:
    source = tmp_path / "bad.tmc"
    source.write_text("FLY 1\nSTOP\nJA Nowhere\n#include /etc/passwd\n")
    code, _, err = run(capsys, "--tcp", tmcl_sim.tcp, "program", "upload", str(source))
    assert code == 4 and err.splitlines() == [
        f"tmcl: {source}:1:1: unknown mnemonic 'FLY'",
        f"tmcl: {source}:3:4: undefined symbol 'Nowhere'",
        f"tmcl: {source}:4:10: include file '/etc/passwd' is outside the source's folder, the -I "
        "folders and the shipped include folder"]
    assert "root:" not in err


def test_options_out_of_range_get_one_line(capsys) -> None:
    finite = "tmcl: argument --timeout: a finite number above 0 expected, got"
    for argv, message in [
        (["--timeout", "inf", "info"], f"{finite} 'inf'"),
        (["--timeout", "nan", "info"], f"{finite} 'nan'"),
        (["program", "read", "--start", "-5"],
         "tmcl program read: argument --start: a number 0 or more expected, got -5"),
        (["watch", "ActualPosition", "--rate", "0"], "tmcl watch: argument --rate: a finite number above 0"),
    ]:
        with pytest.raises(SystemExit) as info:
            tmcl(argv)
        err = capsys.readouterr().err
        assert info.value.code == 2 and err.startswith(message) and err.count("\n") == 1, err


def _recording(path: Path) -> None:
    rows = [",".join(CSV_COLUMNS)]
    for i in range(20):
        rows.append(f"{i / 100},1,0,{i * 10},{1000 if i else 0},0,128,200,0,0,0,0,,")
    path.write_text("\n".join(rows) + "\n")


def test_plot_refuses_bad_recordings_in_one_line(capsys, tmp_path: Path) -> None:
    pytest.importorskip("matplotlib")
    record = tmp_path / "record.csv"
    _recording(record)
    assert run(capsys, "plot", str(record), "-o", str(tmp_path / "ok.png"))[0] == 0
    truncated = tmp_path / "truncated.csv"
    truncated.write_text(record.read_text()[:-25])  # the last row cut short, as by a crash
    code, out, err = run(capsys, "plot", str(truncated), "-o", str(tmp_path / "t.png"))
    assert (code, out) == (4, "") and err.count("\n") == 1
    assert err.startswith(f"tmcl: {truncated}: cannot read the recording: line 21: incomplete row")
    nested = tmp_path / "nested.jsonl"
    nested.write_text('{"t":' * 1100 + "0" + "}" * 1100 + "\n")
    code, _, err = run(capsys, "plot", str(nested), "-o", str(tmp_path / "n.png"))
    assert code == 4 and err == (f"tmcl: {nested}: cannot read the recording: line 1: not JSON "
                                 "(nested too deeply)\n")
    listed = tmp_path / "list.jsonl"
    listed.write_text(json.dumps([1, 2]) + "\n")
    code, _, err = run(capsys, "plot", str(listed), "-o", str(tmp_path / "l.png"))
    assert code == 4 and "line 1: not a recorder row (a JSON list)" in err
    code, _, err = run(capsys, "plot", str(record), "-o", str(tmp_path / "x.png"), "--axes", "x")
    assert code == 2 and err == "tmcl: --axes: a list like 0,2 expected, got 'x'\n"


def test_decode_of_a_file_that_is_not_text_is_one_line(capsys, tmp_path: Path) -> None:
    binary = tmp_path / "capture.bin"
    binary.write_bytes(bytes(range(256)) * 64)
    code, out, err = run(capsys, "decode", "--file", str(binary))
    assert (code, out) == (4, "")
    assert err == (f"tmcl: {binary} is not a text dump (byte 0x80 at offset 128 is not UTF-8): give a hex "
                   "dump (xxd FILE | tmcl decode) or a CAN log python-can reads (.asc, .blf, .csv, .db, "
                   ".log, .mf4, .trc)\n")
