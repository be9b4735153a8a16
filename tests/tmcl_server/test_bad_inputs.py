"""Issue 36, N9 and N10: bad input to the tools gets one line and a non-zero exit, never a
traceback or a hang, and an error in an included file never shows that file's text.  Each
case runs the installed tool as a user would (``python -m``), in a temporary folder."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tmcl_server.embed import SimulatorThread
from tmcl_server.fault_language import FaultSpecError

BIG = "9" * 5000  # past int()'s 4,300-digit limit


def _run(tmp_path: Path, *argv: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", *argv], cwd=tmp_path, capture_output=True,
                          text=True, timeout=timeout)


def _one_line(result: subprocess.CompletedProcess[str], *words: str) -> str:
    lines = result.stderr.splitlines()
    assert result.returncode != 0, result
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    for word in words:
        assert word in lines[0], lines[0]
    return lines[0]


def test_decode_a_can_line_with_half_a_byte(tmp_path):
    _one_line(_run(tmp_path, "tmcl_server.tool", "decode", "can0 123#0"), "line 1", "hex")


def test_send_a_5000_digit_value(tmp_path):
    # refused while the line is read, before any connection is tried
    _one_line(_run(tmp_path, "tmcl_server.tool", "--tcp", "127.0.0.1:9", "send",
                   f"SAP 4 0 {BIG}"), "beyond")


def test_program_step_is_bounded(tmp_path):
    _one_line(_run(tmp_path, "tmcl_server.tool", "program", "step", "1000000"), "at most")


def test_assemble_into_a_directory(tmp_path):
    (tmp_path / "x.tmc").write_text("SAP 4, 0, 100\nSTOP\n")
    _one_line(_run(tmp_path, "interpreter.cli", "assemble", "x.tmc", "-o", "."), "cannot write")


def test_assemble_a_5000_digit_literal(tmp_path):
    (tmp_path / "big.tmc").write_text(f"SAP 4, 0, {BIG}\n")
    _one_line(_run(tmp_path, "interpreter.cli", "assemble", "big.tmc"), "big.tmc:1:", "beyond")


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs are POSIX")
def test_assemble_a_fifo_answers_instead_of_waiting(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    _one_line(_run(tmp_path, "interpreter.cli", "assemble", "fifo", timeout=20),
              "not a regular file")


def test_an_included_file_s_text_never_reaches_an_error(tmp_path):
    """N10: ``#include .env`` holding ``SECRET_TOKEN=...`` printed the secret as the
    "undefined symbol"; now the message says where (file, line, column) and what, not the
    text.  The source's own text is still quoted."""
    (tmp_path / ".env").write_text("SECRET_TOKEN=hunter2secret\n")
    (tmp_path / "prog.tmc").write_text("#include .env\nSAP 4, 0, Missing\nSTOP\n")
    result = _run(tmp_path, "interpreter.cli", "assemble", "prog.tmc")
    assert result.returncode != 0 and "Traceback" not in result.stderr
    assert "hunter2secret" not in result.stderr + result.stdout
    assert ".env:1:14: undefined symbol" in result.stderr
    assert "prog.tmc:2:11: undefined symbol 'Missing'" in result.stderr


@pytest.mark.parametrize("spec", ["noreply:opcode=||", "noreply:opcode=GAP|", "delay:ms=5,motor=|1"])
def test_a_fault_with_an_empty_alternative_is_refused(tmp_path, spec):
    """A spec that could never strike was accepted; now one line and status 2."""
    line = _one_line(_run(tmp_path, "tmcl_server", "--tcp", "127.0.0.1:0", "--fault", spec),
                     "--fault", "empty alternative")
    assert line.startswith("tmcl-server: error:")


def test_the_embedding_api_says_what_a_fault_is() -> None:
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim, \
            pytest.raises(FaultSpecError, match="a fault is a spec string"):
        sim.fault(123)  # type: ignore[arg-type]
