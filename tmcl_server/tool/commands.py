"""What each ``tmcl`` subcommand does (the parser is in tmcl_server/tool/__init__.py)."""

from __future__ import annotations

import argparse
import csv
import difflib
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from interpreter.assembler import AssemblyError
from interpreter.disassembler import disassemble, listing
from interpreter.isa import Instruction
from tmcl_server.decode import (
    Vocabulary,
    decode_text,
    describe_outcome,
    describe_program_record,
    describe_request,
    module_type_by_number,
)
from tmcl_server.protocol import Reply
from tmcl_server.tool.connection import (
    BadInput,
    Connection,
    GaveUp,
    Refused,
    UsageError,
    Where,
)
from tmcl_server.tool.progress import Progress
from tmcl_server.upload import UploadError, load_program, upload
from tmcl_spec.commands import TYPE_SYMBOLS, ApplicationStatus, Opcode, Status
from tmcl_spec.modules import ModuleType, module_type
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP, BANK_USER_VARIABLES, GP

_AXIS_COMMANDS = frozenset({Opcode.SAP, Opcode.GAP, Opcode.STAP, Opcode.RSAP, Opcode.AAP})
_GLOBAL_COMMANDS = frozenset({Opcode.SGP, Opcode.GGP, Opcode.STGP, Opcode.RSGP, Opcode.AGP})
#: Mnemonics people type for the control commands, besides the Opcode names.
_ALIASES = {"GETVERSION": Opcode.GET_FIRMWARE_VERSION, "VERSION": Opcode.GET_FIRMWARE_VERSION,
            "RUN": Opcode.RUN_APPLICATION, "STOPAPP": Opcode.STOP_APPLICATION,
            "STATUS": Opcode.GET_APPLICATION_STATUS}
#: How often waits poll the module (wall seconds).
POLL_S = 0.05


def _out(text: str = "") -> None:
    sys.stdout.write(text + "\n")


# -- names ------------------------------------------------------------------------------------

def parse_number(text: str, what: str) -> int:
    try:
        return int(text, 0)
    except ValueError:
        raise UsageError(f"{what} must be a number, got {text!r}") from None


def parse_opcode(text: str) -> int:
    """A mnemonic (``SAP``), an opcode name (``GET_FIRMWARE_VERSION``) or a number."""
    name = text.strip().upper().replace("-", "_")
    if name in Opcode.__members__:
        return int(Opcode[name])
    if name in _ALIASES:
        return int(_ALIASES[name])
    if text.strip().isdigit() or text.strip().lower().startswith("0x"):
        opcode = parse_number(text, "the command")
        if 0 <= opcode <= 255:
            return opcode
    close = difflib.get_close_matches(name, list(Opcode.__members__), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise UsageError(f"unknown command {text!r}{hint}")


def parse_type(opcode: int, text: str, motor: int, words: Vocabulary) -> int:
    """The type field: a number, a parameter name (SAP/GAP: axis, SGP/GGP: bank ``motor``) or
    the command's symbol (MVP ABS, RFS START, ...)."""
    stripped = text.strip()
    if stripped.lstrip("-").isdigit() or stripped.lower().startswith("0x"):
        return parse_number(stripped, "the type")
    names = None
    if opcode in _AXIS_COMMANDS:
        names = words.axis
    elif opcode in _GLOBAL_COMMANDS:
        names = words.banks.get(motor)
        if names is None:
            raise UsageError(f"{words.type.name} has no global parameter bank {motor}")
    if names is not None:
        number = names.number(stripped)
        if number is None:
            close = difflib.get_close_matches(stripped, [n for _, n in names], n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise UsageError(f"unknown parameter {text!r}{hint}")
        return number
    symbols = TYPE_SYMBOLS.get(opcode)  # type: ignore[call-overload]
    if symbols is not None and stripped.upper() in symbols.__members__:
        return int(symbols[stripped.upper()])
    known = f"; one of {', '.join(symbols.__members__)}" if symbols is not None else ""
    raise UsageError(f"type {text!r} is not a number{known}")


def _words(args: argparse.Namespace) -> Vocabulary:
    try:
        return Vocabulary(module_type(args.module_type))
    except ValueError as exc:
        raise UsageError(str(exc)) from None


def _detect_type(conn: Connection, fallback: str) -> ModuleType:
    """The module's own type (command 136 type 1), or the ``--module-type`` one."""
    try:
        number = conn.ok(Opcode.GET_FIRMWARE_VERSION, 1) >> 16
    except Refused:
        number = -1
    return module_type_by_number(number) or module_type(fallback)


# -- send -------------------------------------------------------------------------------------

def cmd_send(args: argparse.Namespace) -> int:
    words = _words(args)
    opcode = parse_opcode(args.command)
    motor = parse_number(args.motor, "the motor/bank") if args.motor is not None else 0
    type_ = parse_type(opcode, args.type, motor, words) if args.type is not None else 0
    value = to_int32(parse_number(args.value, "the value")) if args.value is not None else 0
    text = describe_request(opcode, type_, motor, value, words)
    if args.wait and _motion_done_check(opcode, type_) is None:
        raise UsageError("--wait works with MVP, SAP 0 (TargetPosition) and RFS START")
    with Connection(Where.from_args(args)) as conn:
        if opcode == Opcode.GET_FIRMWARE_VERSION and type_ == 0:
            version = conn.version_string()
            _show(args, text, f'→ "{version}"', {"status": Status.OK, "version": version}, version)
            return 0
        if opcode == Opcode.RESTORE_FACTORY_SETTINGS and value == 1234:
            conn.send_no_reply(opcode, type_, motor, value)
            _show(args, text, "(no reply: the module restarts)", {"status": None}, "")
            return 0
        reply = conn.request(opcode, type_, motor, value)
        if opcode == Opcode.READ_PROGRAM_MEMORY and reply.opcode != opcode:  # the legacy layout
            raw = bytes((reply.host, reply.module, reply.status, reply.opcode)) + \
                (reply.value & 0xFFFFFFFF).to_bytes(4, "big")
            _show(args, text, describe_program_record(raw, value, words),
                  {"status": Status.OK, "instruction": [*raw[1:4], to_int32(reply.value)]}, "")
            return 0
        _show(args, text, describe_outcome(reply.status, reply.opcode, type_, reply.value),
              _reply_json(reply), str(to_int32(reply.value)))
        if reply.status not in (Status.OK, Status.LOADED):
            return Refused.exit_code
        if args.wait:
            _wait_for_motion(conn, opcode, type_, motor, value, args.wait_timeout)
    return 0


def _reply_json(reply: Reply) -> dict[str, Any]:
    try:
        name = Status(reply.status).name
    except ValueError:
        name = "UNKNOWN"
    return {"status": reply.status, "status_name": name, "opcode": reply.opcode,
            "value": to_int32(reply.value), "module": reply.module}


def _show(args: argparse.Namespace, request: str, outcome: str, body: dict[str, Any], value: str) -> None:
    if args.json:
        _out(json.dumps({"request": request, **body, "text": outcome}, ensure_ascii=False))
    elif args.value_only:
        _out(value)
    else:
        _out(f"{request} {outcome}")


def _motion_done_check(opcode: int, type_: int) -> tuple[int, int, int, str] | None:
    """What ``--wait`` polls after this command: (opcode, type, value when done, what), or None."""
    if opcode == Opcode.RFS and type_ == 0:
        return Opcode.RFS, 2, 0, "reference search"
    if opcode == Opcode.MVP or (opcode == Opcode.SAP and type_ == AP.TARGET_POSITION):
        return Opcode.GAP, AP.POSITION_REACHED, 1, "move"
    return None


def _wait_for_motion(conn: Connection, opcode: int, type_: int, motor: int, value: int,
                     timeout: float) -> None:
    """``--wait``: poll until a move arrives (MVP, SAP 0) or a reference search ends (RFS)."""
    check = _motion_done_check(opcode, type_)
    assert check is not None  # cmd_send checked it
    poll_opcode, poll_type, finished, what = check
    label = f"{what} m{motor}"

    def done() -> bool:
        return conn.ok(poll_opcode, poll_type, motor) == finished

    deadline = time.monotonic() + timeout
    with Progress(label) as bar:
        while not done():
            if time.monotonic() > deadline:
                raise GaveUp(f"{label}: not done after {timeout:g} s")
            bar.draw(f"position {conn.ok(Opcode.GAP, AP.ACTUAL_POSITION, motor)}")
            time.sleep(POLL_S)


# -- info -------------------------------------------------------------------------------------

def cmd_info(args: argparse.Namespace) -> int:
    with Connection(Where.from_args(args)) as conn:
        version = conn.version_string()
        number = conn.ok(Opcode.GET_FIRMWARE_VERSION, 1) & 0xFFFF_FFFF
        kind = module_type_by_number(number >> 16)
        bank0 = {n: conn.ok(Opcode.GGP, n, 0) for n in (
            GP.SERIAL_ADDRESS, GP.SERIAL_SECONDARY_ADDRESS, GP.HOST_ADDRESS, GP.BAUD_RATE,
            GP.CAN_ID, GP.CAN_REPLY_ID, GP.CAN_SECONDARY_ID, GP.CAN_BIT_RATE)}
        status = conn.ok(Opcode.GET_APPLICATION_STATUS, 1) & 0xFFFF_FFFF
    baud = (kind or module_type()).baud_rates.get(bank0[GP.BAUD_RATE])
    mode = status >> 24
    info = {
        "version": version,
        "module": number >> 16,
        "firmware": f"{number >> 8 & 0xFF}.{number & 0xFF:02d}",
        "type": kind.name if kind else None,
        "axes": kind.number_of_axes if kind else None,
        "serial_address": bank0[GP.SERIAL_ADDRESS],
        "serial_secondary_address": bank0[GP.SERIAL_SECONDARY_ADDRESS],
        "host_address": bank0[GP.HOST_ADDRESS],
        "baud_rate": baud,
        "can_id": bank0[GP.CAN_ID],
        "can_reply_id": bank0[GP.CAN_REPLY_ID],
        "can_secondary_id": bank0[GP.CAN_SECONDARY_ID],
        "program": "DOWNLOAD" if mode == 4 else ApplicationStatus(mode).name if mode < 4 else mode,
        "program_counter": status & 0xFFFF,
    }
    if args.json:
        _out(json.dumps(info, indent=1))
        return 0
    width = max(map(len, info))
    for key, value in info.items():
        _out(f"{key.replace('_', ' '):<{width}}  {value if value is not None else '-'}")
    return 0


# -- dump -------------------------------------------------------------------------------------

def cmd_dump(args: argparse.Namespace) -> int:
    with Connection(Where.from_args(args)) as conn:
        kind = _detect_type(conn, args.module_type)
        words = Vocabulary(kind)
        axes = _axes(args.axes, kind)
        banks = [b for b in kind.global_parameters if args.user or b != BANK_USER_VARIABLES]
        jobs: list[tuple[str, int, int, str]] = []  # section, number, motor/bank, name
        for axis in axes:
            jobs += [(f"axis {axis}", n, axis, name) for n, name in words.axis
                     if kind.axis_parameters[n].readable]
        for bank in banks:
            jobs += [(f"bank {bank}", n, bank, name) for n, name in words.banks[bank]
                     if kind.global_parameters[bank][n].readable]
        values: dict[str, dict[str, int | None]] = {}
        rows: list[tuple[str, int, str, int | None]] = []
        with Progress("dump", len(jobs)) as bar:
            for section, number, where, name in jobs:
                opcode = Opcode.GAP if section.startswith("axis") else Opcode.GGP
                reply = conn.request(opcode, number, where)
                value = to_int32(reply.value) if reply.status == Status.OK else None
                values.setdefault(section, {})[name] = value
                rows.append((section, number, name, value))
                bar.advance()
    if args.json:
        _out(json.dumps({"type": kind.name, "address": conn.address,
                         "axes": {s.split()[1]: v for s, v in values.items() if s.startswith("axis")},
                         "globals": {s.split()[1]: v for s, v in values.items() if s.startswith("bank")}},
                        indent=1))
        return 0
    _out(f"# {kind.name} module {conn.address} ({conn.where.describe()})")
    for section, number, name, value in rows:
        _out(f"{section:<7} {number:>3} {name:<28} {'-' if value is None else value}")
    return 0


def _axes(text: str | None, kind: ModuleType) -> list[int]:
    if not text:
        return list(range(kind.number_of_axes))
    try:
        axes = [int(a) for a in text.split(",") if a.strip()]
    except ValueError:
        raise UsageError(f"--axes: a list like 0,2 expected, got {text!r}") from None
    bad = [a for a in axes if not 0 <= a < kind.number_of_axes]
    if bad:
        raise UsageError(f"{kind.name} has axes 0..{kind.number_of_axes - 1}, not {bad}")
    return axes


# -- watch ------------------------------------------------------------------------------------

def cmd_watch(args: argparse.Namespace) -> int:
    if args.rate <= 0:
        raise UsageError("--rate must be positive")
    words = _words(args)
    numbers = [parse_type(Opcode.GAP, name, 0, words) for name in args.parameters]
    axes = _axes(args.axes, words.type)
    columns = [(axis, number, f"{axis}.{words.axis.name(number) or number}")
               for axis in axes for number in numbers]
    live = sys.stdout.isatty() and not args.csv
    period = 1.0 / args.rate
    with Connection(Where.from_args(args)) as conn:
        writer = None if live else csv.writer(sys.stdout, lineterminator="\n")
        if writer is not None:
            writer.writerow(["t", *(name for _, _, name in columns)])
        start = time.monotonic()
        count = 0
        while (args.count is None or count < args.count) and (
                args.duration is None or time.monotonic() - start <= args.duration):
            t = time.monotonic() - start
            row = [conn.ok(Opcode.GAP, number, axis) for axis, number, _ in columns]
            if writer is not None:
                writer.writerow([f"{t:.3f}", *row])
                sys.stdout.flush()
            else:
                _draw_table(columns, row, t, redraw=count > 0)
            count += 1
            time.sleep(max(0.0, start + count * period - time.monotonic()))
    return 0


def _draw_table(columns: Sequence[tuple[int, int, str]], row: Sequence[int], t: float,
                redraw: bool) -> None:
    lines = [f"t = {t:8.2f} s"] + [f"  {name:<34} {value:>12}" for (_, _, name), value in zip(
        columns, row, strict=True)]
    if redraw:
        sys.stdout.write(f"\x1b[{len(lines)}F")
    sys.stdout.write("\n".join(f"{line}\x1b[K" for line in lines) + "\n")
    sys.stdout.flush()


# -- program ----------------------------------------------------------------------------------

class _CountingClient:
    """Hands upload()'s commands to the connection and moves the progress bar."""

    def __init__(self, conn: Connection, bar: Progress) -> None:
        self.conn = conn
        self.bar = bar

    def send(self, opcode: int, type_: int, motor: int, value: int) -> tuple[int, int, int, int]:
        reply = self.conn.request(opcode, type_, motor, value)
        self.bar.advance()
        return reply.module, reply.status, reply.opcode, to_int32(reply.value)

    def close(self) -> None:
        pass


def cmd_program(args: argparse.Namespace) -> int:
    action = args.action
    if action == "upload":
        try:
            instructions = load_program(args.program, args.include)
        except AssemblyError as exc:
            raise BadInput(str(exc)) from None
        except (OSError, ValueError) as exc:
            raise BadInput(f"{args.program}: {exc}") from None
    with Connection(Where.from_args(args)) as conn:
        if action == "upload":
            return _upload(conn, args, instructions)
        if action == "run":
            if args.continue_:
                conn.ok(Opcode.RUN_APPLICATION, 0)
            else:
                conn.ok(Opcode.RUN_APPLICATION, 1, 0, args.address_from)
            if args.wait:
                _wait_for_program(conn, args.wait_timeout)
        elif action == "stop":
            conn.ok(Opcode.STOP_APPLICATION)
        elif action == "step":
            for _ in range(args.steps):
                conn.ok(Opcode.STEP_APPLICATION)
        elif action == "read":
            return _read_program(conn, args)
        return _status(conn, args)


def _upload(conn: Connection, args: argparse.Namespace, instructions: list[Instruction]) -> int:
    total = 2 + len(instructions) * (2 if args.verify else 1) + (2 if args.run else 0)
    with Progress(f"upload {args.program.name}", total) as bar:
        try:
            upload(_CountingClient(conn, bar), instructions, args.start, args.verify, args.run)
        except UploadError as exc:
            raise Refused(str(exc)) from None
    done = ", verified" if args.verify else ""
    _out(f"{args.program}: {len(instructions)} commands at {args.start}{done}"
         f"{', running' if args.run else ''}")
    return 0


def _wait_for_program(conn: Connection, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    with Progress("program running") as bar:
        while True:
            status = conn.ok(Opcode.GET_APPLICATION_STATUS, 1) & 0xFFFF_FFFF
            if status >> 24 != ApplicationStatus.RUN:
                return
            if time.monotonic() > deadline:
                raise GaveUp(f"the program still runs after {timeout:g} s")
            bar.draw(f"pc {status & 0xFFFF}")
            time.sleep(POLL_S)


def _status(conn: Connection, args: argparse.Namespace) -> int:
    status = conn.ok(Opcode.GET_APPLICATION_STATUS, 1) & 0xFFFF_FFFF
    mode = status >> 24
    body = {"state": "DOWNLOAD" if mode == 4 else ApplicationStatus(mode).name if mode < 4 else mode,
            "pc": status & 0xFFFF, "waiting": bool(status >> 16 & 0xFF),
            "accumulator": conn.ok(Opcode.GET_APPLICATION_STATUS, 2),
            "x": conn.ok(Opcode.GET_APPLICATION_STATUS, 3)}
    if getattr(args, "json", False):
        _out(json.dumps(body))
    else:
        waiting = ", waiting" if body["waiting"] else ""
        _out(f"{body['state']} pc {body['pc']}{waiting}  A={body['accumulator']} X={body['x']}")
    return 0


def _read_program(conn: Connection, args: argparse.Namespace) -> int:
    instructions: list[Instruction] = []
    address = args.start
    limit = args.count if args.count is not None else 1 << 16
    with Progress("read", args.count) as bar:
        while len(instructions) < limit:
            reply = conn.request(Opcode.READ_PROGRAM_MEMORY, 0, 0, address)
            if reply.opcode == Opcode.READ_PROGRAM_MEMORY and reply.status < Status.OK:
                break  # an ordinary error reply: past the end of program memory
            ins = Instruction(reply.module, reply.status, reply.opcode, to_int32(reply.value))
            if ins.opcode == 0 and args.count is None:
                break  # empty memory: the end of the program
            instructions.append(ins)
            address += 1
            bar.advance()
    text = listing(instructions, args.start) if args.listing else disassemble(instructions)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


# -- decode -----------------------------------------------------------------------------------

def cmd_decode(args: argparse.Namespace) -> int:
    if args.file is not None:
        try:
            text = sys.stdin.read() if str(args.file) == "-" else \
                Path(args.file).read_text(encoding="utf-8", errors="replace")
        except OSError as exc:
            raise BadInput(f"{args.file}: {exc}") from None
    elif args.hex:
        text = " ".join(args.hex)
    elif not sys.stdin.isatty():
        text = sys.stdin.read()
    else:
        raise UsageError("give hex bytes, --file FILE, or pipe a dump in")
    try:
        decoded = decode_text(text, _words(args), replies_only=args.replies)
    except ValueError as exc:
        raise BadInput(f"cannot read the dump: {exc}") from None
    if not decoded:
        raise BadInput("no TMCL frame found in the input")
    for frame in decoded:
        _out(frame.as_json() if args.json else frame.line())
    return 0


# -- plot -------------------------------------------------------------------------------------

def cmd_plot(args: argparse.Namespace) -> int:
    from tmcl_server.tool.plot import PlotError, plot_file  # imports matplotlib

    try:
        size = tuple(float(x) for x in args.size.lower().split("x"))
        if len(size) != 2 or min(size) <= 0:
            raise ValueError
    except ValueError:
        raise UsageError(f"--size must look like 10x6 (inches), got {args.size!r}") from None
    axes = [int(a) for a in args.axes.split(",")] if args.axes else None
    try:
        shown = plot_file(args.record, args.output, axes=axes, size=size, dpi=args.dpi,  # type: ignore[arg-type]
                          title=args.title, whole=args.whole)
    except PlotError as exc:
        raise BadInput(str(exc)) from None
    _out(f"{args.output}: {len(shown)} axes ({', '.join(shown)})")
    return 0

