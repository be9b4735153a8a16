"""The README's code blocks run as pasted (issues 14 and 37): every block is run here, or is
output (```text), or is the set-up block tests/test_scripts.py runs.

Each block gets a server of its own, on a real clock (the transcript waits for moves), with
TCP on a free port and a pty in a temporary folder.  What the test writes in, visibly, and
the README says so above its first snippet: that server's TCP endpoint for the default
``127.0.0.1:2323`` and its pty for ``/tmp/ttyTMCL0``, and ``--tcp`` with that endpoint for a
``tmcl`` line that names no connection (``tmcl send ...`` means the default port); in the
transcript's output the test's endpoints are written back as the defaults.  Shell blocks run
in a scratch folder that holds a link to the checkout's ``docs/`` (what they write lands
there, not in the checkout), with ``.venv``'s programs on PATH; the plotting block runs in the
checkout itself, as the README tells, and must leave it unchanged.  Python blocks with a
``test_`` function run under pytest (the package's plugin gives them ``tmcl_sim``), the others
as scripts.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tomllib
from collections.abc import Iterator
from pathlib import Path

import pytest

from tmcl_server.embed import SimulatorThread

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "scripts" / "example_pytrinamic.py"
WAIT_S = 120.0  # a fail-safe for what is due
DEFAULT_TCP = "127.0.0.1:2323"
DEFAULT_PTY = "/tmp/ttyTMCL0"
#: The transcript's commands whose numbers depend on when they ran (positions of a moving
#: axis, a running program's counter): their lines are compared with any number in place.
TIMED = ("tmcl watch", "tmcl program status", "tmcl program stop")


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


# -- the blocks ------------------------------------------------------------------------------------

def readme_blocks() -> list[tuple[str, str, int]]:
    """(language, text, line number) of every fenced block of the README."""
    blocks = []
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines(keepends=True)
    index = 0
    while index < len(lines):
        if lines[index].startswith("```"):
            language, start = lines[index][3:].strip(), index + 1
            end = next(i for i in range(start, len(lines)) if lines[i].startswith("```"))
            blocks.append((language, "".join(lines[start:end]), start))
            index = end
        index += 1
    return blocks


#: The device a block names when it is about a module on the user's desk (``tmcl proxy``).
REAL_MODULE = "/dev/ttyACM0"


def _is_setup(text: str) -> bool:
    return text.startswith("python3 scripts/serve.py")


def _runnable() -> list[tuple[str, str, int]]:
    return [b for b in readme_blocks() if b[0] != "text" and not _is_setup(b[1])]


def test_every_block_is_run_here_or_is_output_or_is_the_setup():
    languages = [language for language, _, _ in readme_blocks()]
    assert set(languages) <= {"sh", "python", "console", "text"}, languages
    (setup,) = [b for b in readme_blocks() if _is_setup(b[1])]  # tests/test_scripts.py runs it
    assert setup[0] == "sh" and setup[2] == 3  # the first block, lines 4 and 5
    assert len(_runnable()) >= 9


@pytest.fixture
def server(tmp_path: Path) -> Iterator[SimulatorThread]:
    with SimulatorThread(clock="real", tcp=["127.0.0.1:0"], pty=[str(tmp_path / "ttyREADME")]) as sim:
        yield sim


def _pasted(text: str, sim: SimulatorThread, shell: bool = True) -> str:
    """The block with the test's server written in for the defaults (module docstring)."""
    text = text.replace(DEFAULT_TCP, sim.tcp).replace(DEFAULT_PTY, str(sim.pty))
    if not shell:
        return text
    return re.sub(r"(?m)(^|[;|&]\s*)tmcl (?!--tcp|--serial|--connection|plot)",
                  rf"\1tmcl --tcp {sim.tcp} ", text)


def _scratch(tmp_path: Path) -> Path:
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    (scratch / "docs").symlink_to(ROOT / "docs")
    return scratch


def _env() -> dict[str, str]:
    return {**os.environ, "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]])}


@pytest.mark.parametrize("block", [b for b in _runnable() if b[0] == "python"],
                         ids=lambda b: f"line {b[2]}")
def test_python_block_runs_as_pasted(block: tuple[str, str, int], server: SimulatorThread,
                                     tmp_path: Path) -> None:
    _, text, _ = block
    script = tmp_path / ("test_block.py" if re.search(r"^def test_", text, re.M) else "block.py")
    script.write_text(_pasted(text, server, shell=False))
    command = [sys.executable, str(script)]
    if script.name.startswith("test_"):
        command = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", str(script)]
    done = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=WAIT_S)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    if "get_version_string" in text:
        assert done.stdout.splitlines()[0] == "6212V105"


@pytest.mark.parametrize("block", [b for b in _runnable() if b[0] == "sh"], ids=lambda b: f"line {b[2]}")
def test_shell_block_runs_as_pasted(block: tuple[str, str, int], server: SimulatorThread,
                                    tmp_path: Path) -> None:
    _, text, _ = block
    if REAL_MODULE in text:
        pytest.skip(f"a block for a real module on {REAL_MODULE}: tests/tmcl_server/test_proxy.py "
                    "and test_replay.py run the proxy and the replay against the simulator")
    in_checkout = text.startswith("source .venv/bin/activate")
    if in_checkout and not (ROOT / ".venv" / "bin" / "activate").exists():
        pytest.skip("the block uses the .venv that scripts/serve.py or test.py makes")
    before = git_status() if in_checkout else ""
    done = subprocess.run(["bash", "-e", "-c", _pasted(text, server)], capture_output=True, text=True,
                          timeout=WAIT_S, cwd=ROOT if in_checkout else _scratch(tmp_path),
                          env={**_env(), "TMPDIR": str(tmp_path)})
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    if in_checkout:  # the recording and the picture went to the temporary folder
        (picture,) = re.findall(r"^(\S+run\.png): 2 axes \(axis 0, axis 1\)$", done.stdout, re.M)
        assert Path(picture).is_file() and Path(picture).is_relative_to(tmp_path)
        assert git_status() == before


def git_status() -> str:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("git is needed to see that no tracked file changed")
    return subprocess.run(["git", "status", "--porcelain"], cwd=ROOT, capture_output=True,
                          text=True, check=True).stdout


def _session(text: str) -> list[tuple[str, list[str]]]:
    """(command, its output lines) of a ``$`` transcript."""
    session: list[tuple[str, list[str]]] = []
    for line in text.splitlines():
        if line.startswith("$ "):
            session.append((line[2:], []))
        else:
            session[-1][1].append(line)
    return session


def _timed_pattern(line: str) -> str:
    return "".join(r"-?\d+(?:\.\d+)?" if re.fullmatch(r"-?\d+(?:\.\d+)?", part) else re.escape(part)
                   for part in re.split(r"(-?\d+(?:\.\d+)?)", line))


@pytest.mark.parametrize("block", [b for b in _runnable() if b[0] == "console"],
                         ids=lambda b: f"line {b[2]}")
def test_the_tool_transcript_runs_as_shown(block: tuple[str, str, int], server: SimulatorThread,
                                           tmp_path: Path) -> None:
    """Each ``$`` line, in order, against one server: its output (standard error too) is the
    README's, the timed commands' numbers aside."""
    scratch = _scratch(tmp_path)
    for command, shown in _session(block[1]):
        done = subprocess.run(["bash", "-c", "exec 2>&1\n" + _pasted(command, server)], cwd=scratch,
                              capture_output=True, text=True, timeout=WAIT_S, env=_env())
        out = done.stdout.replace(server.tcp, DEFAULT_TCP).replace(str(server.pty), DEFAULT_PTY)
        lines = out.splitlines()
        if command.startswith(TIMED):
            assert len(lines) == len(shown), (command, lines)
            for line, expected in zip(lines, shown, strict=True):
                assert re.fullmatch(_timed_pattern(expected), line), (command, line, expected)
        else:
            assert lines == shown, (command, lines)


# -- what the README's other instructions leave behind -------------------------------------------

def test_building_the_wheel_as_the_readme_says_leaves_no_file_in_the_clone() -> None:
    """``pip wheel --no-deps .`` alone wrote the wheel into the clone (issue 37, item 9): the
    README and docs/windows.md name ``-w dist/``, and git ignores ``dist/``."""
    for page in ("README.md", "docs/windows.md"):
        text = (ROOT / page).read_text(encoding="utf-8")
        assert re.findall(r"pip wheel [^`]*", text) == ["pip wheel --no-deps . -w dist/"], page
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("git is needed to ask what it ignores")
    ignored = subprocess.run(["git", "check-ignore", "-q", "dist/tmcl_sim-0.1.0-py3-none-any.whl"],
                             cwd=ROOT, timeout=30)
    assert ignored.returncode == 0


def test_the_plot_example_leaves_the_tracked_picture_alone_unless_asked(tmp_path: Path) -> None:
    """``scripts/plot_example.sh`` without an argument writes to a temporary folder (it used to
    rewrite docs/plot-example.png)."""
    before = git_status()
    env = {**_env(), "BIN": str(Path(sys.executable).parent), "TMPDIR": str(tmp_path)}
    done = subprocess.run(["sh", str(ROOT / "scripts" / "plot_example.sh")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=WAIT_S, env=env)
    assert done.returncode == 0, done.stderr[-2000:]
    (picture,) = re.findall(r"^(\S+plot-example\.png): 2 axes", done.stdout, re.M)
    assert Path(picture).is_relative_to(tmp_path) and Path(picture).is_file()
    assert git_status() == before
