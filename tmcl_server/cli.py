"""``tmcl-server``: run simulated TMCL modules (a TMCM-6212 by default) from the shell."""

from __future__ import annotations

import argparse
import asyncio
import errno
import logging
import math
import sys
from pathlib import Path
from typing import NoReturn

from axes.cores import CHIP_CORES
from tmcl_server.loops import LOOPS, new_event_loop
from tmcl_server.observe import DEFAULT_RECORD_MAX, DEFAULT_TRACE_MAX
from tmcl_server.platform import add_stop_handlers, dump_stacks_on_signal
from tmcl_server.server import Server, ServerConfig
from tmcl_server.transports.can import DEFAULT_BUS_NAME, DEFAULT_SOCKETCAND_PORT, check_bus_name
from tmcl_server.transports.tcp import DEFAULT_TCP
from tmcl_spec.modules import DEFAULT_MODULE_TYPE, MODULE_TYPES, module_type
from tmcl_spec.package import add_version_option, doc, docs_location, safe_console, with_suggestion

log = logging.getLogger("tmcl_server")


class UsageError(SystemExit):
    """A bad command-line value: one line on standard error, exit status 2 (as argparse)."""

    def __init__(self, message: str) -> None:
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


class _HelpFormatter(argparse.HelpFormatter):
    """Lines wrap at spaces only: a path to a documentation page stays whole."""

    def _split_lines(self, text: str, width: int) -> list[str]:
        import textwrap

        return textwrap.wrap(" ".join(text.split()), width, break_on_hyphens=False,
                             break_long_words=False)

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        import textwrap

        return textwrap.fill(" ".join(text.split()), width, initial_indent=indent,
                             subsequent_indent=indent, break_on_hyphens=False,
                             break_long_words=False)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        """One line, not the usage block: the line names the option and what is wrong, with
        a did-you-mean for a misspelt option or choice."""
        raise UsageError(f"{with_suggestion(self, message)} (tmcl-server --help lists the options)")


def _number(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
    return value


def positive(text: str) -> float:
    """A finite number > 0 (a rate, a speed factor, a resolution)."""
    value = _number(text)
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be positive")
    return value


_SIZE_UNITS = {"": 1, "k": 1024, "m": 1024 ** 2, "g": 1024 ** 3}


def size(text: str) -> int:
    """Bytes: ``500000``, ``100k``, ``100M``, ``2G`` (binary units; ``0``: no limit)."""
    body = text.strip().lower().removesuffix("b").removesuffix("i")
    unit = body[-1:] if body[-1:] in _SIZE_UNITS else ""
    number = body[:-1] if unit else body
    try:
        value = float(number)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size (e.g. 100M, 500k, 0)") from None
    if not math.isfinite(value) or value < 0 or value * _SIZE_UNITS[unit] > 2 ** 62:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size (e.g. 100M, 500k, 0)")
    bytes_ = int(value * _SIZE_UNITS[unit])
    if 0 < bytes_ < 4096:
        raise argparse.ArgumentTypeError(f"{text!r}: a file limit below 4k holds next to nothing "
                                         "(0 means no limit)")
    return bytes_


def _megabytes(count: int) -> str:
    return f"{count // (1024 * 1024)}M"


def non_negative(text: str) -> float:
    """A finite number >= 0 (a duration)."""
    value = _number(text)
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} cannot be negative")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="tmcl-server", formatter_class=_HelpFormatter,
        description="Simulated TRINAMIC TMCL modules (by default TMCM-6212, firmware V1.05).",
        epilog=f"Documentation: {docs_location()}")
    who = parser.add_mutually_exclusive_group()
    who.add_argument("--modules", type=int, metavar="N",
                     help="host N modules with addresses (and CAN ids) 1..N (default 1)")
    who.add_argument("--address", type=int, metavar="A",
                     help="host one module with address (and CAN id) A")
    parser.add_argument("--tcp", action="append", metavar="HOST:PORT[,mode=rs485|usb]",
                        help=f"serve raw TMCL over TCP (repeatable; default {DEFAULT_TCP}, "
                             "port 0 picks a free port); addresses filter as on RS-485 unless "
                             "mode=usb")
    parser.add_argument("--no-tcp", action="store_true", help="do not open the default TCP port")
    parser.add_argument("--max-connections", type=_positive_int, default=256, metavar="N",
                        help="clients each TCP and socketcand endpoint serves at once; past it "
                             "a newcomer is refused unless a connection is idle (default 256; "
                             f"{doc('robustness.md')}, Connection limits)")
    parser.add_argument("--pty", action="append", metavar="PATH[,mode=usb|rs485]", default=[],
                        help="open a virtual serial port and link PATH to it (repeatable); "
                             "mode usb answers any address like the module's USB port, rs485 "
                             "filters by address; default: usb for one module, rs485 for several")
    parser.add_argument("--serial", action="append", metavar="DEVICE[:BAUD][,mode=usb|rs485]",
                        default=[], help="serve on an existing serial port through pyserial "
                                         "(repeatable; mode as for --pty)")
    can = parser.add_argument_group(f"CAN (see {doc('can.md')})")
    can.add_argument("--can", action="append", metavar="INTERFACE:CHANNEL[:BITRATE]", default=[],
                     help="join the simulated CAN bus to a python-can bus, e.g. socketcan:can0, "
                          "virtual:NAME (repeatable)")
    can.add_argument("--can-bus", metavar="NAME",
                     help="name of the simulated CAN bus (default can0; socketcand clients open it)")
    can.add_argument("--slcan-pty", action="append", metavar="PATH", default=[],
                     help="a virtual SLCAN (Lawicel) USB-CAN adapter on a pty linked at PATH")
    can.add_argument("--socketcand", action="append", metavar="[HOST:]PORT", nargs="?",
                     const=f"127.0.0.1:{DEFAULT_SOCKETCAND_PORT}", default=[],
                     help="a socketcand server (raw mode) on the simulated CAN bus; default "
                          f"127.0.0.1:{DEFAULT_SOCKETCAND_PORT}")
    parser.add_argument("--mqtt", action="append", metavar="URL", default=[],
                        help="bridge to an MQTT broker, e.g. mqtt://127.0.0.1:1883/tmcl "
                             "(mqtts:// for TLS; credentials in the URL or in "
                             "TMCL_MQTT_USERNAME/TMCL_MQTT_PASSWORD)")
    parser.add_argument("--mqtt-rate", type=positive, default=10.0, metavar="HZ",
                        help="at most this many state messages per module and second (default 10)")
    parser.add_argument("--mqtt-faults", action="store_true",
                        help="let MQTT clients inject faults (sim/fault, sim/power_cycle); off by "
                             "default: every client of the broker could silence the module")
    parser.add_argument("--mqtt-commands", action="store_true",
                        help="let MQTT clients send TMCL commands that change the module (SAP, "
                             "STAP, MVP, programs, 137, ...); off by default, since every client "
                             "of the broker could drive it; reads are always served")
    add_model_options(parser)
    parser.add_argument("--speed", type=positive, default=1.0, metavar="X",
                        help="run simulated time X times faster than real time")
    parser.add_argument("--step-every-instruction", action="store_true",
                        help="execute every TMCL program instruction, even in loops that change "
                             "nothing (the reference the default skipping is checked against; "
                             "same results, slower)")
    parser.add_argument("--ready-file", metavar="PATH",
                        help="write the endpoints as JSON to PATH once all accept traffic")
    parser.add_argument("--loop", type=str.lower, choices=LOOPS, default="auto",
                        help="event loop: uvloop (the fast extra) or asyncio's; default auto: "
                             "uvloop if installed")
    watch = parser.add_argument_group(f"watching (see {doc('observe.md')})")
    watch.add_argument("--trace", nargs="?", const="-", metavar="FILE",
                       help="log every request, reply, event and dropped frame, decoded "
                            "(to stderr, or to FILE)")
    watch.add_argument("--trace-format", type=str.lower, choices=["text", "jsonl"], default="text",
                       help="trace lines as text (default) or one JSON object each")
    watch.add_argument("--trace-max", type=size, default=DEFAULT_TRACE_MAX, metavar="SIZE",
                       help="past this size the trace file becomes FILE.1 and a new one starts "
                            f"(default {_megabytes(DEFAULT_TRACE_MAX)}; 0: no limit)")
    watch.add_argument("--record", metavar="FILE",
                       help="record position, velocity, acceleration, current, switches and "
                            "events of the axes to FILE (.csv or .jsonl)")
    watch.add_argument("--record-max", type=size, default=DEFAULT_RECORD_MAX, metavar="SIZE",
                       help="past this size the record file becomes FILE.1 and a new one starts "
                            f"(default {_megabytes(DEFAULT_RECORD_MAX)}; 0: no limit)")
    watch.add_argument("--record-resolution", type=positive, default=0.01, metavar="SECONDS",
                       help="simulated time between two samples (default 0.01)")
    watch.add_argument("--record-axes", metavar="LIST",
                       help="axes to record, e.g. 0,1 (default: all)")
    watch.add_argument("--http", action="append", metavar="[HOST:]PORT", default=[],
                       help="serve the live dashboard (axes, I/O, parameters, program debugger, "
                            "wire) to a browser; host 127.0.0.1 unless given; needs the extra "
                            f"tmcl-sim[http] ({doc('dashboard.md')}); beyond loopback it needs the "
                            "token it prints")
    watch.add_argument("--http-allow-origin", action="append", metavar="ORIGIN", default=[],
                       help="let pages from ORIGIN (e.g. http://lab-pc:9000, or * for any) "
                            "drive the dashboard; by default only its own page may (repeatable)")
    faults = parser.add_argument_group(f"faults and wire timing (see {doc('faults.md')})")
    faults.add_argument("--fault", action="append", metavar="SPEC", default=[],
                        help="inject a fault, e.g. noreply:opcode=GAP,rate=0.1,seed=7 or "
                             "delay:ms=50 or stuck:axis=0 (repeatable)")
    faults.add_argument("--faults", action="append", metavar="FILE", default=[],
                        help="faults from a TOML ([[fault]] tables), JSON or text file (one spec "
                             "a line)")
    faults.add_argument("--wire-timing", action="store_true",
                        help="the pty and serial ports send each byte at the baud rate (GP 65, "
                             "or ,baud=N) and CAN frames take their time at GP 69's bit rate")
    faults.add_argument("--processing-time", type=non_negative, default=0.0002, metavar="SECONDS",
                        help="with --wire-timing: the module's time between a request's last byte "
                             "and its reply's first (default 0.0002)")
    parser.add_argument("--clock", type=str.lower, choices=["real", "lockstep"], default="real",
                        help="real: simulated time follows the wall clock (x --speed); "
                             "lockstep: it moves only by --request-time per request")
    parser.add_argument("--request-time", type=non_negative, default=0.001, metavar="SECONDS",
                        help="with --clock lockstep: simulated time each request takes "
                             "(default 0.001)")
    parser.add_argument("--log-level", default="WARNING", type=str.upper,
                        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                        help="what the server logs to standard error: WARNING (default) "
                             "problems such as dropped replies, INFO also reconnections (MQTT), "
                             "DEBUG also failed writes and malformed input")
    add_version_option(parser, f"simulates a {module_type().name}, firmware {_firmware()}")
    return parser


def add_model_options(parser: argparse.ArgumentParser,
                      default_type: str | None = DEFAULT_MODULE_TYPE,
                      default_said: str = f"default {DEFAULT_MODULE_TYPE}") -> None:
    """What the simulated modules are: --module-type, --axis-core, --world, --state-dir (one
    definition for tmcl-server and ``tmcl replay``; checked by :func:`check_model_options`)."""
    parser.add_argument("--state-dir", metavar="DIR",
                        help="keep each module's EEPROM in DIR/module-<address>/ "
                             "(default: nothing persists)")
    parser.add_argument("--module-type", default=default_type, type=str.lower,
                        choices=sorted(MODULE_TYPES),
                        help=f"which module every address holds ({default_said})")
    parser.add_argument("--axis-core", type=str.lower, choices=sorted(CHIP_CORES),
                        help="the motion-controller chip the axes run on (default: the module "
                             "type's own)")
    parser.add_argument("--world", metavar="FILE",
                        help="TOML file placing switches, load zones, encoder slip and inputs "
                             f"({doc('world.md')}); default: free axes, open switches")


def check_model_options(args: argparse.Namespace) -> None:
    """The options of :func:`add_model_options`, before anything starts: no empty names; the
    state directory is a directory (made if missing)."""
    for name in ("state_dir", "world"):
        value = getattr(args, name)
        if value is not None and not value.strip():
            raise UsageError(f"argument --{name.replace('_', '-')}: an empty value names nothing")
    if args.state_dir is not None:
        if Path(args.state_dir).exists() and not Path(args.state_dir).is_dir():
            raise UsageError(f"argument --state-dir: {args.state_dir} is not a directory")
        try:
            Path(args.state_dir).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"argument --state-dir: cannot use {args.state_dir}: "
                             f"{exc.strerror or exc}") from None


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def _firmware() -> str:
    major, minor = module_type().firmware
    return f"V{major}.{minor:02d}"


def _record_axes(text: str, kind: str) -> list[int]:
    axes = module_type(kind).number_of_axes
    try:
        chosen = [int(a) for a in text.split(",") if a.strip()]
    except ValueError:
        raise UsageError(f"argument --record-axes: bad list {text!r}") from None
    wrong = [a for a in chosen if not 0 <= a < axes]
    if wrong or not chosen:
        raise UsageError(f"argument --record-axes: {text!r}: the axes are 0..{axes - 1}")
    return chosen


#: Options whose values name something (an endpoint, a file): none may be empty.
_NAMING_OPTIONS = ("tcp", "pty", "serial", "can", "slcan_pty", "socketcand", "mqtt", "http",
                   "record", "trace", "faults", "ready_file", "can_bus")


def _check_paths(args: argparse.Namespace) -> None:
    """Files and directories named on the command line, before anything starts."""
    for name in _NAMING_OPTIONS:
        value = getattr(args, name)
        values = value if isinstance(value, list) else [value]
        if any(v is not None and not v.strip() for v in values):
            raise UsageError(f"argument --{name.replace('_', '-')}: an empty value names nothing")
    for option, path in (("--trace", None if args.trace in (None, "-") else args.trace),
                         ("--record", args.record)):
        if path is not None and not Path(path).absolute().parent.is_dir():
            raise UsageError(f"argument {option}: directory {Path(path).absolute().parent} "
                             "does not exist")
    if args.record is not None:
        from tmcl_server.record import file_format

        try:
            file_format(args.record)
        except ValueError as exc:
            raise UsageError(f"argument --record: {exc}") from None
    check_model_options(args)


def config_from_args(args: argparse.Namespace) -> ServerConfig:
    _check_paths(args)
    if args.address is not None:
        if not 1 <= args.address <= 255:
            raise UsageError("argument --address: must be 1..255")
        addresses = [args.address]
    else:
        count = args.modules if args.modules is not None else 1
        if not 1 <= count <= 255:
            raise UsageError("argument --modules: must be 1..255")
        addresses = list(range(1, count + 1))
    endpoints: dict[str, list[str]] = {}
    tcp = args.tcp if args.tcp else ([] if args.no_tcp else [DEFAULT_TCP])
    if tcp:
        endpoints["tcp"] = tcp
    if args.pty:
        endpoints["pty"] = args.pty
    if args.serial:
        endpoints["serial"] = args.serial
    for kind, values in (("can", args.can), ("slcan", args.slcan_pty),
                         ("socketcand", args.socketcand)):
        if values:
            endpoints[kind] = values
    if args.mqtt:
        endpoints["mqtt"] = args.mqtt
    if not endpoints:
        raise UsageError("no transport left to serve on")
    if args.http:  # not a transport for hosts: it does not count as one to serve on
        import importlib.util

        if importlib.util.find_spec("aiohttp") is None:
            raise UsageError("argument --http: needs aiohttp: pip install 'tmcl-sim[http]'")
        endpoints["http"] = args.http
        from tmcl_server.dashboard.guard import AccessPolicy

        try:
            AccessPolicy("127.0.0.1", args.http_allow_origin)
        except ValueError as exc:
            raise UsageError(f"argument --http-allow-origin: {exc}") from None
    try:
        can_bus_name = (check_bus_name(args.can_bus) if args.can_bus is not None
                        else DEFAULT_BUS_NAME)
    except ValueError as exc:
        raise UsageError(f"argument --can-bus: {exc}") from None
    from tmcl_server.faults import MAX_FAULTS, FaultSpecError, load_fault_file, parse_fault

    faults = []
    try:
        for path in args.faults:
            faults += load_fault_file(path)
    except FaultSpecError as exc:  # names the file and the line
        raise UsageError(f"argument --faults: {exc}") from None
    for text in args.fault:
        try:
            faults.append(parse_fault(text))
        except FaultSpecError as exc:
            shown = text if len(text) <= 60 else f"{text[:60]}..."
            raise UsageError(f"argument --fault {shown}: {exc}") from None
    if len(faults) > MAX_FAULTS:
        raise UsageError(f"argument --fault/--faults: {len(faults)} faults, at most {MAX_FAULTS} "
                         "at once")
    if args.axis_core:  # a module type and a core that cannot work together: one line now
        from tmcl_server.module.core import chip_core_problem

        problem = chip_core_problem(module_type(args.module_type), args.axis_core)
        if problem is not None:
            raise UsageError(f"argument --axis-core: {problem}")
    record_axes = _record_axes(args.record_axes, args.module_type) if args.record_axes else None
    return ServerConfig(addresses=addresses, endpoints=endpoints, state_dir=args.state_dir,
                        clock=args.clock, speed=args.speed, ready_file=args.ready_file,
                        mqtt_rate=args.mqtt_rate, can_bus_name=can_bus_name, world=args.world,
                        module_type=args.module_type, axis_core=args.axis_core,
                        request_time=args.request_time, trace=args.trace,
                        trace_format=args.trace_format, record=args.record,
                        record_resolution=args.record_resolution, record_axes=record_axes,
                        faults=faults, wire_timing=args.wire_timing,
                        processing_time=args.processing_time, max_connections=args.max_connections,
                        skip_loops=not args.step_every_instruction,
                        trace_max=args.trace_max, record_max=args.record_max,
                        http_allow_origins=args.http_allow_origin, mqtt_faults=args.mqtt_faults,
                        mqtt_commands=args.mqtt_commands)


#: Errors at start that say the surroundings refused (exit status 1), not that a value given
#: on the command line is wrong (exit status 2): a port or pty link in use, no permission, no
#: such device or protocol here (SocketCAN on a system without it).
_REFUSED = frozenset({errno.EADDRINUSE, errno.EBUSY, errno.EACCES, errno.EPERM, errno.ENODEV,
                      errno.EAFNOSUPPORT, errno.EPROTONOSUPPORT})


class StartError(Exception):
    """The server could not start: one line for standard error, and the exit status."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


def _start_error(exc: Exception) -> StartError:
    """Name the option whose value failed (Server.start notes it) and pick the status."""
    text = str(exc) or type(exc).__name__
    option = exc.__notes__[-1] if getattr(exc, "__notes__", None) else None
    where = f"argument {option}: " if option and not text.startswith(option.split()[0]) else ""
    from tmcl_server.transports.pty import LinkInUseError

    if isinstance(exc, ImportError):  # a library that cannot load here (pyserial without fcntl)
        return StartError(f"{where}this Python cannot load a module it needs: {text}", 1)
    refused = isinstance(exc, LinkInUseError) or (isinstance(exc, OSError)
                                                  and exc.errno in _REFUSED)
    return StartError(f"{where}{text}", 1 if refused else 2)


async def run(config: ServerConfig) -> None:
    try:
        server = Server(config)
    except Exception as exc:  # a world file, the state directory, ... given on the command line
        if (isinstance(exc, OSError) and config.state_dir
                and str(exc.filename or "").startswith(str(config.state_dir))):
            exc.add_note(f"--state-dir {config.state_dir}")
        raise _start_error(exc) from exc
    loop = asyncio.get_running_loop()
    log.info("event loop: %s", type(loop).__module__.split(".")[0])
    add_stop_handlers(loop, server.request_stop)
    try:
        await server.start()
    except Exception as exc:  # an endpoint that cannot be opened as given
        raise _start_error(exc) from exc
    addresses = ", ".join(str(m.address) for m in server.simulation.modules)
    kind = server.simulation.modules[0].type.name
    print(f"tmcl-server: {kind} module(s) at address {addresses}", flush=True)
    for kind, endpoints in server.endpoints.items():
        for endpoint in endpoints:
            print(f"{kind} {endpoint}", flush=True)
    try:
        await server.wait_stopped()
    finally:
        await server.stop()
        print("tmcl-server: stopped", flush=True)


def main(argv: list[str] | None = None) -> int:
    """Exit status 0 after a clean stop, 2 for a bad command-line value (one line on standard
    error, as argparse), 1 when the surroundings refuse (a port in use) or serving fails."""
    safe_console()
    try:
        args = build_parser().parse_args(argv)
        logging.basicConfig(level=args.log_level, format="%(levelname)s %(name)s: %(message)s")
        dump_stacks_on_signal()
        config = config_from_args(args)
        with asyncio.Runner(loop_factory=lambda: new_event_loop(args.loop)) as runner:
            runner.run(run(config))
    except UsageError as exc:
        print(f"tmcl-server: error: {exc.message}", file=sys.stderr)
        return 2
    except StartError as exc:
        print(f"tmcl-server: {'error: ' if exc.status == 2 else ''}{exc}", file=sys.stderr)
        return exc.status
    except (OSError, ValueError) as exc:
        print(f"tmcl-server: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        # Ctrl-C where the loop cannot watch signals (Windows): asyncio.Runner cancelled the
        # server, which closed its endpoints and flushed the EEPROM on the way out (run()).
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
