"""Every fault spec is bounded (issue 27, item 4): how many faults, how long a reply may be
held, how long a value or a file may be; every refusal is one line naming the field or the
line; a FIFO or a device as ``--faults`` is refused before it is opened."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tmcl_server.clock import VirtualClock
from tmcl_server.fault_language import (
    MAX_FAULT_FILE,
    MAX_FAULTS,
    FaultSpecError,
    load_fault_file,
    parse_fault,
)
from tmcl_server.faults import FaultInjector
from tmcl_server.module import TMCM6212
from tmcl_server.simulation import Simulation


def refused(text: str) -> str:
    with pytest.raises(FaultSpecError) as caught:
        parse_fault(text)
    message = str(caught.value)
    assert "\n" not in message and len(message) < 300, message
    return message


def test_values_are_bounded_and_every_refusal_names_its_field() -> None:
    digits = "9" * 4300
    message = refused(f"noreply:type={digits}")
    assert "type=" in message and "4,300 characters" in message
    assert "Exceeds the limit" not in message  # not Python's own words
    assert "type must be 0..255" in refused(f"noreply:type={'9' * 200}")
    for key in ("opcode", "type", "motor", "module", "endpoint", "rate", "count"):
        assert f"{key}= has no value" in refused(f"noreply:{key}=")
    assert "ms must be 0..10000" in refused("delay:ms=3600000")
    assert "ms must be 0..10000" in refused("delay:ms=5..3600000")
    assert "pause_ms must be 0..1000" in refused("tear:pause_ms=60000")
    assert "at most 1,024" in refused("noreply:" + ",".join(["opcode=GAP"] * 200))
    long_name = "x" * 5000
    assert "5,000 characters" in refused(f"{long_name}:opcode=GAP")
    assert parse_fault("delay:ms=10000").params["ms"] == (10000.0, 10000.0)


def test_at_most_max_faults_are_installed_at_once() -> None:
    injector = FaultInjector(Simulation([TMCM6212(1)], VirtualClock()))
    for _ in range(MAX_FAULTS):
        injector.add("noreply:opcode=GAP")
    with pytest.raises(FaultSpecError, match=f"{MAX_FAULTS} faults are installed"):
        injector.add("noreply:opcode=GAP")
    injector.clear()
    injector.add("noreply:opcode=GAP")


def test_fault_files_name_the_line_accept_a_bom_and_refuse_what_is_no_small_file(tmp_path: Path) -> None:
    text = tmp_path / "faults.txt"
    text.write_text("# comment\nnoreply:opcode=GAP\n\ndelay:ms=oops\n")
    with pytest.raises(FaultSpecError, match=r"line 4: ms must be a number, got 'oops'"):
        load_fault_file(text)
    text.write_bytes(b"\xef\xbb\xbfnoreply:opcode=GAP\ndelay:ms=5\n")
    assert [s.kind.name for s in load_fault_file(text)] == ["noreply", "delay"]
    toml = tmp_path / "faults.toml"
    toml.write_bytes(b'\xef\xbb\xbf[[fault]]\nkind = "noreply"\n[[fault]]\nkind = "delay"\nms = -1\n')
    with pytest.raises(FaultSpecError, match=r"fault 2: ms must be 0..10000"):
        load_fault_file(toml)
    many = tmp_path / "many.txt"
    many.write_text("noreply:opcode=GAP\n" * (MAX_FAULTS + 1))
    with pytest.raises(FaultSpecError, match=f"more than {MAX_FAULTS} faults"):
        load_fault_file(many)
    big = tmp_path / "big.txt"
    big.write_text("noreply:opcode=GAP\n" * 600_000)  # about 10 MB
    began = time.monotonic()
    with pytest.raises(FaultSpecError, match=f"at most {MAX_FAULT_FILE:,}"):
        load_fault_file(big)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    for special in (fifo, Path("/dev/zero")):
        with pytest.raises(FaultSpecError, match="not a regular file"):
            load_fault_file(special)
    assert time.monotonic() - began < 1.0  # refused without reading


@pytest.mark.parametrize("args, words", [
    (["--faults", "{fifo}"], "argument --faults: fault file {fifo}: not a regular file"),
    (["--faults", "/dev/zero"], "not a regular file"),
    (["--faults", "{big}"], "bytes (at most"),
    (["--faults", "{bad}"], "line 2: unknown fault"),
    (["--fault", "noreply:type={digits}"], "type= is 4,300 characters long"),
    (["--fault", "noreply:opcode="], "opcode= has no value"),
    (["--fault", "delay:ms=3600000"], "ms must be 0..10000"),
])
def test_the_command_line_refuses_them_in_one_line_at_once(tmp_path: Path, args: list[str],
                                                           words: str) -> None:
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    big = tmp_path / "big.txt"
    big.write_text("noreply:opcode=GAP\n" * 600_000)
    bad = tmp_path / "bad.txt"
    bad.write_text("noreply\nbogus:x=1\n")
    names = {"fifo": str(fifo), "big": str(big), "bad": str(bad), "digits": "9" * 4300}
    argv = [a.format(**names) for a in args]
    began = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", *argv],
                          capture_output=True, text=True, timeout=30)
    assert time.monotonic() - began < 20  # (a FIFO used to hang the start for ever)
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tmcl-server: error: argument --fault")
    assert words.format(**names) in lines[0], lines[0]
    assert "Traceback" not in done.stderr and len(lines[0]) < 400
