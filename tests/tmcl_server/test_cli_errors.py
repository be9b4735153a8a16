"""Issue 11 item 9: every bad command-line value gets one clear line and exit status 2.

Each case runs ``python -m tmcl_server`` as a user would; a value that slipped through would
start a server, which the timeout turns into a failure.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest


def _files(tmp: Path) -> dict[str, str]:
    """Bad files to name on the command line (world, faults, state directory, ...)."""
    made = {
        "world_bad_toml": "[chip\n",
        "world_inf.toml": "[chip]\nclock_hz = inf\n",
        "world_nan.toml": "[[axis]]\nindex = 0\nencoder_slip = nan\n",
        "world_type.toml": "[[axis]]\nindex = 0\nleft = \"x\"\n",
        "faults_nan.toml": '[[fault]]\nkind = "delay"\nms = nan\n',
        "faults_deep.json": "[" * 100_000 + "]" * 100_000,
        "faults_text.txt": "delay:ms=inf\n",
        "a_file": "x",
        "world_core.toml": '[chip]\ncore = "tmc4361a"\n',
    }
    for name, text in made.items():
        (tmp / name).write_text(text)
    (tmp / "state_with_file").mkdir()
    (tmp / "state_with_file" / "module-1").write_text("not a directory")
    (tmp / "not_utf8.toml").write_bytes(b"\xff\xfe[chip]")
    (tmp / "not_utf8.txt").write_bytes(b"\xff\xfe")
    return {name: str(tmp / name) for name in [*made, "not_utf8.toml", "not_utf8.txt"]}


#: (arguments, a word the one line must contain); {name} is a file from _files, {tmp} the dir.
CASES = [
    (["--speed", "inf"], "--speed"), (["--speed", "nan"], "--speed"),
    (["--speed", "1e999"], "--speed"), (["--speed", "0"], "--speed"),
    (["--speed", "-2"], "--speed"), (["--speed", "fast"], "--speed"),
    (["--mqtt-rate", "nan"], "--mqtt-rate"), (["--mqtt-rate", "0"], "--mqtt-rate"),
    (["--record-resolution", "inf"], "--record-resolution"),
    (["--request-time", "nan"], "--request-time"), (["--request-time", "-1"], "--request-time"),
    (["--processing-time", "inf"], "--processing-time"),
    (["--modules", "0"], "--modules"), (["--modules", "256"], "--modules"),
    (["--modules", "two"], "--modules"), (["--address", "0"], "--address"),
    (["--address", "1", "--modules", "2"], "--modules"),
    (["--can", "nosuchiface:can0"], "nosuchiface"), (["--can", "socketcan"], "--can"),
    (["--serial", "/dev/null:fast"], "baud rate 'fast'"), (["--serial", "/dev/null:0"], "baud"),
    (["--serial", "/dev/null:9600,mode=bogus"], "mode"),
    (["--tcp", "127.0.0.1:99999"], "--tcp"), (["--tcp", "127.0.0.1:port"], "--tcp"),
    (["--tcp", "127.0.0.1:0,mode=x"], "mode"),
    (["--pty", "{tmp}/missing/tty"], "--pty"), (["--slcan-pty", "{tmp}/missing/tty"], "--slcan-pty"),
    (["--socketcand", "70000"], "--socketcand"), (["--http", "70000"], "--http"),
    (["--mqtt", "ftp://h/x"], "--mqtt"), (["--mqtt", "mqtt://127.0.0.1:70000/x"], "--mqtt"),
    (["--can-bus", ""], "--can-bus"), (["--can-bus", "a b"], "--can-bus"),
    (["--record-axes", "0,x"], "--record-axes"), (["--record-axes", "6"], "--record-axes"),
    (["--record", "{tmp}/r.xyz"], "--record"), (["--record", "{tmp}/missing/r.csv"], "--record"),
    (["--trace", "{tmp}/missing/t.log"], "--trace"),
    (["--state-dir", "{a_file}"], "--state-dir"), (["--state-dir", "{a_file}/sub"], "--state-dir"),
    (["--world", "{tmp}/missing.toml"], "world file"), (["--world", "{world_bad_toml}"], "world file"),
    (["--world", "{world_inf.toml}"], "clock_hz"), (["--world", "{world_nan.toml}"], "encoder_slip"),
    (["--world", "{world_type.toml}"], "left"), (["--world", "{not_utf8.toml}"], "UTF-8"),
    (["--faults", "{tmp}/missing.toml"], "fault file"), (["--faults", "{faults_nan.toml}"], "ms"),
    (["--faults", "{faults_deep.json}"], "nested"), (["--faults", "{faults_text.txt}"], "ms"),
    (["--faults", "{not_utf8.txt}"], "UTF-8"),
    (["--fault", "bogus"], "unknown fault"), (["--fault", "delay:ms=nan"], "ms"),
    (["--loop", "bogus"], "--loop"), (["--module-type", "bogus"], "--module-type"),
    (["--axis-core", "bogus"], "--axis-core"), (["--log-level", "bogus"], "--log-level"),
    (["--module-type", "tmcm-6110", "--axis-core", "tmc4361a"], "it runs on tmc4210, tmc429"),
    (["--module-type", "tmcm-6110", "--world", "{world_core.toml}"], "does not run on the tmc4361a"),
    (["--no-such-option"], "unrecognized"), (["--no-tcp"], "no transport"),
    (["--mqtt", ""], "--mqtt"), (["--state-dir", ""], "--state-dir"), (["--world", ""], "--world"),
    (["--ready-file", ""], "--ready-file"), (["--pty", "{tmp}"], "not a symlink"),
    (["--state-dir", "{tmp}/state_with_file"], "--state-dir"),  # module-1 is a file there
]


@pytest.mark.parametrize("argv, word", CASES, ids=[" ".join(a) for a, _ in CASES])
def test_bad_value_gets_one_line_and_status_2(tmp_path, argv, word):
    files = _files(tmp_path)
    for name, path in {"tmp": str(tmp_path), **files}.items():
        argv = [a.replace("{" + name + "}", path) for a in argv]
    tcp = [] if "--tcp" in argv or "--no-tcp" in argv else ["--tcp", "127.0.0.1:0"]
    result = subprocess.run([sys.executable, "-m", "tmcl_server", *tcp, *argv],
                            capture_output=True, text=True, timeout=30)
    lines = result.stderr.splitlines()
    assert result.returncode == 2, result.stderr
    assert len(lines) == 1 and lines[0].startswith("tmcl-server: error: "), result.stderr
    assert word in lines[0], lines[0]
    assert "Traceback" not in result.stderr and result.stdout == ""
