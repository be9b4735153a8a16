"""``tmcl``: one command-line tool for TMCL modules, simulated or real.

    tmcl send SAP MaxPositioningSpeed 0 51200      # names or numbers; the reply decoded
    tmcl info                                      # version, type, addresses
    tmcl dump --json > before.json                 # every parameter, diffable
    tmcl watch ActualPosition ActualSpeed --axes 0 --rate 10 --count 50
    tmcl program upload prog.tmc --verify --run    # also: run, stop, step, status, read
    tmcl decode 01 06 04 00 00 00 00 00 0b         # a hex dump or --file capture.txt
    tmcl plot record.csv -o record.png             # a tmcl-server --record file
    tmcl --serial /dev/ttyACM0 proxy --listen-tcp 127.0.0.1:2323 --capture run.jsonl
    tmcl replay run.jsonl                          # the capture against the simulator

It reaches the simulator over TCP (``--tcp``, default 127.0.0.1:2323) or its pty
(``--serial``), and a real module through anything pytrinamic's ConnectionManager accepts
(``--connection "--interface usb_tmcl --port COM4"``; pytrinamic is imported only then).
``tmcl-upload`` is ``tmcl program upload``.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import NoReturn

from tmcl_server.tool.connection import ToolError
from tmcl_spec.package import (
    EXIT_CODES,
    EXIT_USAGE,
    add_version_option,
    doc,
    safe_console,
    version_text,
    with_suggestion,
)

_EPILOG = """examples:
  tmcl send SAP 4, 0, 51200                     set AP 4 of motor 0, as a TMCL program writes it
  tmcl send SAP MaxPositioningSpeed 0 51200     the same: commas optional, names allowed
  tmcl send GAP ActualPosition 0 --value        print only the value
  tmcl send MVP ABS, 0, 51200 --wait            move and wait until the target is reached
  tmcl --serial /tmp/ttyTMCL0 info              over the simulator's pty
  tmcl --connection "--interface usb_tmcl" dump --json > module.json   a real module
  tmcl watch ActualPosition ActualSpeed --axes 0,1 --rate 20 --csv > motion.csv
  tmcl program upload prog.tmc --verify --run
  tmcl decode --file capture.txt                  a hex dump or candump log
  tmcl plot record.csv -o record.png
  tmcl --serial /dev/ttyACM0 proxy --listen-tcp 127.0.0.1:2323 --capture run.jsonl
  tmcl replay run.jsonl                           every reply compared with the simulator's

exit codes:
""" + "\n".join(f"  {code:<4} {meaning}" for code, meaning in EXIT_CODES)


class OneLineParser(argparse.ArgumentParser):
    """Usage errors in one line (the message and where help is), not the usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: {with_suggestion(self, message)} (see {self.prog} --help)\n")


def positive(text: str) -> float:
    """A finite number above 0 (argparse type for seconds and rates): ``inf``, ``nan`` and
    ``0`` get a message of their own, not a failure further on."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a number expected, got {text!r}") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"a finite number above 0 expected, got {text!r}")
    return value


def count(text: str) -> int:
    """A whole number 0 or more (argparse type for addresses and counts)."""
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a whole number expected, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"a number 0 or more expected, got {value}")
    return value


def positive_count(text: str) -> int:
    value = count(text)
    if value == 0:
        raise argparse.ArgumentTypeError("a number above 0 expected, got 0")
    return value


#: ``tmcl program step N`` steps at most this many instructions (one request each): a
#: mistyped count must not keep the tool busy for hours (issue 36, N9).
MAX_STEPS = 10_000


def step_count(text: str) -> int:
    value = positive_count(text)
    if value > MAX_STEPS:
        raise argparse.ArgumentTypeError(f"at most {MAX_STEPS} steps at once, got {value}")
    return value


def _connection_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """--tcp/--serial/--connection/--address/--timeout, before or after the subcommand."""
    default = argparse.SUPPRESS if suppress else None
    group = parser.add_argument_group("connection (one of; default --tcp 127.0.0.1:2323)")
    group.add_argument("--tcp", metavar="HOST:PORT", default=default,
                       help="raw TMCL over TCP (the simulator, an Ethernet-serial converter)")
    group.add_argument("--serial", "--pty", metavar="DEVICE[:BAUD]", default=default,
                       help="raw TMCL over a serial port or the simulator's pty")
    group.add_argument("--connection", metavar="ARGS", default=default,
                       help='pytrinamic ConnectionManager arguments, e.g. "--interface usb_tmcl"')
    group.add_argument("--address", type=count, metavar="A", default=default,
                       help="module address / CAN id (default 1)")
    group.add_argument("--timeout", type=positive, metavar="SECONDS", default=default,
                       help="reply timeout (default 2)")
    group.add_argument("--module-type", metavar="NAME", default=argparse.SUPPRESS if suppress
                       else "tmcm-6212", help="names parameters from this module type's tables "
                       "(default tmcm-6212; dump asks the module)")


def _send_epilog() -> str:
    from tmcl_server.tool.line import old_form_help

    return ("examples:\n  tmcl send SAP 4, 0, 51200\n  tmcl send SAP MaxPositioningSpeed 0 51200\n"
            "  tmcl send SAP APMaxPositioningSpeed, Motor0, 51200   (names of the include files)\n"
            "  tmcl send 'ROR 1, 20000'; tmcl send MST 1\n  tmcl send MVP ABS, 2, 1000 --wait\n"
            "  tmcl send GIO 8, 1\n  tmcl send GGP SerialAddress 0 --value\n"
            "  tmcl send GET_FIRMWARE_VERSION\n  tmcl send 138 0 0 1\n\n" + old_form_help())


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(
        prog="tmcl", description="Talk to a TMCL module (simulated or real): send commands by "
        "name, read its identity and parameters, watch it, manage its program, decode dumps, "
        "plot recordings.", epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version_option(parser)
    _connection_options(parser, suppress=False)
    sub = parser.add_subparsers(dest="subcommand", required=True, metavar="COMMAND")

    def command(name: str, help_text: str, epilog: str = "") -> argparse.ArgumentParser:
        p = sub.add_parser(name, help=help_text, description=help_text, epilog=epilog,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
        _connection_options(p, suppress=True)
        return p

    send = command("send", "send one command, written as in a TMCL program; the reply is printed "
                   "decoded", _send_epilog())
    send.add_argument("line", nargs="+", metavar="COMMAND",
                      help="a TMCL line: mnemonic and the manual's operands (SAP 4, 0, 51200), a "
                      "control command (GET_FIRMWARE_VERSION) or a number with TYPE MOTOR VALUE")
    shown = send.add_mutually_exclusive_group()
    shown.add_argument("--value", dest="value_only", action="store_true", help="print only the reply value")
    shown.add_argument("--json", action="store_true", help="print the reply as JSON")
    send.add_argument("--wait", action="store_true",
                      help="after MVP / SAP 0 / RFS START: wait until the move or search is done")
    send.add_argument("--wait-timeout", type=positive, default=60.0, metavar="SECONDS")
    send.add_argument("--stop-on-interrupt", action="store_true",
                      help="Ctrl-C during --wait stops the motor (MST, or RFS STOP); without it "
                      "the motor goes on and the tool says so")

    info = command("info", "firmware version, module type, addresses, program state")
    info.add_argument("--json", action="store_true")

    dump = command("dump", "every readable axis and global parameter, by name",
                   "examples:\n  tmcl dump > before.txt; ...; tmcl dump | diff before.txt -\n"
                   "  tmcl dump --json --axes 0")
    dump.add_argument("--json", action="store_true", help="one JSON object (default: a table)")
    dump.add_argument("--axes", metavar="LIST", help="only these axes, e.g. 0,1")
    dump.add_argument("--no-user", dest="user", action="store_false",
                      help="leave out the user variables (bank 2)")

    watch = command("watch", "poll axis parameters at a rate: a live table, or CSV",
                    "example:\n  tmcl watch ActualPosition ActualSpeed --axes 0,1 --rate 10")
    watch.add_argument("parameters", nargs="+", metavar="PARAMETER", help="axis parameter names or numbers")
    watch.add_argument("--axes", metavar="LIST", default="0", help="axes (default 0)")
    watch.add_argument("--rate", type=positive, default=5.0, metavar="HZ",
                       help="samples per second (default 5)")
    watch.add_argument("--count", type=positive_count, metavar="N", help="stop after N samples")
    watch.add_argument("--duration", type=positive, metavar="SECONDS", help="stop after this long")
    watch.add_argument("--csv", action="store_true", help="CSV even on a terminal")

    program = command("program", "the standalone TMCL program: upload, run, stop, step, status, read")
    actions = program.add_subparsers(dest="action", required=True, metavar="ACTION")

    def action(name: str, help_text: str) -> argparse.ArgumentParser:
        p = actions.add_parser(name, help=help_text, description=help_text)
        _connection_options(p, suppress=True)
        return p

    up = action("upload", "download a .tmc source or .bin program (132, 133; 134 to verify)")
    up.add_argument("program", type=Path, help=".tmc source or .bin binary")
    up.add_argument("--start", type=count, default=0, help="program address to download to")
    up.add_argument("-I", "--include", action="append", type=Path, default=[], metavar="DIR")
    up.add_argument("--verify", action="store_true", help="read the program back (command 134)")
    up.add_argument("--run", action="store_true", help="reset and start the program afterwards")
    up.add_argument("--force", action="store_true",
                    help="upload even while a program runs (the upload stops it; without "
                    "--force the tool refuses)")
    run = action("run", "start the program (129) and print its state")
    run.add_argument("address_from", nargs="?", type=count, default=0, metavar="ADDRESS",
                     help="start here (default 0)")
    run.add_argument("--continue", dest="continue_", action="store_true",
                     help="continue where it stopped instead")
    run.add_argument("--wait", action="store_true", help="wait until the program stops")
    run.add_argument("--wait-timeout", type=positive, default=600.0, metavar="SECONDS")
    action("stop", "stop the program (128)")
    step = action("step", "execute single instructions (130)")
    step.add_argument("steps", nargs="?", type=step_count, default=1)
    status = action("status", "state, program counter, accumulator and X (135)")
    status.add_argument("--json", action="store_true")
    read = action("read", "read the program back (134) as source")
    read.add_argument("--start", type=count, default=0)
    read.add_argument("--count", type=positive_count,
                      help="commands to read (default: up to the first empty)")
    read.add_argument("--listing", action="store_true", help="numbered addresses instead of labels")
    read.add_argument("-o", "--output", type=Path)

    decode = command("decode", "decode a hex dump or capture file into readable telegrams",
                     "examples:\n  tmcl decode 01 06 04 00 00 00 00 00 0b\n"
                     "  tmcl decode --file capture.txt      (hex, hexdump -C, candump logs)\n"
                     "  xxd -p serial.bin | tmcl decode")
    decode.add_argument("hex", nargs="*", help="bytes in hex")
    decode.add_argument("--file", type=Path, help="a dump or capture file ('-' for stdin)")
    decode.add_argument("--replies", action="store_true", help="every frame is a reply")
    decode.add_argument("--json", action="store_true", help="one JSON object per frame")

    plot = command("plot", "plot a tmcl-server --record file (needs tmcl-sim[plot])")
    plot.add_argument("record", type=Path, help=".csv or .jsonl recording")
    plot.add_argument("-o", "--output", type=Path, required=True, help="image file (.png, .svg, .pdf)")
    plot.add_argument("--axes", metavar="LIST", help="axes to draw (default: those that moved)")
    plot.add_argument("--size", default="10x6", metavar="WxH", help="inches (default 10x6)")
    plot.add_argument("--dpi", type=positive_count, default=100, help="pixels per inch (default 100)")
    plot.add_argument("--title")
    plot.add_argument("--all", dest="whole", action="store_true",
                      help="the whole recording (default: from shortly before the first motion "
                           "to shortly after the last)")

    proxy = command("proxy", "forward hosts' frames to the module unchanged, and capture them",
                    "examples:\n  tmcl --serial /dev/ttyACM0 proxy --listen-tcp 127.0.0.1:2323 "
                    "--capture run.jsonl\n  tmcl --tcp 10.0.0.5:4001 proxy --listen-pty "
                    "/tmp/ttyPROXY --capture run.jsonl\n\nThe capture format: "
                    f"{doc('capture.md')}; replay it with 'tmcl replay run.jsonl'.")
    proxy.add_argument("--listen-tcp", action="append", metavar="HOST:PORT", default=[],
                       help="hosts connect here (repeatable; port 0 picks a free port)")
    proxy.add_argument("--listen-pty", action="append", metavar="PATH", default=[],
                       help="a pseudo-terminal linked at PATH for a serial host (repeatable; "
                       "POSIX only)")
    proxy.add_argument("--capture", metavar="FILE",
                       help="write every request and reply to FILE as they pass (JSON lines)")
    proxy.add_argument("--no-identify", action="store_true",
                       help="do not ask the module's identity (command 136) at start")
    proxy.add_argument("--ready-file", metavar="PATH",
                       help="once the hosts can connect, write the endpoints as JSON to PATH")

    # `tmcl replay` needs the simulator: its options (those of tmcl-server among them) are
    # parsed by tmcl_server.replay, imported only when it runs, so no other command loads it.
    sub.add_parser("replay", help="replay a capture against the simulator and list every "
                   "divergence (tmcl replay --help)", add_help=False,
                   prefix_chars="\0").add_argument("replay_arguments", nargs=argparse.REMAINDER)
    return parser


def main(argv: list[str] | None = None) -> int:
    from tmcl_server.tool import commands

    safe_console()  # a cp1252 console shows "->" for the arrows in decoded replies
    parser = build_parser()
    args = parser.parse_args(argv)
    handler = {"send": commands.cmd_send, "info": commands.cmd_info, "dump": commands.cmd_dump,
               "watch": commands.cmd_watch, "program": commands.cmd_program,
               "decode": commands.cmd_decode, "plot": commands.cmd_plot,
               "proxy": _proxy, "replay": _replay}[args.subcommand]
    try:
        return handler(args)
    except ToolError as exc:
        for line in str(exc).splitlines() or [""]:  # several source errors: one line each
            print(f"tmcl: {line}", file=sys.stderr)
        return exc.exit_code
    except KeyboardInterrupt:
        print("tmcl: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `tmcl dump | head`
        return 0


def _proxy(args: argparse.Namespace) -> int:
    from tmcl_server.tool.proxy import cmd_proxy

    return cmd_proxy(args)


def _replay(args: argparse.Namespace) -> int:
    from tmcl_server.replay import main as replay  # the simulator: loaded for this command only

    return replay(args.replay_arguments)


def upload_alias(argv: list[str] | None = None) -> int:
    """``tmcl-upload PROGRAM [options]`` is ``tmcl program upload PROGRAM [options]``."""
    arguments = sys.argv[1:] if argv is None else argv
    if "--version" in arguments:  # as argparse's --version does: print, then exit 0
        print(version_text("tmcl-upload", "tmcl program upload"))
        raise SystemExit(0)
    return main(["program", "upload", *arguments])


if __name__ == "__main__":
    sys.exit(main())
