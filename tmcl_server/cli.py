"""``tmcl-server``: run simulated TMCL modules (a TMCM-6212 by default) from the shell."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys

from axes.cores import CHIP_CORES
from tmcl_server.loops import LOOPS, new_event_loop
from tmcl_server.server import Server, ServerConfig
from tmcl_server.transports.can import DEFAULT_BUS_NAME, DEFAULT_SOCKETCAND_PORT, check_bus_name
from tmcl_server.transports.tcp import DEFAULT_TCP
from tmcl_spec.modules import DEFAULT_MODULE_TYPE, MODULE_TYPES, module_type
from tmcl_spec.package import add_version_option

log = logging.getLogger("tmcl_server")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tmcl-server",
        description="Simulated TRINAMIC TMCL modules (by default TMCM-6212, firmware V1.05).")
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
                        help="clients each TCP endpoint serves at once; more are accepted and "
                             "closed at once (default 256)")
    parser.add_argument("--pty", action="append", metavar="PATH[,mode=usb|rs485]", default=[],
                        help="open a virtual serial port and link PATH to it (repeatable); "
                             "mode usb answers any address like the module's USB port, rs485 "
                             "filters by address; default: usb for one module, rs485 for several")
    parser.add_argument("--serial", action="append", metavar="DEVICE[:BAUD][,mode=usb|rs485]",
                        default=[], help="serve on an existing serial port through pyserial "
                                         "(repeatable; mode as for --pty)")
    can = parser.add_argument_group("CAN (see docs/can.md)")
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
    parser.add_argument("--mqtt-rate", type=float, default=10.0, metavar="HZ",
                        help="at most this many state messages per module and second (default 10)")
    parser.add_argument("--state-dir", metavar="DIR",
                        help="keep each module's EEPROM in DIR/module-<address>/ "
                             "(default: nothing persists)")
    parser.add_argument("--speed", type=float, default=1.0, metavar="X",
                        help="run simulated time X times faster than real time")
    parser.add_argument("--module-type", default=DEFAULT_MODULE_TYPE, choices=sorted(MODULE_TYPES),
                        help=f"which module every address holds (default {DEFAULT_MODULE_TYPE})")
    parser.add_argument("--axis-core", choices=sorted(CHIP_CORES),
                        help="the motion-controller chip the axes run on (default: the module "
                             "type's own)")
    parser.add_argument("--world", metavar="FILE",
                        help="TOML file placing switches, load zones, encoder slip and inputs "
                             "(docs/world.md); default: free axes, open switches")
    parser.add_argument("--ready-file", metavar="PATH",
                        help="write the endpoints as JSON to PATH once all accept traffic")
    parser.add_argument("--loop", choices=LOOPS, default="auto",
                        help="event loop: uvloop (the fast extra) or asyncio's; default auto: "
                             "uvloop if installed")
    watch = parser.add_argument_group("watching (see README: trace, recorder)")
    watch.add_argument("--trace", nargs="?", const="-", metavar="FILE",
                       help="log every request, reply, event and dropped frame, decoded "
                            "(to stderr, or to FILE)")
    watch.add_argument("--trace-format", choices=["text", "jsonl"], default="text",
                       help="trace lines as text (default) or one JSON object each")
    watch.add_argument("--record", metavar="FILE",
                       help="record position, velocity, acceleration, current, switches and "
                            "events of the axes to FILE (.csv or .jsonl)")
    watch.add_argument("--record-resolution", type=float, default=0.01, metavar="SECONDS",
                       help="simulated time between two samples (default 0.01)")
    watch.add_argument("--record-axes", metavar="LIST",
                       help="axes to record, e.g. 0,1 (default: all)")
    watch.add_argument("--http", action="append", metavar="[HOST:]PORT", default=[],
                       help="serve the live dashboard (axes, I/O, parameters, program debugger, "
                            "wire) to a browser; host 127.0.0.1 unless given; needs the extra "
                            "tmcl-sim[http] (docs/dashboard.md)")
    faults = parser.add_argument_group("faults and wire timing (see docs/faults.md)")
    faults.add_argument("--fault", action="append", metavar="SPEC", default=[],
                        help="inject a fault, e.g. noreply:opcode=GAP,rate=0.1,seed=7 or "
                             "delay:ms=50 or stuck:axis=0 (repeatable)")
    faults.add_argument("--faults", action="append", metavar="FILE", default=[],
                        help="faults from a TOML ([[fault]] tables), JSON or text file (one spec "
                             "a line)")
    faults.add_argument("--wire-timing", action="store_true",
                        help="the pty and serial ports send each byte at the baud rate (GP 65, "
                             "or ,baud=N) and CAN frames take their time at GP 69's bit rate")
    faults.add_argument("--processing-time", type=float, default=0.0002, metavar="SECONDS",
                        help="with --wire-timing: the module's time between a request's last byte "
                             "and its reply's first (default 0.0002)")
    parser.add_argument("--clock", choices=["real", "lockstep"], default="real",
                        help="real: simulated time follows the wall clock (x --speed); "
                             "lockstep: it moves only by --request-time per request")
    parser.add_argument("--request-time", type=float, default=0.001, metavar="SECONDS",
                        help="with --clock lockstep: simulated time each request takes "
                             "(default 0.001)")
    parser.add_argument("--log-level", default="WARNING",
                        choices=["DEBUG", "INFO", "WARNING", "ERROR"],
                        help="what the server logs to standard error: WARNING (default) "
                             "problems such as dropped replies, INFO also reconnections (MQTT), "
                             "DEBUG also failed writes and malformed input")
    add_version_option(parser, f"simulates a {module_type().name}, firmware {_firmware()}")
    return parser


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


def config_from_args(args: argparse.Namespace) -> ServerConfig:
    if args.address is not None:
        if not 1 <= args.address <= 255:
            raise SystemExit("tmcl-server: --address must be 1..255")
        addresses = [args.address]
    else:
        count = args.modules if args.modules is not None else 1
        if not 1 <= count <= 255:
            raise SystemExit("tmcl-server: --modules must be 1..255")
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
        raise SystemExit("tmcl-server: no transport left to serve on")
    if args.http:  # not a transport for hosts: it does not count as one to serve on
        import importlib.util

        if importlib.util.find_spec("aiohttp") is None:
            raise SystemExit("tmcl-server: --http needs aiohttp: pip install 'tmcl-sim[http]'")
        endpoints["http"] = args.http
    if args.speed <= 0:
        raise SystemExit("tmcl-server: --speed must be positive")
    if args.mqtt_rate <= 0:
        raise SystemExit("tmcl-server: --mqtt-rate must be positive")
    try:
        can_bus_name = check_bus_name(args.can_bus) if args.can_bus else DEFAULT_BUS_NAME
    except ValueError as exc:
        raise SystemExit(f"tmcl-server: --can-bus: {exc}") from None
    if args.record_resolution <= 0:
        raise SystemExit("tmcl-server: --record-resolution must be positive")
    if args.request_time < 0:
        raise SystemExit("tmcl-server: --request-time cannot be negative")
    if args.processing_time < 0:
        raise SystemExit("tmcl-server: --processing-time cannot be negative")
    from tmcl_server.faults import FaultSpecError, load_fault_file, parse_fault

    try:
        faults = [spec for path in args.faults for spec in load_fault_file(path)]
        faults += [parse_fault(text) for text in args.fault]
    except FaultSpecError as exc:
        raise SystemExit(f"tmcl-server: fault: {exc}") from None
    try:
        record_axes = ([int(a) for a in args.record_axes.split(",") if a.strip()]
                       if args.record_axes else None)
    except ValueError:
        raise SystemExit(f"tmcl-server: --record-axes: bad list {args.record_axes!r}") from None
    return ServerConfig(addresses=addresses, endpoints=endpoints, state_dir=args.state_dir,
                        clock=args.clock, speed=args.speed, ready_file=args.ready_file,
                        mqtt_rate=args.mqtt_rate, can_bus_name=can_bus_name, world=args.world,
                        module_type=args.module_type, axis_core=args.axis_core,
                        request_time=args.request_time, trace=args.trace,
                        trace_format=args.trace_format, record=args.record,
                        record_resolution=args.record_resolution, record_axes=record_axes,
                        faults=faults, wire_timing=args.wire_timing,
                        processing_time=args.processing_time, max_connections=args.max_connections)


async def run(config: ServerConfig) -> None:
    server = Server(config)
    loop = asyncio.get_running_loop()
    log.info("event loop: %s", type(loop).__module__.split(".")[0])
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, server.request_stop)
    await server.start()
    for module in server.simulation.modules:
        if module.eeprom.problem:
            print(f"warning: module {module.slot}: {module.eeprom.problem}; running on factory "
                  "defaults, nothing is saved", file=sys.stderr, flush=True)
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
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level, format="%(levelname)s %(name)s: %(message)s")
    config = config_from_args(args)
    try:
        with asyncio.Runner(loop_factory=lambda: new_event_loop(args.loop)) as runner:
            runner.run(run(config))
    except (OSError, ValueError) as exc:
        print(f"tmcl-server: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
