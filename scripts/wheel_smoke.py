#!/usr/bin/env python3
"""Build the wheel and use it alone, the way a stranger would: a fresh virtualenv in a
temporary folder outside the checkout, ``pip install tmcl_sim-*.whl[http] pytest``, then

* ``tmcl-server`` answers a round trip (``tmcl send`` from the same wheel),
* its dashboard serves the page and its static files (``--http``),
* ``tmcl-asm`` assembles a program that does ``#include TMCLParam.tmc``,
* the pytest plugin's ``tmcl_sim`` fixture works in a test of the stranger's own,
* ``--version`` says pyproject.toml's version, and every page ``--help`` names exists.

Usage: .venv/bin/python scripts/wheel_smoke.py [--keep]     (scripts/test.py runs it)
Exit status 0 when all hold; the first that does not is printed as one line, status 1.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import urllib.request
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
WAIT_S = 30.0  # a fail-safe for what is due
#: Wheels of the requirements, kept between runs (inside .venv: never tracked).
WHEELHOUSE = ROOT / ".venv" / "wheelhouse"
#: The setuptools pyproject.toml's [build-system] asks for (a licence expression needs 77).
BACKEND_SETUPTOOLS = 77

PROGRAM = """\
#include TMCLParam.tmc
    SAP APMaxPositioningSpeed, Motor0, 51200   // names from the include file
    ROR 0, 1000
    WAIT TICKS, 0, 10
    MST 0
    STOP
"""

PLUGIN_TEST = """\
from pytrinamic_free_host import gap

def test_the_fixture_serves(tmcl_sim):
    assert gap(tmcl_sim.tcp, 6) == 128          # AP 6 MaxCurrent, factory default
    tmcl_sim.advance(1.0)
"""

# A host without pytrinamic: nine bytes out, nine back.
HOST = """\
import socket

def gap(endpoint, parameter, motor=0):
    host, port = endpoint.rsplit(":", 1)
    frame = bytes([1, 6, parameter, motor, 0, 0, 0, 0])
    with socket.create_connection((host, int(port)), timeout=5) as s:
        s.sendall(frame + bytes([sum(frame) & 0xFF]))
        reply = b""
        while len(reply) < 9:
            reply += s.recv(9 - len(reply))
    assert reply[2] == 100, reply
    return int.from_bytes(reply[4:8], "big", signed=True)
"""


class SmokeError(Exception):
    pass


def run(*args: str | Path, cwd: Path, env: dict[str, str] | None = None,
        check: bool = True) -> subprocess.CompletedProcess[str]:
    done = subprocess.run([str(a) for a in args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=300)
    if check and done.returncode != 0:
        raise SmokeError(f"{' '.join(map(str, args))} -> exit {done.returncode}: "
                         f"{(done.stderr or done.stdout).strip()[-2000:]}")
    return done


def step(name: str, started: float) -> None:
    print(f"  {name} ({time.monotonic() - started:.1f} s)", flush=True)


def clean_env() -> dict[str, str]:
    """The caller's environment without what would reach back into the checkout."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "PYTHONSTARTUP")}
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def build_wheel(into: Path) -> Path:
    """pyproject.toml's build backend; in this Python when it has it (the test extra brings
    setuptools), saving the isolated build environment's seconds."""
    from importlib import metadata

    try:
        isolation = int(metadata.version("setuptools").split(".")[0]) < BACKEND_SETUPTOOLS
    except (metadata.PackageNotFoundError, ValueError):
        isolation = True
    run(sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir", into,
        *([] if isolation else ["--no-build-isolation"]), ROOT, cwd=into)
    (wheel,) = into.glob("tmcl_sim-*.whl")
    return wheel


def make_venv(where: Path, wheel: Path) -> Path:
    """A fresh virtualenv with the wheel, its http extra and pytest, from the wheelhouse in
    .venv (filled from the package index the first time, or when a requirement is new):
    the install itself checks that the wheel's requirements resolve."""
    venv.EnvBuilder(with_pip=False).create(where)
    python = where / ("Scripts/python.exe" if os.name == "nt" else "bin/python")
    wanted = [f"{wheel}[http]", "pytest"]
    # the checkout's pip installs into the new environment (no ensurepip: seconds saved)
    pip = [sys.executable, "-m", "pip", "--python", python]
    offline = [*pip, "install", "--quiet", "--no-compile", "--no-index", "--find-links",
               WHEELHOUSE, *wanted]
    if run(*offline, cwd=where.parent, env=clean_env(), check=False).returncode != 0:
        WHEELHOUSE.mkdir(parents=True, exist_ok=True)
        run(sys.executable, "-m", "pip", "download", "--quiet", "--dest", WHEELHOUSE, *wanted,
            cwd=where.parent, env=clean_env())
        for own in WHEELHOUSE.glob("tmcl_sim-*.whl"):  # the wheel under test comes from dist
            own.unlink()
        run(*offline, cwd=where.parent, env=clean_env())
    return python


def check_installed_alone(python: Path, cwd: Path) -> None:
    where = run(python, "-c", "import tmcl_server, interpreter; print(tmcl_server.__file__); "
                "print(interpreter.__file__)", cwd=cwd, env=clean_env()).stdout.split()
    outside = [w for w in where if Path(w).resolve().is_relative_to(ROOT)]
    if outside:
        raise SmokeError(f"imported from the checkout, not the wheel: {outside}")


def check_version_and_help(bin_dir: Path, cwd: Path) -> None:
    version = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["version"]
    said = run(bin_dir / "tmcl-server", "--version", cwd=cwd, env=clean_env()).stdout
    if not said.startswith(f"tmcl-server {version} "):
        raise SmokeError(f"tmcl-server --version says {said.strip()!r}, pyproject {version}")
    text = run(bin_dir / "tmcl-server", "--help", cwd=cwd, env=clean_env(),
               ).stdout.replace("\n", " ")
    pages = {p.lstrip("(") for p in re.findall(r"\(?(?:see )?(/\S+?\.md)", text)}
    if not pages:
        raise SmokeError("tmcl-server --help names no documentation page")
    missing = [p for p in pages if not Path(p).is_file()]
    if missing or any(Path(p).resolve().is_relative_to(ROOT) for p in pages):
        raise SmokeError(f"--help names pages the installed wheel lacks: {missing or pages}")


def check_server(bin_dir: Path, cwd: Path) -> None:
    ready = cwd / "ready.json"
    server = subprocess.Popen(
        [bin_dir / "tmcl-server", "--tcp", "127.0.0.1:0", "--http", "127.0.0.1:0",
         "--ready-file", ready], cwd=cwd, env=clean_env(), stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True)
    try:
        assert server.stdout is not None
        if not server.stdout.readline():  # the first line: it is up, the ready file written
            raise SmokeError(f"tmcl-server did not start: {server.communicate()[1].strip()}")
        endpoints = json.loads(ready.read_text())
        tcp, http = endpoints["tcp"][0], endpoints["http"][0]
        value = run(bin_dir / "tmcl", "--tcp", tcp, "send", "GAP", "MaxCurrent", "0", "--value",
                    cwd=cwd, env=clean_env()).stdout.strip()
        if value != "128":
            raise SmokeError(f"tmcl send GAP MaxCurrent 0 answered {value!r}, not 128")
        base = http if http.startswith("http") else f"http://{http}"
        page = fetch(f"{base.rstrip('/')}/")
        scripts = re.findall(r'(?:src|href)="([^"]+\.(?:js|css))"', page)
        if not scripts:
            raise SmokeError("the dashboard page names no static file")
        for path in scripts:
            if not fetch(f"{base.rstrip('/')}/{path.lstrip('/')}"):
                raise SmokeError(f"the dashboard's {path} is empty")
    finally:
        server.terminate()
        server.communicate(timeout=WAIT_S)


def fetch(url: str) -> str:
    try:
        with urllib.request.urlopen(url, timeout=WAIT_S) as response:
            return response.read().decode()
    except OSError as exc:
        raise SmokeError(f"GET {url}: {exc}") from None


def check_assembler(bin_dir: Path, cwd: Path) -> None:
    source = cwd / "prog.tmc"
    source.write_text(PROGRAM)
    run(bin_dir / "tmcl-asm", "assemble", source, cwd=cwd, env=clean_env())
    binary = source.with_suffix(".bin").read_bytes()
    if len(binary) != 5 * 8:  # five instructions
        raise SmokeError(f"tmcl-asm made {len(binary)} bytes of {source}, expected 40")


def check_pytest_plugin(python: Path, cwd: Path) -> None:
    project = cwd / "stranger"
    project.mkdir()
    (project / "pytrinamic_free_host.py").write_text(HOST)
    (project / "test_with_fixture.py").write_text(PLUGIN_TEST)
    done = run(python, "-m", "pytest", "-q", "-p", "no:cacheprovider", cwd=project,
               env={**clean_env(), "PYTHONPATH": str(project)}, check=False)
    if done.returncode != 0 or "1 passed" not in done.stdout:
        raise SmokeError(f"the pytest plugin: {done.stdout.strip()[-1500:]}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--keep", action="store_true", help="keep the temporary folder")
    args = parser.parse_args()
    started = time.monotonic()
    work = Path(tempfile.mkdtemp(prefix="tmcl-wheel-smoke-"))
    print(f"wheel smoke test in {work}", flush=True)
    try:
        (work / "dist").mkdir()
        wheel = build_wheel(work / "dist")
        step(f"built {wheel.name}", started)
        python = make_venv(work / "venv", wheel)
        bin_dir = python.parent
        step("installed it alone in a fresh virtualenv", started)
        (work / "run").mkdir()
        check_installed_alone(python, work / "run")
        check_version_and_help(bin_dir, work / "run")
        step("--version and the pages --help names", started)
        check_server(bin_dir, work / "run")
        step("tmcl-server round trip (tmcl send) and the dashboard's static files", started)
        check_assembler(bin_dir, work / "run")
        step("tmcl-asm with #include TMCLParam.tmc", started)
        check_pytest_plugin(python, work / "run")
        step("the pytest plugin's tmcl_sim fixture", started)
    except SmokeError as exc:
        print(f"wheel smoke test: FAILED: {exc}", file=sys.stderr)
        return 1
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)
    print(f"wheel smoke test: passed in {time.monotonic() - started:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
