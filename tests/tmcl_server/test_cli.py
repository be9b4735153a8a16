"""``tmcl-server`` as a real process: endpoints, ready file, signals, crash safety."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import RawClient
from tests.helpers.processes import ServerProcess
from tmcl_server.cli import build_parser, config_from_args
from tmcl_spec.commands import Opcode


def test_endpoints_ready_file_and_clean_shutdown(tmp_path):
    link = tmp_path / "ttyTMCL0"
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--pty", str(link), "--modules", "2")
    try:
        assert set(server.endpoints) == {"tcp", "pty"}
        assert server.endpoints["pty"] == [str(link)]
        assert link.is_symlink() and os.readlink(link).startswith("/dev/pts/")
        client = RawClient(server.endpoints["tcp"][0])
        assert client.request(2, Opcode.GGP, 66, 0).value == 2
        client.close()
    finally:
        code, out, err = server.stop(signal.SIGTERM)
    assert code == 0, err
    lines = out.splitlines()
    assert f"tcp {server.endpoints['tcp'][0]}" in lines
    assert f"pty {link}" in lines
    assert not link.exists(), "the pty link must be removed on shutdown"
    assert not server.ready_file.exists()


def test_sigint_also_stops_cleanly(tmp_path):
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0")
    code, out, _ = server.stop(signal.SIGINT)
    assert code == 0 and "stopped" in out


def test_state_survives_a_kill(tmp_path):
    state = tmp_path / "state"
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state))
    client = RawClient(server.endpoints["tcp"][0])
    client.request(1, Opcode.SGP, 20, 2, 2020)
    client.request(1, Opcode.STGP, 20, 2)
    client.request(1, Opcode.SGP, 76, 0, 3)  # bank 0: stored when set
    client.close()
    server.stop(signal.SIGKILL)  # no chance to flush anything
    # on disk: the snapshot, or the journal a server appends each store to (docs/eeprom.md)
    assert any((state / "module-1").iterdir())
    again = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state))
    try:
        client = RawClient(again.endpoints["tcp"][0])
        assert client.request(1, Opcode.GGP, 20, 2).value == 2020
        assert client.request(1, Opcode.GGP, 1, 2).host == 3
        client.close()
    finally:
        again.stop()


def test_corrupt_state_is_reported_at_start(tmp_path):
    state = tmp_path / "state" / "module-1"
    state.mkdir(parents=True)
    (state / "eeprom.json").write_text("garbage")
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state.parent))
    code, _, err = server.stop()
    assert code == 0
    assert "eeprom.json is unreadable" in err and "factory defaults" in err
    assert (state / "eeprom.json").read_text() == "garbage"


def test_occupied_port_is_a_clear_error(tmp_path):
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0")
    try:
        taken = server.endpoints["tcp"][0]
        result = subprocess.run([sys.executable, "-m", "tmcl_server", "--tcp", taken],
                                capture_output=True, text=True, timeout=20)
        assert result.returncode == 1
        assert "address already in use" in result.stderr.lower()
    finally:
        server.stop()


@pytest.mark.parametrize(("argv", "addresses", "endpoints"), [
    ([], [1], {"tcp": ["127.0.0.1:2323"]}),
    (["--modules", "3"], [1, 2, 3], {"tcp": ["127.0.0.1:2323"]}),
    (["--address", "7", "--pty", "/tmp/x"], [7], {"tcp": ["127.0.0.1:2323"], "pty": ["/tmp/x"]}),
    (["--tcp", ":0", "--tcp", "0.0.0.0:5000"], [1], {"tcp": [":0", "0.0.0.0:5000"]}),
    (["--no-tcp", "--serial", "/dev/ttyUSB0:115200"], [1], {"serial": ["/dev/ttyUSB0:115200"]}),
])
def test_argument_parsing(argv, addresses, endpoints):
    config = config_from_args(build_parser().parse_args(argv))
    assert config.addresses == addresses
    assert config.endpoints == endpoints


def test_the_tmc4361a_core_and_the_evaluation_board_from_the_command_line(tmp_path):
    core = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--axis-core", "tmc4361a")
    board = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0",
                          "--module-type", "landungsbruecke-tmc4361a")
    try:
        client = RawClient(core.endpoints["tcp"][0])
        assert client.request(1, Opcode.SAP, 2, 0, 7_999_774).status == 100  # rotations: f/2
        assert client.request(1, Opcode.SAP, 4, 0, 7_999_774).status == 4  # positioning: f/4
        assert client.request(1, Opcode.READ_MC, 0x7F).value == 2  # TMC4361A VERSION_NO
        client.close()
        client = RawClient(board.endpoints["tcp"][0])
        assert client.request(1, Opcode.GGP, 4, 0).value == 0x0600_020B  # TMC4361A on channel 1
        client.close()
    finally:
        assert core.stop()[0] == 0
        assert board.stop()[0] == 0


def test_no_transport_is_refused():
    with pytest.raises(SystemExit):
        config_from_args(build_parser().parse_args(["--no-tcp"]))


def test_example_script_runs_self_contained():
    result = subprocess.run([sys.executable, "scripts/example_pytrinamic.py", "--self-contained"],
                            capture_output=True, text=True, timeout=60,
                            cwd=Path(__file__).resolve().parents[2])
    assert result.returncode == 0, result.stderr
    assert "firmware: 6212V105" in result.stdout
    assert "reached 102400" in result.stdout


@pytest.mark.parametrize("tool", ["tmcl_server.cli:main", "interpreter.cli:main",
                                  "tmcl_server.tool:upload_alias", "tmcl_server.tool:main"])
def test_every_console_script_has_version(tool, capsys):
    """tmcl-server, tmcl-asm, tmcl-upload and tmcl all answer --version (issues 14, 15)."""
    import importlib

    from tmcl_spec.package import package_version

    module, _, function = tool.partition(":")
    with pytest.raises(SystemExit) as exit_:
        getattr(importlib.import_module(module), function)(["--version"])
    assert exit_.value.code == 0
    out = capsys.readouterr().out
    assert package_version() in out and package_version() != "unknown"
    if tool == "tmcl_server.cli":
        assert out.startswith("tmcl-server ") and "TMCM-6212, firmware V1.05" in out


def test_every_server_option_has_help():
    for action in build_parser()._actions:
        assert action.help, f"{action.option_strings} has no help text"
