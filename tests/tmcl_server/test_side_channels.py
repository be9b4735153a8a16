"""Nothing on the side stops the module answering (issue 27, item 2): a trace or record file
that cannot be written (an injected write error, a full file system: a 64 KiB tmpfs) stops
that observer with one warning while every request is answered; both files rotate past their
size limit (``--trace-max``, ``--record-max``)."""

from __future__ import annotations

import errno
import io
import json
import logging
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import RawClient
from tests.helpers.processes import wait_for_ready_file
from tmcl_server.embed import SimulatorThread
from tmcl_server.sidechannel import RotatingFile, SideChannel
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP


class FullDisk(io.StringIO):
    """A stream whose writes start failing with ENOSPC after ``room`` characters."""

    def __init__(self, room: int) -> None:
        super().__init__()
        self.room = room

    def write(self, text: str) -> int:
        if self.tell() + len(text) > self.room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(text)


def test_a_rotating_file_rotates_with_its_header_and_stops_once_on_a_write_error(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "tmcl_server.sidechannel")
    stopped: list[str] = []
    channel = SideChannel("the test file", lambda: stopped.append("stopped"))
    path = tmp_path / "data.csv"
    stream = RotatingFile(path, channel, max_bytes=100)
    stream.header = lambda: "a,b\n"
    stream.write("a,b\n")
    for n in range(30):
        stream.write(f"{n:04d},{n:04d}\n")  # 10 bytes a row
    stream.flush()
    assert stream.rotations >= 2
    current, rotated = path.read_text(), (tmp_path / "data.csv.1").read_text()
    assert current.startswith("a,b\n") and rotated.startswith("a,b\n")
    assert len(current) <= 100 and len(rotated) <= 100
    assert current.splitlines()[-1] == "0029,0029"
    full = RotatingFile(None, channel, stream=FullDisk(room=25))
    full.write("0123456789\n")
    for _ in range(5):
        full.write("0123456789\n")  # the third write fails: one warning, then nothing
    assert stopped == ["stopped"] and channel.stopped
    assert "No space left on device" in (channel.reason or "")
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 1 and "the test file stopped" in warnings[0]
    assert "the modules go on without it" in warnings[0]


def test_an_injected_write_error_stops_the_recorder_and_the_trace_and_the_module_answers(
        tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    caplog.set_level(logging.WARNING, "tmcl_server.sidechannel")
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], record=str(tmp_path / "r.csv"),
                         trace=str(tmp_path / "t.txt")) as sim:
        observers = sim.server.observers  # type: ignore[union-attr]
        for stream in observers._files:  # the disk fills up under both files
            sim.call(lambda s=stream: setattr(s, "_stream", FullDisk(room=0)))
        host = RawClient(sim.tcp)
        try:
            assert host.request(1, Opcode.MVP, 0, 0, 100_000).status == 100
            for _ in range(50):
                sim.advance(0.05)  # samples are due at every step: each write fails
                assert host.request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0).status == 100
        finally:
            host.close()
        assert sim.call(lambda: sim.simulation.recorder) is None  # detached, costs nothing
        deadline = time.monotonic() + 5  # the trace writes its batch within 50 ms (wall time)
        while sim.call(lambda: sim.simulation.tracer) is not None:
            assert time.monotonic() < deadline, "the trace did not stop"
            time.sleep(0.01)
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 2, warnings
    assert any(w.startswith("the recorder (--record) stopped (writing") for w in warnings)
    assert any(w.startswith("the trace (--trace) stopped (writing") for w in warnings)


@pytest.fixture
def tiny_fs(tmp_path: Path) -> Iterator[Path]:
    """A 64 KiB tmpfs (root only); otherwise a file size limit makes writes fail the same way."""
    mount = tmp_path / "tiny"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                          capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def test_a_full_file_system_under_record_and_trace_never_stops_the_server(tmp_path: Path,
                                                                          tiny_fs: Path) -> None:
    """The issue: 19 of 20 polls ended with the connection closed, a traceback, status 1."""
    ready = tmp_path / "ready.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", "--ready-file", str(ready),
         "--record", str(tiny_fs / "record.csv"), "--record-resolution", "0.001",
         "--trace", str(tiny_fs / "trace.txt")],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        host = RawClient(wait_for_ready_file(proc, ready)["tcp"][0], timeout=5)
        try:
            for motor in range(6):
                assert host.request(1, Opcode.ROR, 0, motor, 2000).status == 100
            answered = 0
            stop = time.monotonic() + 3.0  # 64 KiB fill within a second: the rest on a full disk
            while time.monotonic() < stop:
                reply = host.request(1, Opcode.GAP, AP.ACTUAL_POSITION, answered % 6)
                assert reply.status == 100
                answered += 1
        finally:
            host.close()
    finally:
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0, stderr
    assert "Traceback" not in stderr
    lines = [line for line in stderr.splitlines() if "stopped" in line and "tmcl-server" not in line]
    assert len(lines) == 2, stderr
    assert all("No space left on device" in line for line in lines), lines
    assert answered > 100


def test_trace_and_record_files_rotate_past_their_limit(tmp_path: Path) -> None:
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], record=str(tmp_path / "r.jsonl"),
                         record_max=8192, trace=str(tmp_path / "t.txt"), trace_max=8192,
                         record_resolution=0.001) as sim:
        host = RawClient(sim.tcp)
        try:
            host.request(1, Opcode.ROR, 0, 0, 1000)
            for _ in range(200):
                host.request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0)
                sim.advance(0.005)
        finally:
            host.close()
    for name in ("r.jsonl", "t.txt"):
        current, rotated = tmp_path / name, tmp_path / f"{name}.1"
        assert rotated.exists() and 0 < rotated.stat().st_size <= 8192 + 4096
        assert current.stat().st_size <= 8192 + 4096
    rows = [json.loads(line) for line in (tmp_path / "r.jsonl").read_text().splitlines()]
    assert rows and all("t" in row for row in rows)  # whole lines only


def test_the_size_options(tmp_path: Path) -> None:
    from tmcl_server.cli import build_parser, config_from_args
    config = config_from_args(build_parser().parse_args(
        ["--trace-max", "100M", "--record-max", "0", "--trace-max", "512k"]))
    assert config.trace_max == 512 * 1024 and config.record_max == 0
    for bad in ("-1", "lots", "1x", "100", "inf"):
        done = subprocess.run([sys.executable, "-m", "tmcl_server", "--record-max", bad],
                              capture_output=True, text=True, timeout=30)
        assert done.returncode == 2 and done.stderr.count("\n") == 1
        assert "--record-max" in done.stderr
