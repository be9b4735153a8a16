"""The README's serve-then-run-the-example path works as written (issue 14)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "scripts" / "example_pytrinamic.py"


def extras_installed_by_serve_script() -> list[str]:
    script = (ROOT / "scripts" / "serve.py").read_text()
    match = re.search(r'^SERVE_EXTRAS = "([\w,]+)"$', script, re.M)
    assert match, "serve.py must install the project with the extras the examples need"
    return match.group(1).split(",")


def test_serve_installs_what_the_example_and_the_snippets_import():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    installed = [req for name in extras_installed_by_serve_script() for req in extras[name]]
    assert any(req.startswith("pytrinamic") for req in installed)
    imports = set(re.findall(r"^\s*(?:from|import) (\w+)", EXAMPLE.read_text(), re.M))
    assert imports <= {"__future__", "argparse", "sys", "time", "pytrinamic", "tmcl_server"}


def test_the_example_runs():
    done = subprocess.run([sys.executable, str(EXAMPLE), "--self-contained"], capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "firmware: 6212V105" in done.stdout and "reached 102400" in done.stdout


def test_without_pytrinamic_the_example_says_how_to_get_it():
    hide = ("import sys, runpy; sys.modules['pytrinamic'] = None; sys.argv = ['x', '--tcp', 'h:1'];"
            f" runpy.run_path({str(EXAMPLE)!r}, run_name='__main__')")
    done = subprocess.run([sys.executable, "-c", hide], capture_output=True, text=True, timeout=60)
    assert done.returncode == 1
    assert "needs pytrinamic" in done.stderr and "'.[examples]'" in done.stderr


def test_serve_installs_what_the_readme_uses():
    """plot (tmcl plot), http (--http), tools (tmcl --connection) and pytrinamic."""
    assert {"examples", "plot", "http", "tools"} <= set(extras_installed_by_serve_script())


def readme_block(first_line: str) -> str:
    text = (ROOT / "README.md").read_text()
    start = text.index(f"```sh\n{first_line}") + len("```sh\n")
    return text[start:text.index("```", start)]


@pytest.mark.skipif(not (ROOT / ".venv" / "bin" / "activate").exists(),
                    reason="the block uses the .venv that scripts/serve.py or test.py makes")
def test_record_and_plot_block_runs_when_pasted_as_one(tmp_path):
    """The README's block, run as pasted: it waits for its server and writes nothing into the
    checkout (the recording and the picture go to a temporary folder)."""
    block = readme_block("source .venv/bin/activate")
    before = git_status()
    done = subprocess.run(["bash", "-c", block], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, env={**os.environ, "TMPDIR": str(tmp_path)})
    assert done.returncode == 0, done.stdout + done.stderr
    (picture,) = re.findall(r"^(\S+run\.png): 2 axes \(axis 0, axis 1\)$", done.stdout, re.M)
    assert Path(picture).is_file() and Path(picture).is_relative_to(tmp_path)
    assert git_status() == before


def git_status() -> str:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("git is needed to see that no tracked file changed")
    return subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout
