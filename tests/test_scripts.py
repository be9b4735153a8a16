"""scripts/serve.sh and scripts/venv.sh: which Python, when to install, which port.

The scripts run as they are, in a copy of the checkout's files, with a stand-in Python on
PATH that logs how it is called (venv, pip, the version checks) and a stand-in tmcl-server
that prints its arguments: what is checked is the scripts' own logic, in seconds.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Behaves like a Python 3.11 for what venv.sh asks of it.
FAKE_PYTHON = r"""#!/bin/sh
echo "python $*" >> "$FAKE_LOG"
case "$*" in
  *"-m venv"*)
    mkdir -p .venv/bin
    cp "$0" .venv/bin/python
    printf '#!/bin/sh\necho "tmcl-server $*"\n' > .venv/bin/tmcl-server
    chmod +x .venv/bin/python .venv/bin/tmcl-server ;;
  *"-m pip install"*) echo "Collecting pyserial>=3.5"; echo "Successfully installed tmcl-sim" ;;
  *"print("*) echo 3.11.7 ;;
esac
exit 0
"""


@pytest.fixture
def checkout(tmp_path: Path) -> Path:
    tree = tmp_path / "checkout"
    (tree / "scripts").mkdir(parents=True)
    for name in ("scripts/serve.sh", "scripts/venv.sh", "pyproject.toml", "setup.py"):
        shutil.copy2(ROOT / name, tree / name)
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    python = bin_dir / "python3.11"
    python.write_text(FAKE_PYTHON)
    python.chmod(0o755)
    return tree


def serve(checkout: Path, *args: str, python: str | None = None) -> tuple[str, str, list[str]]:
    """Run serve.sh; (what tmcl-server got, its messages, the Python calls of this run)."""
    log = checkout.parent / "calls.log"
    log.unlink(missing_ok=True)
    env = {"PATH": f"{checkout.parent / 'bin'}:/usr/bin:/bin", "FAKE_LOG": str(log),
           "HOME": str(checkout.parent)}
    if python is not None:
        env["PYTHON"] = python
    done = subprocess.run(["bash", str(checkout / "scripts" / "serve.sh"), *args],
                          capture_output=True, text=True, env=env, timeout=60)
    calls = log.read_text().splitlines() if log.exists() else []
    assert done.returncode == 0, done.stderr
    return done.stdout.strip(), done.stderr, calls


def test_first_start_says_which_python_and_shows_progress(checkout: Path) -> None:
    server, messages, calls = serve(checkout)
    assert "serve.sh: using python3.11 (Python 3.11.7," in messages
    assert "creating .venv" in messages and "Collecting pyserial" in messages
    assert any("-m pip install --progress-bar off -e .[examples,fast,plot,http,tools]" in c
               for c in calls), calls
    assert server == "tmcl-server --pty /tmp/ttyTMCL0"


def test_second_start_installs_nothing(checkout: Path) -> None:
    serve(checkout)
    started = time.monotonic()
    server, messages, calls = serve(checkout)
    assert time.monotonic() - started < 3.0
    assert calls == [], "a second start with nothing changed ran Python for its setup"
    assert "(.venv is up to date)" in messages and "Python 3.11.7" in messages
    assert server == "tmcl-server --pty /tmp/ttyTMCL0"


def test_a_changed_pyproject_installs_again(checkout: Path) -> None:
    serve(checkout)
    with (checkout / "pyproject.toml").open("a") as f:
        f.write("\n# a new requirement\n")
    _, messages, calls = serve(checkout)
    assert "setting up .venv again" in messages
    assert sum("-m pip install" in c for c in calls) == 1


@pytest.mark.parametrize(("args", "expected"), [
    (["--tcp", "127.0.0.1:0"], "--pty /tmp/ttyTMCL0 --tcp 127.0.0.1:0"),
    (["--modules", "3", "--trace"], "--pty /tmp/ttyTMCL0 --modules 3 --trace"),
    (["--slcan-pty", "/tmp/slcan0"], "--pty /tmp/ttyTMCL0 --slcan-pty /tmp/slcan0"),
    (["--pty", "/tmp/mine"], "--pty /tmp/mine"),
    (["--pty=/tmp/mine"], "--pty=/tmp/mine"),
    (["--serial", "/dev/ttyUSB0"], "--serial /dev/ttyUSB0"),
    (["--no-tcp", "--serial=/dev/ttyUSB0"], "--no-tcp --serial=/dev/ttyUSB0"),
])
def test_the_default_pty_stays_unless_the_arguments_name_a_port(
        checkout: Path, args: list[str], expected: str) -> None:
    server, _, _ = serve(checkout, *args)
    assert server == f"tmcl-server {expected}"


def test_python_from_the_environment(checkout: Path) -> None:
    fake = str(checkout.parent / "bin" / "python3.11")
    _, messages, calls = serve(checkout, python=fake)
    assert f"using {fake} (Python 3.11.7" in messages
    assert calls and all(c.startswith("python ") for c in calls)


def test_an_unusable_python_is_one_line(checkout: Path) -> None:
    env = {"PATH": "/usr/bin:/bin", "PYTHON": "/bin/false", "HOME": str(checkout.parent)}
    done = subprocess.run(["bash", str(checkout / "scripts" / "serve.sh")], capture_output=True,
                          text=True, env=env, timeout=60)
    assert done.returncode == 1
    assert done.stderr == "serve.sh: error: PYTHON=/bin/false is not a Python >= 3.11 with venv\n"


def test_no_python_at_all_says_what_to_do(checkout: Path, tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    for tool in ("dirname", "cat", "cksum", "cut", "head", "sed", "awk", "rm"):
        found = shutil.which(tool)
        if found:
            os.symlink(found, empty / tool)
    done = subprocess.run(["/bin/bash", str(checkout / "scripts" / "serve.sh")],
                          capture_output=True, text=True, timeout=60,
                          env={"PATH": str(empty), "HOME": str(tmp_path)})
    assert done.returncode == 1
    assert "no Python >= 3.11 with venv found" in done.stderr and "PYTHON=" in done.stderr
