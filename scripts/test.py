#!/usr/bin/env python3
"""Set up everything the tests need from the project's own files, then run the suite, on
any system:

    python3 scripts/test.py [pytest arguments]       (Windows: py scripts/test.py ...)

ruff and mypy first, then ``pytest -n 2`` with the arguments as they came.  Without
arguments it also builds the wheel and smoke-tests it in a fresh virtualenv
(scripts/wheel_smoke.py).  Test paths given are the caller's: pytest runs in the caller's
directory (with the checkout as its root).  It never asks for a password: the MQTT tests need
mosquitto and the dashboard's browser tests chromium and chromium-driver, from the
distribution; when one is missing a line says what installs it and those tests are skipped
(.ci/run installs them and sets TMCL_SIM_REQUIRE_ALL=1, under which a missing one fails the
run instead).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import bootstrap

WHO = "test.py"
#: What the programs the tests start are called in Debian's packages.
PROGRAMS = (("MQTT", ("mosquitto",), ("mosquitto",)),
            ("dashboard browser", ("chromium", "chromedriver"), ("chromium", "chromium-driver")))


def _installed(program: str) -> bool:
    return shutil.which(program) is not None or Path("/usr/sbin", program).exists() \
        or Path("/usr/bin", program).exists()


def report_missing() -> None:
    """One line per group of tests that will be skipped, with what installs its programs."""
    for what, programs, packages in PROGRAMS:
        missing = [p for p in programs if not _installed(p)]
        if missing:
            how = ("; install with: sudo apt-get install " + " ".join(packages)
                   if shutil.which("apt-get") else "")
            bootstrap.say(WHO, f"{what} tests skipped: {' or '.join(missing)} missing{how}")


def step(command: list[str]) -> None:
    """A check in the checkout (ruff, mypy, the wheel): its failure ends the run."""
    status = subprocess.call(command, cwd=str(bootstrap.ROOT))
    if status != 0:
        raise SystemExit(status)


def pytest_command(python: Path, arguments: list[str]) -> list[str]:
    command = [str(python), "-m", "pytest", "-n", "2"]
    if Path.cwd().resolve() != bootstrap.ROOT:  # the caller's paths, the checkout's settings
        command += ["--rootdir", str(bootstrap.ROOT), "-c", str(bootstrap.ROOT / "pyproject.toml")]
        if not arguments:
            arguments = [str(bootstrap.ROOT / "tests")]
    return command + arguments


def main() -> int:
    arguments = sys.argv[1:]
    report_missing()
    python = bootstrap.ensure_venv(WHO, "test")
    step([str(python), "-m", "ruff", "check", "."])
    step([str(python), "-m", "mypy", "tmcl_spec", "interpreter", "axes", "tmcl_server"])
    if not arguments:
        step([str(python), str(bootstrap.ROOT / "scripts" / "wheel_smoke.py")])
    command = pytest_command(python, arguments)
    return bootstrap.hand_over(Path(command[0]), command[1:])


if __name__ == "__main__":
    sys.exit(bootstrap.main_guard(WHO, main))
