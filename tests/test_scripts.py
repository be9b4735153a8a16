"""scripts/serve.py, scripts/test.py and scripts/bootstrap.py: which Python, when to install,
what the server and pytest get, on POSIX and (emulated) Windows.

The scripts run as they are, with the Python running these tests, in a copy of the
checkout's files.  ``PYTHON`` names a stand-in Python (a shell script) that logs how it is
called (venv, pip, the version checks) and makes a ``.venv`` whose programs print what they
got: what is checked is the scripts' own logic, in seconds.  The Windows runs put
tests/helpers/windows_site first on PYTHONPATH and set ``TMCL_SIM_EMULATE_WINDOWS=1``, as
tests/tmcl_server/test_windows.py does for the server.
"""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

import pytest

ROOT = Path(__file__).resolve().parents[1]
SITE = ROOT / "tests" / "helpers" / "windows_site"
WAIT_S = 30.0  # a fail-safe for what is due, never a pause to hope in
COPIED = ("scripts/bootstrap.py", "scripts/serve.py", "scripts/test.py", "scripts/serve.sh",
          "scripts/test.sh", "pyproject.toml", "setup.py")

# Behaves like a Python 3.11 for what the bootstrap asks of it.  pip says one line, waits
# until the test has seen it ($FAKE_GO appears), then says the next: the bootstrap must pass
# pip's output on as it comes.  The venv's programs print what they got, and where.
FAKE_PYTHON = r"""#!/bin/sh
echo "python $*" >> "$FAKE_LOG"
case "$*" in
  *"-m venv"*)
    if [ "$TMCL_SIM_EMULATE_WINDOWS" = 1 ]; then bin="Scripts"; exe=".exe"; else bin="bin"; exe=""; fi
    for last; do :; done
    mkdir -p "$last/$bin"
    cp "$0" "$last/$bin/python$exe"
    cat > "$last/$bin/tmcl-server$exe" <<'SERVER'
#!/bin/sh
echo "tmcl-server $*"
for argument in "$@"; do echo "argument <$argument>"; done
echo "cwd $(pwd)"
exit ${FAKE_EXIT:-0}
SERVER
    chmod +x "$last/$bin/tmcl-server$exe"
    chmod +x "$last/$bin/python$exe" ;;
  *"-m pip install"*)
    echo "Collecting pyserial>=3.5"
    waited=0
    while [ ! -e "$FAKE_GO" ] && [ $waited -lt 300 ]; do sleep 0.1; waited=$((waited + 1)); done
    if [ -e "$FAKE_GO" ]; then echo "Successfully installed tmcl-sim"; else echo "pip output held back"; fi ;;
  *"-m pytest"*|*"-m ruff"*|*"-m mypy"*|*wheel_smoke*) echo "ran $*"; echo "cwd $(pwd)" ;;
  *"-c "*) echo 3.11.7 ;;
esac
exit 0
"""


class Checkout:
    """A copy of the checkout's set-up files, a stand-in Python, and a caller's directory."""

    def __init__(self, tmp: Path) -> None:
        self.tree = tmp / "checkout"
        (self.tree / "scripts").mkdir(parents=True)
        for name in COPIED:
            shutil.copy2(ROOT / name, self.tree / name)
        self.bin = tmp / "bin"
        self.bin.mkdir()
        self.python = self.bin / "fakepython"
        self.python.write_text(FAKE_PYTHON)
        self.python.chmod(0o755)
        self.caller = tmp / "caller"
        self.caller.mkdir()
        self.log = tmp / "calls.log"
        self.go = tmp / "go"

    def env(self, windows: bool = False, **extra: str) -> dict[str, str]:
        env = {"PATH": os.pathsep.join([str(self.bin), str(Path(sys.executable).parent),
                                        "/usr/bin", "/bin"]),
               "HOME": str(self.tree.parent), "FAKE_LOG": str(self.log), "FAKE_GO": str(self.go),
               "PYTHON": str(self.python)}
        if windows:
            env["TMCL_SIM_EMULATE_WINDOWS"] = "1"
            env["PYTHONPATH"] = str(SITE)
        env.update(extra)
        return {k: v for k, v in env.items() if v}

    def run(self, script: str, *args: str, windows: bool = False, status: int = 0,
            **extra: str) -> tuple[str, list[str]]:
        """Run a script (its pip step let through at once); (its output, the Python calls)."""
        self.log.unlink(missing_ok=True)
        self.go.touch()
        command = [sys.executable, str(self.tree / "scripts" / script), *args]
        if script.endswith(".sh"):
            command = ["sh", str(self.tree / "scripts" / script), *args]
        done = subprocess.run(command, cwd=self.caller, stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, text=True, timeout=WAIT_S,
                              env=self.env(windows, **extra))
        assert done.returncode == status, done.stdout
        calls = self.log.read_text().splitlines() if self.log.exists() else []
        return done.stdout, calls

    def server_line(self, output: str) -> str:
        (line,) = [line for line in output.splitlines() if line.startswith("tmcl-server")]
        return line


@pytest.fixture
def checkout(tmp_path: Path) -> Checkout:
    return Checkout(tmp_path)


def test_first_start_says_which_python_and_shows_pip_as_it_comes(checkout: Checkout) -> None:
    """pip's first line reaches the terminal while pip still runs (it waits for the test to
    see it): nothing holds its progress back."""
    checkout.go.unlink(missing_ok=True)
    proc = subprocess.Popen([sys.executable, str(checkout.tree / "scripts" / "serve.py")],
                            cwd=checkout.caller, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=checkout.env())
    assert proc.stdout is not None
    lines = []
    for line in proc.stdout:
        lines.append(line.rstrip("\n"))
        if line.startswith("Collecting"):
            checkout.go.touch()  # pip may go on: the test saw its line as it came
    assert proc.wait(timeout=WAIT_S) == 0, lines
    output = "\n".join(lines)
    assert "pip output held back" not in output
    assert f"serve.py: using {checkout.python} (Python 3.11.7," in output
    assert "serve.py: creating .venv" in output
    assert lines.index("Collecting pyserial>=3.5") < lines.index("Successfully installed tmcl-sim") \
        < lines.index("serve.py: .venv is ready")
    calls = checkout.log.read_text().splitlines()
    assert f"python -m pip install -e {checkout.tree}[examples,fast,plot,http,tools]" in calls
    assert checkout.server_line(output) == "tmcl-server --pty /tmp/ttyTMCL0"
    tools = checkout.tree / ".venv" / "bin"
    assert f"the tools (tmcl, tmcl-asm, tmcl-upload) are in {tools}: {tools}/tmcl, or source " \
           f"{tools}/activate" in output


def test_second_start_installs_nothing(checkout: Checkout) -> None:
    checkout.run("serve.py")
    started = time.monotonic()
    output, calls = checkout.run("serve.py")
    assert calls == [], "a second start with nothing changed ran Python for its setup"
    assert time.monotonic() - started < WAIT_S
    assert "(.venv is up to date)" in output and "Python 3.11.7" in output
    assert checkout.server_line(output) == "tmcl-server --pty /tmp/ttyTMCL0"


def test_a_changed_pyproject_installs_again(checkout: Checkout) -> None:
    checkout.run("serve.py")
    with (checkout.tree / "pyproject.toml").open("a") as f:
        f.write("\n# a new requirement\n")
    output, calls = checkout.run("serve.py")
    assert "setting up .venv again" in output
    assert sum("-m pip install" in c for c in calls) == 1
    assert not any("-m venv" in c for c in calls)


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
        checkout: Checkout, args: list[str], expected: str) -> None:
    output, _ = checkout.run("serve.py", *args)
    assert checkout.server_line(output) == f"tmcl-server {expected}"


def test_arguments_pass_untouched_and_run_in_the_callers_directory(checkout: Checkout) -> None:
    """Commas, spaces and quotes stay inside their argument, and the server runs where the
    user typed the command, so ``--world my.toml`` is the user's file (issue 37, items 1, 6)."""
    args = ["--serial", "COM11,mode=rs485", "--fault", "noreply:opcode=GAP,rate=0.5",
            "--world", "my.toml", "--trace", "a 'file' with spaces.txt"]
    output, _ = checkout.run("serve.py", *args)
    assert [line[len("argument <"):-1] for line in output.splitlines()
            if line.startswith("argument <")] == args
    assert f"cwd {checkout.caller}" in output.splitlines()


def test_the_shell_callers_are_one_line_each(checkout: Checkout) -> None:
    for name in ("serve.sh", "test.sh", "serve.ps1", "test.ps1"):
        code = [line for line in (ROOT / "scripts" / name).read_text().splitlines()
                if line.strip() and not line.lstrip().startswith("#")]
        assert len(code) == 1, (name, code)
        assert name.replace(".sh", ".py").replace(".ps1", ".py") in code[0]
    output, _ = checkout.run("serve.sh", "--tcp", "127.0.0.1:0")
    assert checkout.server_line(output) == "tmcl-server --pty /tmp/ttyTMCL0 --tcp 127.0.0.1:0"


def test_python_from_the_environment(checkout: Checkout) -> None:
    output, calls = checkout.run("serve.py")
    assert f"using {checkout.python} (Python 3.11.7" in output
    assert calls and all(c.startswith("python ") for c in calls)


def test_an_unusable_python_is_one_line(checkout: Checkout) -> None:
    output, _ = checkout.run("serve.py", status=1, PYTHON="/bin/false")
    assert output == "serve.py: error: PYTHON=/bin/false is not a Python >= 3.11 with venv\n"


# -- the choice of Python, in-process -----------------------------------------------------------

@pytest.fixture
def bootstrap(monkeypatch: pytest.MonkeyPatch) -> Iterator[ModuleType]:
    spec = importlib.util.spec_from_file_location("bootstrap_under_test",
                                                  ROOT / "scripts" / "bootstrap.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    monkeypatch.delenv("PYTHON", raising=False)
    monkeypatch.delenv("TMCL_SIM_EMULATE_WINDOWS", raising=False)
    yield module


def test_the_running_python_makes_the_venv_when_it_is_new_enough(bootstrap: ModuleType) -> None:
    assert bootstrap.pick_python() == ([sys.executable], ".".join(map(str, sys.version_info[:3])))


def fake_pythons(where: Path, *names: str) -> None:
    where.mkdir(exist_ok=True)
    for name in names:
        path = where / name
        path.write_text('#!/bin/sh\n[ "$1" = -3.11 ] || [ "$1" = -c ] || exit 1\necho 3.11.7\n')
        path.chmod(0o755)


def test_an_old_running_python_looks_for_another(bootstrap: ModuleType, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    fake_pythons(tmp_path, "python3.11")
    monkeypatch.setenv("PATH", str(tmp_path))
    assert bootstrap.pick_python(running_version=(3, 8, 10)) == (["python3.11"], "3.11.7")


def test_on_windows_the_py_launcher_comes_first(bootstrap: ModuleType, tmp_path: Path,
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    fake_pythons(tmp_path, "py", "python3")
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("TMCL_SIM_EMULATE_WINDOWS", "1")
    assert bootstrap.pick_python(running=None) == (["py", "-3.11"], "3.11.7")
    assert bootstrap.venv_program("tmcl") == ROOT / ".venv" / "Scripts" / "tmcl.exe"


def test_no_python_at_all_says_what_to_do(bootstrap: ModuleType, tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(bootstrap.SetupError, match=r"no Python >= 3\.11 with venv found "
                                                   r"\(this one is 3\.8\.10; tried python3\.13"):
        bootstrap.pick_python(running_version=(3, 8, 10))


# -- Windows, emulated ---------------------------------------------------------------------------

def test_windows_layout_no_pty_and_the_exit_status_passed_on(checkout: Checkout) -> None:
    """Under the emulation: ``.venv\\Scripts\\python.exe`` installs, ``Scripts\\tmcl-server.exe``
    serves (a child: Windows has no exec) and its exit status is the script's; no pty is
    added, and a line says how to serve a COM port for the TMCL-IDE."""
    output, calls = checkout.run("serve.py", "--tcp", "127.0.0.1:0", windows=True, status=3,
                                 FAKE_EXIT="3")
    assert checkout.server_line(output) == "tmcl-server --tcp 127.0.0.1:0"
    assert (checkout.tree / ".venv" / "Scripts" / "python.exe").exists()
    assert not (checkout.tree / ".venv" / "bin").exists()
    assert "--serial COM11" in output
    assert re.search(r"the tools .* are in \S+.venv.Scripts: \S+.venv.Scripts.tmcl\.exe, or "
                     r"\S+.venv.Scripts.Activate\.ps1 \(PowerShell\)", output), output
    assert any("-m pip install -e" in c for c in calls)
    output, calls = checkout.run("serve.py", "--serial", "COM11,mode=rs485", windows=True)
    assert calls == [] and "(.venv is up to date)" in output
    assert checkout.server_line(output) == "tmcl-server --serial COM11,mode=rs485"


# -- test.py -------------------------------------------------------------------------------------

def test_the_test_script_checks_then_runs_pytest_with_the_arguments(checkout: Checkout) -> None:
    output, calls = checkout.run("test.py", "tests/test_x.py", "-k", "a or b")
    ran = [line for line in output.splitlines() if line.startswith("ran ")]
    assert ran[0] == "ran -m ruff check ." and ran[1].startswith("ran -m mypy tmcl_spec")
    assert ran[2] == (f"ran -m pytest -n 2 --rootdir {checkout.tree} -c {checkout.tree}/pyproject.toml "
                      "tests/test_x.py -k a or b")
    assert output.splitlines()[-1] == f"cwd {checkout.caller}"  # the caller's paths
    assert not any("wheel_smoke" in c for c in calls)
    assert any("-m pip install -e" in c and c.endswith("[test]") for c in calls)


def test_the_test_script_without_arguments_also_smoke_tests_the_wheel(checkout: Checkout) -> None:
    output, _ = checkout.run("test.py")
    ran = [line for line in output.splitlines() if line.startswith("ran ")]
    assert ran[2] == f"ran {checkout.tree}/scripts/wheel_smoke.py"
    assert ran[3] == f"ran -m pytest -n 2 --rootdir {checkout.tree} -c {checkout.tree}/pyproject.toml " \
                     f"{checkout.tree}/tests"


# -- what the README and CI run -------------------------------------------------------------------

def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"```sh\n(.*?)```", text, re.S)
    assert block, "the README starts with its two commands"
    return [line.split("#")[0].strip() for line in block.group(1).splitlines() if line.strip()]


def test_the_readme_starts_with_the_two_commands_of_every_system() -> None:
    assert readme_commands() == ["python3 scripts/serve.py", "python3 scripts/test.py"]


def test_ci_runs_the_readme_test_command_with_every_program_required() -> None:
    ci = (ROOT / ".ci" / "run").read_text()
    assert readme_commands()[1] in [line.strip() for line in ci.splitlines()]
    assert "export TMCL_SIM_REQUIRE_ALL=1" in ci
    for package in ("mosquitto", "chromium", "chromium-driver"):
        assert f"need+=({package})" in ci
