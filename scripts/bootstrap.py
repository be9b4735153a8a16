"""The project installed into ``.venv``, the same way on Linux, macOS and Windows.

``scripts/serve.py`` and ``scripts/test.py`` call :func:`ensure_venv` first.  It sets ``.venv``
up once and again only when something it depends on changed (``pyproject.toml``, ``setup.py``,
the extras asked for, ``$PYTHON``): a stamp in ``.venv`` records what the last setup used, so
a second start costs a checksum, not a reinstall.  pip writes straight to the terminal, so
its progress shows as it comes.

The Python that makes ``.venv``: ``$PYTHON`` if set (it must be 3.11 or newer), else the one
running this file if it is, else the first of ``py -3.13``/``-3.12``/``-3.11`` (Windows only),
``python3.13``, ``python3.12``, ``python3.11``, ``python3``, ``python`` that is.

``.venv`` has the layout of the system: ``.venv\\Scripts\\python.exe`` on Windows,
``.venv/bin/python`` elsewhere.  ``TMCL_SIM_EMULATE_WINDOWS=1`` (the test switch of
``tmcl_server/platform.py``) takes the Windows branches on Linux, for
``tests/test_scripts.py``.

Nothing here changes directory: the commands started afterwards run in the caller's
directory, so the user's relative paths (``--world my.toml``) mean what they meant.  This file
runs on the Python the user typed, before ``.venv`` exists: standard library only, and
nothing newer than Python 3.7 up to the version check.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

MIN_PYTHON = (3, 11)
ROOT = Path(__file__).resolve().parent.parent
VENV = ROOT / ".venv"
#: The switch tmcl_server/platform.py reads (EMULATE_WINDOWS): Windows' branches on Linux.
EMULATE_WINDOWS = "TMCL_SIM_EMULATE_WINDOWS"
#: Asked of a candidate Python: its version, and whether it can make a venv.
_PROBE = "import sys, venv; print('%d.%d.%d' % sys.version_info[:3]); sys.exit(sys.version_info < (3, 11))"


class SetupError(Exception):
    """Set-up cannot go on; the message is one line."""


def windows() -> bool:
    return os.name == "nt" or os.environ.get(EMULATE_WINDOWS) == "1"


def venv_program(name: str) -> Path:
    """A program installed into ``.venv``: ``.venv/bin/NAME`` or ``.venv\\Scripts\\NAME.exe``."""
    if windows():
        return VENV / "Scripts" / (name + ".exe")
    return VENV / "bin" / name


def activate_hint(programs: Path) -> str:
    """How a shell puts the programs in ``programs`` (``.venv``'s: tmcl, tmcl-asm, ...) on
    its PATH."""
    if windows():
        return f"{programs}\\Activate.ps1 (PowerShell), {programs}\\activate.bat (cmd)"
    return f"source {programs}/activate"


def say(who: str, text: str) -> None:
    sys.stderr.write(f"{who}: {text}\n")
    sys.stderr.flush()


def _version_text(version: tuple[int, ...]) -> str:
    return ".".join(str(part) for part in version[:3])


def probe(command: list[str]) -> str | None:
    """The version of a Python >= 3.11 with venv, or None if ``command`` is not one."""
    try:
        done = subprocess.run([*command, "-c", _PROBE], stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    version = done.stdout.strip()
    return version if done.returncode == 0 and version else None


def candidates() -> list[list[str]]:
    """The Pythons looked for when neither $PYTHON nor the running one will do."""
    names = [["python3.13"], ["python3.12"], ["python3.11"], ["python3"], ["python"]]
    if windows():
        return [["py", "-3.13"], ["py", "-3.12"], ["py", "-3.11"], *names]
    return names


def pick_python(running: str | None = sys.executable,
                running_version: tuple[int, ...] = tuple(sys.version_info)) -> tuple[list[str], str]:
    """(command, version) of the Python to make ``.venv`` with; SetupError if there is none.
    ``running``: the Python running this file (None: do not consider it)."""
    chosen = os.environ.get("PYTHON")
    if chosen:
        version = probe([chosen])
        if version is None:
            raise SetupError(f"PYTHON={chosen} is not a Python >= {_version_text(MIN_PYTHON)} with venv")
        return [chosen], version
    if running and running_version >= MIN_PYTHON and _has_venv():
        return [running], _version_text(running_version)
    for command in candidates():
        if shutil.which(command[0]) is None:
            continue
        version = probe(command)
        if version is not None:
            return command, version
    tried = ", ".join(" ".join(c) for c in candidates())
    raise SetupError(f"no Python >= {_version_text(MIN_PYTHON)} with venv found (this one is "
                     f"{_version_text(running_version)}; tried {tried}): install one (python.org, "
                     "or your system's python3.11+ and python3-venv) or set PYTHON=/path/to/python")


def _has_venv() -> bool:
    import importlib.util

    return importlib.util.find_spec("venv") is not None


def setup_key(extras: str) -> str:
    """What the setup depends on, as one checksum."""
    digest = hashlib.sha256()
    for name in ("pyproject.toml", "setup.py"):
        path = ROOT / name
        digest.update(path.read_bytes() if path.exists() else b"")
        digest.update(b"\0")
    digest.update(f"{extras}\n{os.environ.get('PYTHON', '')}\n".encode())
    return digest.hexdigest()


def _stamp(extras: str) -> Path:
    return VENV / (".setup-" + extras.replace(",", "-"))


def _venv_version() -> str | None:
    python = venv_program("python")
    return probe([str(python)]) if python.exists() else None


def _run(command: list[str], failure: str) -> None:
    """A set-up step whose output goes straight to the terminal (pip's progress as it comes)."""
    try:
        status = subprocess.call(command)
    except OSError as exc:
        raise SetupError(f"{failure}: {exc}") from None
    if status != 0:
        raise SetupError(f"{failure} (see above)")


def ensure_venv(who: str, extras: str) -> Path:
    """``.venv`` with the project and ``extras`` installed; its Python.  The first time (or
    after a change) it installs, saying what; otherwise one line says it is up to date."""
    python = venv_program("python")
    stamp = _stamp(extras)
    key = setup_key(extras)
    if python.exists() and stamp.exists():
        lines = stamp.read_text(encoding="utf-8").splitlines()
        if lines and lines[0] == key:
            using = lines[1] if len(lines) > 1 else "using .venv"
            say(who, f"{using} (.venv is up to date)")
            return python
    command, version = pick_python()
    name = " ".join(command)
    found = shutil.which(command[0]) or command[0]
    say(who, f"using {name} (Python {version}, {found})")
    if _venv_version() == version:
        say(who, "setting up .venv again: pyproject.toml, the extras or PYTHON changed")
    else:
        say(who, f"creating .venv with {name} ...")
        _run([*command, "-m", "venv", "--clear", str(VENV)],
             "creating .venv failed (on Debian/Ubuntu: sudo apt-get install python3-venv)")
        for old in VENV.glob(".setup-*"):
            old.unlink()
    if not python.exists():
        raise SetupError(f"creating .venv left no {python.relative_to(ROOT)}")
    say(who, f"installing tmcl-sim with the extras {extras} into .venv (a minute or two the first "
             "time) ...")
    _run([str(python), "-m", "pip", "install", "-e", f"{ROOT}[{extras}]"],
         "pip install failed")
    stamp.write_text(f"{key}\nusing .venv (Python {version}, set up with {name})\n",
                     encoding="utf-8")
    say(who, ".venv is ready")
    return python


def hand_over(program: Path, arguments: list[str]) -> int:
    """Run ``program`` with ``arguments``, as they came, in the caller's directory.  On POSIX
    the process becomes it (signals reach it directly, as ``exec`` in a shell script); Windows
    has no exec, so it is a child whose exit status is passed on (Ctrl-C reaches both: this
    process waits for the child to finish its shutdown)."""
    sys.stdout.flush()
    sys.stderr.flush()
    if not windows():
        os.execv(str(program), [str(program), *arguments])
    child = subprocess.Popen([str(program), *arguments])
    while True:
        try:
            return child.wait()
        except KeyboardInterrupt:
            continue


def main_guard(who: str, run: Callable[[], int]) -> int:
    """Run a script's body: a SetupError is one line and exit status 1."""
    try:
        return run()
    except SetupError as exc:
        say(who, f"error: {exc}")
        return 1
    except KeyboardInterrupt:
        say(who, "interrupted")
        return 130
