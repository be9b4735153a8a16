"""The README's serve-then-run-the-example path works as written (issue 14)."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "scripts" / "example_pytrinamic.py"


def extras_installed_by_serve_script() -> list[str]:
    script = (ROOT / "scripts" / "serve.sh").read_text()
    match = re.search(r"pip install .*-e '\.\[([\w,]+)\]'", script)
    assert match, "serve.sh must install the project with the extras the examples need"
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
