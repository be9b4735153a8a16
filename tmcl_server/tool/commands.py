"""What each ``tmcl`` subcommand does (the parser is in tmcl_server/tool/__init__.py)."""

from __future__ import annotations

import argparse
import codecs
import csv
import difflib
import json
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from interpreter.assembler import AssemblyError
from interpreter.disassembler import disassemble, listing
from interpreter.isa import Instruction
from tmcl_server.decode import (
    CAN_LOG_SUFFIXES,
    CaptureError,
    Conversation,
    Frame,
    Vocabulary,
    describe_outcome,
    describe_program_record,
    describe_request,
    is_can_log,
    module_type_by_number,
    read_can_log,
    read_capture,
    text_lines,
)
from tmcl_server.protocol import Reply
from tmcl_server.tool.connection import (
    BadInput,
    Connection,
    GaveUp,
    Interrupted,
    Refused,
    ToolError,
    UsageError,
    Where,
)
from tmcl_server.tool.line import LineError, parse_command
from tmcl_server.tool.progress import Progress
from tmcl_server.upload import UploadError, load_program, upload
from tmcl_spec.commands import (
    AXIS_PARAMETER_COMMANDS,
    FACTORY_RESET_KEY,
    GLOBAL_PARAMETER_COMMANDS,
    TYPE_SYMBOLS,
    ApplicationStatus,
    CodeProtection,
    Opcode,
    RfsType,
    Status,
)
from tmcl_spec.modules import ModuleType, module_type
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP, BANK_USER_VARIABLES, GP

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


def parse_type(opcode: int, text: str, motor: int, words: Vocabulary) -> int:
    """The type field: a number, a parameter name (SAP/GAP: axis, SGP/GGP: bank ``motor``) or
    the command's symbol (MVP ABS, RFS START, ...)."""
    stripped = text.strip()
    if stripped.lstrip("-").isdigit() or stripped.lower().startswith("0x"):
        return parse_number(stripped, "the type")
    names = _parameter_names(opcode, motor, words)
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


def _parameter_names(opcode: int, motor: int, words: Vocabulary) -> Any:
    """The names a parameter command's type may be given by (axis parameters, or the bank
    ``motor``), None for any other command."""
    if opcode in AXIS_PARAMETER_COMMANDS:
        return words.axis
    if opcode in GLOBAL_PARAMETER_COMMANDS:
        names = words.banks.get(motor)
        if names is None:
            raise UsageError(f"{words.type.name} has no global parameter bank {motor}")
        return names
    return None


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
    try:
        command = parse_command(" ".join(args.line), words)
    except LineError as exc:
        raise UsageError(str(exc)) from None
    opcode, type_, motor, value = command.opcode, command.type, command.motor, command.value
    text = describe_request(opcode, type_, motor, value, words)
    if args.wait and _motion_done_check(opcode, type_) is None:
        raise UsageError("--wait works with MVP, SAP 0 (TargetPosition) and RFS START")
    where = Where.from_args(args)
    with Connection(where) as conn:
        if opcode == Opcode.GET_FIRMWARE_VERSION and type_ == 0:
            version = conn.version_string()
            _show(args, text, f'→ "{version}"', {"status": Status.OK, "version": version}, version)
            return 0
        if opcode == Opcode.RESTORE_FACTORY_SETTINGS and value == FACTORY_RESET_KEY:
            conn.send_no_reply(opcode, type_, motor, value)
            _show(args, text, "(no reply: the module restarts)", {"status": None}, "")
            return 0
        reply = conn.request(opcode, type_, motor, value)
        try:
            return _answer(args, conn, text, words, reply, (opcode, type_, motor, value))
        except KeyboardInterrupt:  # (during --wait) the move was started: say what runs on
            if not args.wait:
                raise
            conn.close()  # a request may be half answered: a fresh connection stops it
            raise _interrupted_wait(where, opcode, motor, args.stop_on_interrupt) from None


def _answer(args: argparse.Namespace, conn: Connection, text: str, words: Vocabulary, reply: Reply,
            fields: tuple[int, int, int, int]) -> int:
    """Show the reply; with ``--wait``, wait for the move or search it started."""
    opcode, type_, motor, value = fields
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


def _interrupted_wait(where: Where, opcode: int, motor: int, stop: bool) -> Interrupted:
    """Ctrl-C during ``--wait``: the module goes on moving unless asked to stop; say which."""
    search = opcode == Opcode.RFS
    stop_line = f"RFS STOP, {motor}" if search else f"MST {motor}"
    what = "the reference search" if search else f"motor {motor}"
    if not stop:
        return Interrupted(f"interrupted: {what} still runs on the module (stop it with "
                           f"'tmcl send {stop_line}', or pass --stop-on-interrupt)")
    try:
        with Connection(where) as conn:
            if search:
                conn.ok(Opcode.RFS, RfsType.STOP, motor)
            else:
                conn.ok(Opcode.MST, 0, motor)
    except ToolError as exc:
        return Interrupted(f"interrupted; stopping {what} ({stop_line}) failed: {exc}")
    return Interrupted(f"interrupted: {what} stopped ({stop_line})")


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
        bank0 = _read_addresses(conn, kind)
        status = conn.ok(Opcode.GET_APPLICATION_STATUS, 1) & 0xFFFF_FFFF
    info = _info(version, number, kind, bank0, status)
    if args.json:
        _out(json.dumps(info, indent=1))
        return 0
    width = max(map(len, info))
    for key, value in info.items():
        _out(f"{key.replace('_', ' '):<{width}}  {value if value is not None else '-'}")
    return 0


#: The bank 0 rows ``tmcl info`` shows: how the module is addressed on each link.
_ADDRESS_ROWS = (GP.SERIAL_ADDRESS, GP.SERIAL_SECONDARY_ADDRESS, GP.HOST_ADDRESS, GP.BAUD_RATE,
                 GP.CAN_ID, GP.CAN_REPLY_ID, GP.CAN_SECONDARY_ID, GP.CAN_BIT_RATE)


def _read_addresses(conn: Connection, kind: ModuleType | None) -> dict[int, int | None]:
    """The address rows the module's table shows (a module without CAN hides its CAN rows:
    None); all of them from a module of an unknown type."""
    shown = None if kind is None else kind.global_parameters[0]
    return {n: conn.ok(Opcode.GGP, n, 0) if shown is None or (n in shown and shown[n].readable)
            else None for n in _ADDRESS_ROWS}


def _info(version: str, number: int, kind: ModuleType | None, bank0: dict[int, int | None],
          status: int) -> dict[str, Any]:
    """What ``tmcl info`` prints, by name: 136's answers, the addresses, the program's state."""
    rate = bank0[GP.BAUD_RATE]
    baud = None if rate is None else (kind or module_type()).baud_rates.get(rate)
    mode = status >> 24
    return {
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


# -- dump -------------------------------------------------------------------------------------

def cmd_dump(args: argparse.Namespace) -> int:
    with Connection(Where.from_args(args)) as conn:
        kind = _detect_type(conn, args.module_type)
        words = Vocabulary(kind)
        banks = [b for b in kind.global_parameters if args.user or b != BANK_USER_VARIABLES]
        rows = _read_rows(conn, _dump_jobs(kind, words, _axes(args.axes, kind), banks))
    if args.json:
        values: dict[str, dict[str, int | None]] = {}
        for section, _, name, value in rows:
            values.setdefault(section, {})[name] = value
        _out(json.dumps({"type": kind.name, "address": conn.address,
                         "axes": _sections(values, "axis"), "globals": _sections(values, "bank")},
                        indent=1))
        return 0
    _out(f"# {kind.name} module {conn.address} ({conn.where.describe()})")
    for section, number, name, value in rows:
        _out(f"{section:<7} {number:>3} {name:<28} {'-' if value is None else value}")
    return 0


#: One parameter to read: section ("axis 0", "bank 2"), number, motor or bank, name.
_Job = tuple[str, int, int, str]


def _dump_jobs(kind: ModuleType, words: Vocabulary, axes: list[int], banks: list[int]) -> list[_Job]:
    """Every readable row of the chosen axes, then of the chosen banks, in table order."""
    jobs: list[_Job] = []
    for axis in axes:
        jobs += [(f"axis {axis}", n, axis, name) for n, name in words.axis
                 if kind.axis_parameters[n].readable]
    for bank in banks:
        jobs += [(f"bank {bank}", n, bank, name) for n, name in words.banks[bank]
                 if kind.global_parameters[bank][n].readable]
    return jobs


def _read_rows(conn: Connection, jobs: list[_Job]) -> list[tuple[str, int, str, int | None]]:
    """(section, number, name, value) of each job, None where the module refused it."""
    rows: list[tuple[str, int, str, int | None]] = []
    with Progress("dump", len(jobs)) as bar:
        for section, number, where, name in jobs:
            opcode = Opcode.GAP if section.startswith("axis") else Opcode.GGP
            reply = conn.request(opcode, number, where)
            rows.append((section, number, name,
                         to_int32(reply.value) if reply.status == Status.OK else None))
            bar.advance()
    return rows


def _sections(values: dict[str, dict[str, int | None]], kind: str) -> dict[str, dict[str, int | None]]:
    """The sections of one kind ("axis", "bank") by their number."""
    return {s.split()[1]: v for s, v in values.items() if s.startswith(kind)}


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
    columns = _watch_columns(args)
    live = sys.stdout.isatty() and not args.csv
    period = 1.0 / args.rate
    with Connection(Where.from_args(args)) as conn:
        writer = None if live else csv.writer(sys.stdout, lineterminator="\n")
        if writer is not None:
            writer.writerow(["t", *(name for _, _, name in columns)])
        start = time.monotonic()
        count = 0
        while _watching(args, count, time.monotonic() - start):
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


def _watch_columns(args: argparse.Namespace) -> list[tuple[int, int, str]]:
    """(axis, parameter, column name) of each watched value, axis by axis."""
    words = _words(args)
    numbers = [parse_type(Opcode.GAP, name, 0, words) for name in args.parameters]
    axes = _axes(args.axes, words.type)
    return [(axis, number, f"{axis}.{words.axis.name(number) or number}")
            for axis in axes for number in numbers]


def _watching(args: argparse.Namespace, count: int, elapsed: float) -> bool:
    """Until ``--count`` rows or ``--duration`` seconds, whichever ends first (none: for ever)."""
    return ((args.count is None or count < args.count)
            and (args.duration is None or elapsed <= args.duration))


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
    instructions = _program_to_upload(args) if action == "upload" else []
    with Connection(Where.from_args(args)) as conn:
        if action == "upload":
            return _upload(conn, args, instructions)
        if action == "read":
            return _read_program(conn, args)
        control = _PROGRAM_CONTROL.get(action)
        if control is not None:
            control(conn, args)
        return _status(conn, args)


def _program_to_upload(args: argparse.Namespace) -> list[Instruction]:
    """The program file assembled (or read as a binary) before the module is reached."""
    try:
        return load_program(args.program, args.include)
    except AssemblyError as exc:
        raise BadInput(str(exc)) from None
    except (OSError, ValueError) as exc:
        raise BadInput(f"{args.program}: {exc}") from None


def _run_program(conn: Connection, args: argparse.Namespace) -> None:
    """129 from the start (or ``--continue`` where it stopped); with ``--wait``, until it ends."""
    if args.continue_:
        conn.ok(Opcode.RUN_APPLICATION, 0)
    else:
        conn.ok(Opcode.RUN_APPLICATION, 1, 0, args.address_from)
    if args.wait:
        try:
            _wait_for_program(conn, args.wait_timeout)
        except KeyboardInterrupt:
            raise Interrupted("interrupted: the program still runs on the module (stop it "
                              "with 'tmcl program stop')") from None


def _stop_program(conn: Connection, args: argparse.Namespace) -> None:
    conn.ok(Opcode.STOP_APPLICATION)


def _step_program(conn: Connection, args: argparse.Namespace) -> None:
    for _ in range(args.steps):
        conn.ok(Opcode.STEP_APPLICATION)


#: ``tmcl program ACTION`` that acts on the program, then shows its status.
_PROGRAM_CONTROL: dict[str, Callable[[Connection, argparse.Namespace], None]] = {
    "run": _run_program, "stop": _stop_program, "step": _step_program}


def _upload(conn: Connection, args: argparse.Namespace, instructions: list[Instruction]) -> int:
    stopped = _running_program(conn)
    if stopped is not None and not args.force:
        raise Refused(f"module {conn.address} runs a TMCL program (at pc {stopped}); the upload "
                      "would stop it: add --force to stop it and upload")
    total = 2 + len(instructions) * (2 if args.verify else 1) + (2 if args.run else 0)
    with Progress(f"upload {args.program.name}", total) as bar:
        try:
            upload(_CountingClient(conn, bar), instructions, args.start, args.verify, args.run)
        except UploadError as exc:
            raise Refused(str(exc)) from None
    done = ", verified" if args.verify else ""
    was = f" (the program that ran was stopped at pc {stopped})" if stopped is not None else ""
    _out(f"{args.program}: {len(instructions)} commands at {args.start}{done}"
         f"{', running' if args.run else ''}{was}")
    return 0


def _running_program(conn: Connection) -> int | None:
    """The program counter of a running standalone program, or None (stopped, or no answer)."""
    reply = conn.request(Opcode.GET_APPLICATION_STATUS, 1)
    if reply.status != Status.OK:
        return None
    status = reply.value & 0xFFFF_FFFF
    return status & 0xFFFF if status >> 24 == ApplicationStatus.RUN else None


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
    protection = conn.request(Opcode.GGP, GP.CODE_PROTECTION, 0)
    if protection.status == Status.OK and protection.value & CodeProtection.READ:
        raise Refused(f"module {conn.address}'s program memory is read-protected "
                      f"(GP 81 = {to_int32(protection.value)}): it reads back as empty")
    instructions = _read_records(conn, args.start, args.count)
    if not instructions and args.start > 0 and _outside_memory(conn, args.start):
        raise Refused(f"address {args.start} is outside module {conn.address}'s program memory")
    text = listing(instructions, args.start) if args.listing else disassemble(instructions)
    if args.output:
        args.output.write_text(text, encoding="utf-8")
    else:
        sys.stdout.write(text)
    return 0


def _outside_memory(conn: Connection, address: int) -> bool:
    """134 at ``address`` is refused with an ordinary error reply: past program memory."""
    reply = conn.request(Opcode.READ_PROGRAM_MEMORY, 0, 0, address)
    return reply.opcode == Opcode.READ_PROGRAM_MEMORY and reply.status < Status.OK


def _read_records(conn: Connection, start: int, count: int | None) -> list[Instruction]:
    """``count`` records from ``start`` by 134; without a count, up to the first empty one
    (or the end of program memory)."""
    instructions: list[Instruction] = []
    limit = count if count is not None else 1 << 16
    with Progress("read", count) as bar:
        while len(instructions) < limit:
            reply = conn.request(Opcode.READ_PROGRAM_MEMORY, 0, 0, start + len(instructions))
            if reply.opcode == Opcode.READ_PROGRAM_MEMORY and reply.status < Status.OK:
                break  # an ordinary error reply: past the end of program memory
            ins = Instruction(reply.module, reply.status, reply.opcode, to_int32(reply.value))
            if ins.opcode == 0 and count is None:
                break  # empty memory: the end of the program
            instructions.append(ins)
            bar.advance()
    return instructions


# -- decode -----------------------------------------------------------------------------------

def cmd_decode(args: argparse.Namespace) -> int:
    """Streams: frames are printed as they are read, so a long capture needs little memory."""
    if args.file is None and not args.hex and sys.stdin.isatty():
        raise UsageError("give hex bytes, --file FILE, or pipe a dump in")
    if not _show_frames(args, Conversation(_words(args), replies_only=args.replies)):
        raise BadInput("no TMCL frame found in the input")
    return 0


def _show_frames(args: argparse.Namespace, conversation: Conversation) -> int:
    """Each frame printed as it is read (a line or JSON); how many were."""
    shown = 0
    try:
        for frame in conversation.decode(_capture_frames(args)):
            _out(frame.as_json() if args.json else frame.line())
            shown += 1
    except CaptureError as exc:
        raise BadInput(str(exc)) from None
    except BrokenPipeError:  # `tmcl decode ... | head`
        raise
    except OSError as exc:
        raise BadInput(f"{args.file}: {exc.strerror or exc}") from None
    return shown


def _capture_frames(args: argparse.Namespace) -> Iterator[Frame]:
    if args.file is None and args.hex:
        return read_capture([" ".join(args.hex)])
    if args.file is None or str(args.file) == "-":
        return read_capture(text_lines(sys.stdin.buffer, "standard input"))
    path = Path(args.file)
    if is_can_log(path):
        return _can_log_or_text(path)
    if path.is_file():  # (a pipe or device is streamed and checked as it comes)
        _check_text(path)
    return _file_lines(path)


def _can_log_or_text(path: Path) -> Iterator[Frame]:
    """A CAN log by its name; a text dump that merely ends in ``.log`` or ``.csv`` (python-can
    finds no first message in it) is read as text instead."""
    frames = read_can_log(path)
    try:
        first = next(frames)
    except StopIteration:
        return
    except CaptureError:
        try:
            _check_text(path)
        except CaptureError:
            raise CaptureError(f"{path}: neither a CAN log python-can reads nor a text dump") from None
        yield from _file_lines(path)
        return
    yield first
    yield from frames


def _file_lines(path: Path) -> Iterator[Frame]:
    with path.open("rb") as stream:
        yield from read_capture(text_lines(stream, str(path)))


def _check_text(path: Path) -> None:
    """A dump is text: say so before any output if the file is not UTF-8 (read in chunks)."""
    decoder = codecs.getincrementaldecoder("utf-8")()
    offset = 0
    with path.open("rb") as stream:
        while chunk := stream.read(1 << 16):
            try:
                decoder.decode(chunk)
            except UnicodeDecodeError as exc:
                raise CaptureError(_not_text(str(path), offset + exc.start, chunk[exc.start])) from None
            offset += len(chunk)
        try:
            decoder.decode(b"", final=True)
        except UnicodeDecodeError:
            raise CaptureError(_not_text(str(path), offset, None)) from None


def _not_text(name: str, offset: int, byte: int | None) -> str:
    what = f"byte {byte:#04x} at offset {offset}" if byte is not None else "its last bytes"
    return (f"{name} is not a text dump ({what} is not UTF-8): give a hex dump (xxd FILE | tmcl "
            f"decode) or a CAN log python-can reads ({', '.join(CAN_LOG_SUFFIXES)})")


# -- plot -------------------------------------------------------------------------------------

def cmd_plot(args: argparse.Namespace) -> int:
    from tmcl_server.tool.plot import PlotError, plot_file  # imports matplotlib

    try:
        size = tuple(float(x) for x in args.size.lower().split("x"))
        if len(size) != 2 or min(size) <= 0:
            raise ValueError
    except ValueError:
        raise UsageError(f"--size must look like 10x6 (inches), got {args.size!r}") from None
    try:
        axes = [int(a) for a in args.axes.split(",") if a.strip()] if args.axes else None
    except ValueError:
        raise UsageError(f"--axes: a list like 0,2 expected, got {args.axes!r}") from None
    try:
        shown = plot_file(args.record, args.output, axes=axes, size=size, dpi=args.dpi,  # type: ignore[arg-type]
                          title=args.title, whole=args.whole)
    except PlotError as exc:
        raise BadInput(str(exc)) from None
    _out(f"{args.output}: {len(shown)} axes ({', '.join(shown)})")
    return 0

