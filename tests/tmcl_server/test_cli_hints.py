"""What the command lines say when a user slips (issue 37, item 8): one line that names the
fix, a did-you-mean for a misspelt option, command or module type, module types in any case,
SocketCAN's absence said as such, and one exit code per kind of error across the tools."""

from __future__ import annotations

import errno
import subprocess
import sys
from pathlib import Path

import can
import pytest

from interpreter.cli import main as tmcl_asm
from tmcl_server.tool import main as tmcl
from tmcl_server.transports.can.python_can import CanUnavailableError
from tmcl_spec.package import EXIT_BAD_INPUT, EXIT_USAGE


def server(*argv: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", *argv],
                          capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize(("argv", "hint"), [
    (["--modeuls", "3"], "did you mean --modules for --modeuls?"),
    (["--module-type", "tmcm6212"], "did you mean tmcm-6212?"),
    (["--loop", "uvlop"], "did you mean uvloop?"),
    (["--serial", "COM11", "mode=rs485"], "PowerShell splits unquoted commas, quote the argument"),
])
def test_the_server_suggests_what_was_meant(argv: list[str], hint: str) -> None:
    done = server(*argv)
    assert done.returncode == 2
    assert done.stderr.count("\n") == 1 and hint in done.stderr, done.stderr


def test_module_types_and_choices_in_any_case(tmp_path: Path) -> None:
    """``--module-type TMCM-6212`` as printed on the module (it was refused); ``--loop
    ASYNCIO``, ``--log-level info``: checked before anything starts, with --version."""
    from tmcl_server.cli import build_parser

    args = build_parser().parse_args(["--module-type", "TMCM-6212", "--axis-core", "TMC4361A",
                                      "--loop", "ASYNCIO", "--log-level", "info", "--clock", "Real"])
    assert (args.module_type, args.axis_core, args.loop, args.log_level, args.clock) == (
        "tmcm-6212", "tmc4361a", "asyncio", "INFO", "real")


def test_the_tool_suggests_commands_options_and_module_types(capsys: pytest.CaptureFixture[str]) -> None:
    for argv, hint in ((["sned", "GAP", "4", "0"], "did you mean send?"),
                       (["send", "GAP", "4", "0", "--vlaue"], "did you mean --value for --vlaue?"),
                       (["--module-type", "tmcm-6121", "decode", "01 06 04 00 00 00 00 00 0b"],
                        "did you mean tmcm-6212?")):
        with pytest.raises(SystemExit) as exited:
            code = tmcl(argv)
            raise SystemExit(code)
        err = capsys.readouterr().err
        assert exited.value.code == EXIT_USAGE and err.count("\n") == 1 and hint in err, (argv, err)


def test_socketcan_missing_is_one_line_that_says_so() -> None:
    """On this machine SocketCAN is missing (no CAN sockets in a container) or can0 is: either
    way one line that says which, no bare errno."""
    done = server("--can", "socketcan:can0")
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert "[Errno" not in done.stderr
    assert ("this system has no SocketCAN" in done.stderr
            or "no CAN interface 'can0' here" in done.stderr), done.stderr


@pytest.mark.parametrize(("cause", "says"), [
    (OSError(errno.EAFNOSUPPORT, "Address family not supported by protocol"),
     "this system has no SocketCAN"),
    (can.CanInterfaceNotImplementedError("SocketCAN is only available on Linux"),
     "this system has no SocketCAN"),
    (OSError(errno.ENODEV, "No such device"), "no CAN interface 'can7' here"),
])
def test_socketcan_errors_say_what_is_missing(cause: Exception, says: str) -> None:
    text = str(CanUnavailableError("socketcan", "can7", cause))
    assert text.startswith(says) and "\n" not in text
    if "no SocketCAN" in says:
        assert "--can virtual:NAME, --socketcand or --slcan-pty need none" in text


def test_tmcl_asm_and_tmcl_end_a_source_they_cannot_assemble_alike(tmp_path: Path) -> None:
    """The same kind of error, the same exit code (4: a file that cannot be read, assembled
    or decoded), documented in both tools' --help."""
    source = tmp_path / "bad.tmc"
    source.write_text("FLY 1\n")
    assert tmcl_asm(["assemble", str(source)]) == EXIT_BAD_INPUT
    assert tmcl(["--tcp", "127.0.0.1:1", "program", "upload", str(source)]) == EXIT_BAD_INPUT
    assert tmcl_asm(["assemble", str(tmp_path / "missing.tmc")]) == EXIT_BAD_INPUT
    for program in ("interpreter.cli", "tmcl_server.tool"):
        helped = subprocess.run([sys.executable, "-m", program, "--help"], capture_output=True,
                                text=True, timeout=30)
        assert "  4    a file cannot be read, written, assembled or decoded" in helped.stdout
