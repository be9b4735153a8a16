"""Issue 36, N5: files the server creates beside a path the user named never follow a
symbolic link another local user planted there (a shared folder such as /tmp): the pty's lock
file, the trace and record files, the state directory's ``module-A``.  Each case is a real
``python -m tmcl_server`` process: it refuses to start with one line, and the link's target
is untouched.  ``TMCL_SIM_EMULATE_WINDOWS=1`` runs the same through platform.py's Windows
branch (no O_NOFOLLOW there: the link is refused before it is opened)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tmcl_server.platform import EMULATE_WINDOWS

VICTIM_TEXT = "precious\n"


def _plant(tmp_path: Path, name: str, directory: bool = False) -> Path:
    """A link at ``name`` pointing to a victim file (or directory) the user owns."""
    victim = tmp_path / ("victim_dir" if directory else "victim")
    if directory:
        victim.mkdir()
    else:
        victim.write_text(VICTIM_TEXT)
    link = tmp_path / name
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(victim, target_is_directory=directory)
    return victim


CASES = {
    "trace": (lambda tmp: ["--trace", str(tmp / "shared" / "trace.txt")], "shared/trace.txt"),
    "record": (lambda tmp: ["--record", str(tmp / "shared" / "axes.csv")], "shared/axes.csv"),
    "state": (lambda tmp: ["--state-dir", str(tmp / "shared")], "shared/module-1"),
}


@pytest.mark.parametrize("windows", [False, True], ids=["posix", "windows-branch"])
@pytest.mark.parametrize("case", sorted(CASES))
def test_a_planted_link_is_refused_and_its_target_untouched(tmp_path, case, windows):
    arguments, planted = CASES[case]
    victim = _plant(tmp_path, planted, directory=case == "state")
    env = dict(os.environ)
    if windows:
        env[EMULATE_WINDOWS] = "1"
    result = subprocess.run([sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0",
                             *arguments(tmp_path)], capture_output=True, text=True,
                            timeout=30, env=env)
    lines = result.stderr.splitlines()
    assert result.returncode != 0 and len(lines) == 1, result.stderr
    assert "symbolic link" in lines[0] and "Traceback" not in result.stderr
    if case == "state":
        assert not any(victim.iterdir())  # no eeprom.json put there
    else:
        assert victim.read_text() == VICTIM_TEXT


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="pseudo-terminals are POSIX")
def test_a_planted_pty_lock_file_is_refused_and_its_target_untouched(tmp_path):
    """The issue's case: ``.ttyTMCL.lock`` next to a ``--pty`` in a shared folder, a link to
    a file of the user's; the code before truncated it to the server's process id."""
    victim = _plant(tmp_path, "shared/.ttyTMCL.lock")
    result = subprocess.run([sys.executable, "-m", "tmcl_server", "--no-tcp", "--pty",
                             str(tmp_path / "shared" / "ttyTMCL")], capture_output=True,
                            text=True, timeout=30)
    lines = result.stderr.splitlines()
    assert result.returncode != 0 and len(lines) == 1, result.stderr
    assert "symbolic link" in lines[0]
    assert victim.read_text() == VICTIM_TEXT
    assert not (tmp_path / "shared" / "ttyTMCL").exists()
