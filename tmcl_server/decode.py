"""TMCL frames as readable text: ``SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK``.

One decoder for the server's trace (``tmcl-server --trace``), the ``tmcl`` tool's replies and
``tmcl decode`` (a hex dump or a capture file pasted from a user's logs).  It knows the wire
layouts (serial 9-byte frames, CAN payloads, the 136 version string, the 134 legacy read-back)
and names parameters from the module type's tables (:mod:`tmcl_spec.names`); it imports no
transport library and nothing of the running server.
"""

from __future__ import annotations

import io
import json
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

from tmcl_server.protocol import FRAME_LENGTH, Reply, Request, checksum
from tmcl_spec.commands import (
    AXIS_PARAMETER_COMMANDS,
    GLOBAL_PARAMETER_COMMANDS,
    OPERANDS,
    TYPE_SYMBOLS,
    ApplicationStatus,
    Opcode,
    Status,
)
from tmcl_spec.modules import MODULE_TYPES, ModuleType, module_type
from tmcl_spec.names import ParameterNames, module_names
from tmcl_spec.numbers import to_int32

#: Commands whose request value is written (shown as ``= value``).
_WRITES = frozenset({Opcode.SAP, Opcode.SGP, Opcode.SIO, Opcode.SCO, Opcode.WRITE_MC})
#: Commands whose reply value is a reading (shown after the status).
_READS = frozenset({Opcode.GAP, Opcode.GGP, Opcode.GIO, Opcode.GCO, Opcode.CCO, Opcode.READ_MC,
                    Opcode.READ_MC_PYTRINAMIC, Opcode.GET_APPLICATION_STATUS})
_COORDINATE_COMMANDS = frozenset({Opcode.SCO, Opcode.GCO, Opcode.CCO, Opcode.ACO})
_STATUS_NAMES = {int(s): s.name for s in Status}
_OPCODE_NAMES = {int(o): o.name for o in Opcode}
_MODE_NAMES = {int(m): m.name for m in ApplicationStatus} | {4: "DOWNLOAD"}


def status_name(status: int) -> str:
    return _STATUS_NAMES.get(status, "UNKNOWN")


def opcode_name(opcode: int) -> str:
    return _OPCODE_NAMES.get(opcode, f"opcode {opcode}")


class Vocabulary:
    """A module type's names, prepared for decoding (parameter names, banks)."""

    def __init__(self, kind: ModuleType | str | None = None) -> None:
        self.type = module_type() if kind is None else (
            module_type(kind) if isinstance(kind, str) else kind)
        self.axis: ParameterNames
        self.banks: dict[int, ParameterNames]
        self.axis, self.banks = module_names(self.type)

    def parameter_name(self, opcode: int, number: int, bank: int) -> str | None:
        if opcode in AXIS_PARAMETER_COMMANDS:
            return self.axis.name(number)
        names = self.banks.get(bank)
        return names.name(number) if names is not None else None


_VOCABULARIES: dict[int, Vocabulary] = {}


def vocabulary(kind: ModuleType | None = None) -> Vocabulary:
    """The (cached) vocabulary of a module type (the default type when None)."""
    kind = kind or module_type()
    found = _VOCABULARIES.get(id(kind))
    if found is None or found.type is not kind:
        found = _VOCABULARIES[id(kind)] = Vocabulary(kind)
    return found


def module_type_by_number(number: int) -> ModuleType | None:
    """The profile whose command 136 module number is ``number`` (e.g. 6212), if any."""
    for key in MODULE_TYPES:
        kind = module_type(key)
        if kind.module_number == number:
            return kind
    return None


# -- requests ---------------------------------------------------------------------------------

def _symbol(opcode: int, type_: int) -> str:
    symbols = TYPE_SYMBOLS.get(opcode)  # type: ignore[call-overload]
    if symbols is not None:
        try:
            return symbols(type_).name
        except ValueError:
            pass
    return str(type_)


def describe_request(opcode: int, type_: int, motor: int, value: int,
                     words: Vocabulary | None = None) -> str:
    """A command as text, e.g. ``SAP 4 MaxPositioningSpeed m0 = 51200``, ``MVP ABS m0 51200``."""
    words = words or vocabulary()
    if opcode in AXIS_PARAMETER_COMMANDS or opcode in GLOBAL_PARAMETER_COMMANDS:
        name = words.parameter_name(opcode, type_, motor)
        where = f"m{motor}" if opcode in AXIS_PARAMETER_COMMANDS else f"b{motor}"
        text = f"{_OPCODE_NAMES[opcode]} {type_}{' ' + name if name else ''} {where}"
        return f"{text} = {value}" if opcode in _WRITES else text
    if opcode == Opcode.SIO:
        return f"SIO {type_} b{motor} = {value}"
    if opcode == Opcode.GIO:
        return f"GIO {type_} b{motor}"
    if opcode in _COORDINATE_COMMANDS:
        return f"{_OPCODE_NAMES[opcode]} {type_} m{motor}" + (
            f" = {value}" if opcode in _WRITES else "")
    try:
        known = Opcode(opcode)
    except ValueError:
        return f"opcode {opcode} type {type_} motor {motor} value {value}"
    if known in OPERANDS:
        parts = [known.name]
        for spec in OPERANDS[known]:
            if spec.slot == "type":
                parts.append(_symbol(opcode, type_))
            elif spec.slot == "motor":
                parts.append(f"m{motor}")
            else:
                parts.append(str(value))
        return " ".join(parts)
    return _describe_control(known, type_, motor, value)


def _describe_control(opcode: Opcode, type_: int, motor: int, value: int) -> str:
    name = opcode.name
    if opcode == Opcode.RUN_APPLICATION:
        return f"{name} from {value}" if type_ == 1 else f"{name} (continue)"
    if opcode in (Opcode.ENTER_DOWNLOAD_MODE, Opcode.READ_PROGRAM_MEMORY):
        return f"{name} at {value}"
    if opcode in (Opcode.GET_APPLICATION_STATUS, Opcode.GET_FIRMWARE_VERSION):
        return f"{name} type {type_}"
    if opcode == Opcode.RESTORE_FACTORY_SETTINGS:
        return f"{name} {value}"
    if opcode == Opcode.TARGET_REACHED_EVENT:
        return f"{name} {'every move' if type_ == 1 else 'next move'} axes {_axes(value)}"
    if opcode in (Opcode.WRITE_MC, Opcode.READ_MC, Opcode.READ_MC_PYTRINAMIC):
        return f"{name} register {type_:#04x} m{motor}" + (
            f" = {value}" if opcode == Opcode.WRITE_MC else "")
    return name


def _axes(mask: int) -> str:
    bits = [str(i) for i in range(32) if mask >> i & 1]
    return ",".join(bits) if bits else "none"


# -- replies ----------------------------------------------------------------------------------

def describe_value(opcode: int, type_: int, value: int) -> str | None:
    """The reply value of a reading command, as text (None: the value only echoes)."""
    if opcode == Opcode.GET_FIRMWARE_VERSION and type_ == 1:
        value &= 0xFFFF_FFFF
        return f"{value} ({value >> 16} V{value >> 8 & 0xFF}.{value & 0xFF:02d})"
    if opcode == Opcode.GET_APPLICATION_STATUS and type_ in (0, 1):
        mode = _MODE_NAMES.get(value >> 24 & 0xFF, str(value >> 24 & 0xFF))
        pointer = "download address" if type_ == 0 else "pc"
        waiting = ", waiting" if value >> 16 & 0xFF else ""
        return f"{value} ({mode}, {pointer} {value & 0xFFFF}{waiting})"
    if opcode in _READS or (opcode == Opcode.RFS and type_ == 2):
        return str(value)
    return None


def describe_reply(reply: Reply, request: Request | None = None) -> str:
    """``→ 100 OK``, with the value of a reading (``→ 100 OK = 51200``) or of a 138 event."""
    return describe_outcome(reply.status, reply.opcode, request.type if request is not None else 0,
                            reply.value)


def describe_outcome(status: int, opcode: int, type_: int, value: int) -> str:
    """A reply's status, and its value when the command reads one (``type_`` is the request's)."""
    if status == Status.TARGET_REACHED_EVENT and opcode != Opcode.TARGET_REACHED_EVENT:
        return f"→ {status} DELAYED = {to_int32(value)}"  # the evaluation firmware's "not yet"
    text = f"→ {status} {status_name(status)}"
    if status == Status.TARGET_REACHED_EVENT:
        return f"{text} axes {_axes(value)}"
    if status not in (Status.OK, Status.LOADED):
        return text
    shown = describe_value(opcode, type_, to_int32(value))
    return f"{text} = {shown}" if shown is not None else text


def describe_version_string(data: bytes) -> str:
    """Command 136 type 0: ``[host]`` + 8 ASCII characters, no checksum."""
    return f'→ "{data[1:FRAME_LENGTH].decode("ascii", "replace")}"'


def describe_program_record(data: bytes, address: int | None = None,
                            words: Vocabulary | None = None) -> str:
    """Command 134: ``[host][opcode][type][motor][value x4][checksum]`` (a stored command)."""
    value = to_int32(int.from_bytes(data[4:8], "big"))
    where = f"@{address}: " if address is not None else ""
    if data[1] == 0:
        return f"→ {where}(empty)"
    return f"→ {where}{describe_request(data[1], data[2], data[3], value, words)}"


def is_version_string(data: bytes) -> bool:
    text = data[1:FRAME_LENGTH]
    return len(text) == 8 and all(0x20 <= b < 0x7F for b in text)


# -- hex dumps and capture files --------------------------------------------------------------

@dataclass
class Frame:
    """Bytes as captured: a serial stream chunk, or one CAN frame (``can_id`` set), with the
    capture's timestamp as it writes it (``1700000000.000100``, ``12:00:01.5``) if it has one."""

    data: bytes
    can_id: int | None = None
    #: The capture's timestamp of the frame, as it writes it (shown by ``tmcl decode``).
    timestamp: str | None = None

    @property
    def time(self) -> float | None:
        """When it was captured, in seconds of the log's own time base (``tmcl replay``):
        the timestamp read as seconds or as ``[[h:]m:]s``; None where there is none."""
        if self.timestamp is None:
            return None
        seconds = 0.0
        try:
            for part in self.timestamp.split(":"):
                seconds = seconds * 60 + float(part)
        except ValueError:
            return None
        return seconds


@dataclass
class Decoded:
    """One decoded frame: what it is and what it says."""

    kind: str  # request, reply, event, version, program, bad-checksum, incomplete
    data: bytes
    text: str
    can_id: int | None = None
    fields: dict[str, Any] = field(default_factory=dict)
    #: The capture's timestamp of the frame (its first byte's line), as the capture writes it.
    timestamp: str | None = None

    def line(self) -> str:
        when = f"{self.timestamp}  " if self.timestamp is not None else ""
        where = f"id {self.can_id:03x}  " if self.can_id is not None else ""
        return f"{when}{where}{self.data.hex(' '):<26}  {self.kind:<8} {self.text}"

    def as_json(self) -> str:
        body: dict[str, Any] = {"kind": self.kind, "bytes": self.data.hex(), "text": self.text}
        if self.timestamp is not None:
            body["timestamp"] = self.timestamp
        if self.can_id is not None:
            body["can_id"] = self.can_id
        body.update(self.fields)
        return json.dumps(body)


class CaptureError(ValueError):
    """A capture that cannot be read; the message is one line and names the place."""


#: candump's default format, with or without its timestamp: ``can0  001   [7]  06 04 ...``
_CANDUMP = re.compile(r"^\s*(?:\(\S+\)\s+)?\S+\s+([0-9A-Fa-f]{3,8})\s+\[(\d+)\]\s*((?:[0-9A-Fa-f]{2}\s*)*)")
#: candump -L and python-can's .log: ``(1700000000.000000) can0 001#0604...`` (python-can
#: appends `` T``/`` R``; ``##`` is CAN FD with a flags digit, ``#R`` a remote frame).
_CANDUMP_LOG = re.compile(
    r"(?:^|\s)\S+\s+([0-9A-Fa-f]{3,8})#(#[0-9A-Fa-f]|R)?([0-9A-Fa-f]*)(?:\s+[A-Z])?\s*$")
#: python-can's Printer (``python -m can.logger`` on a terminal, its ``.txt`` files).
_PRINTER = re.compile(r"^\s*Timestamp:\s*\S+\s+ID:\s*([0-9A-Fa-f]+)\s+(.*?)\bDL:\s*(\d+)\s*"
                      r"((?:[0-9A-Fa-f]{2}\s)*(?:[0-9A-Fa-f]{2})?)")
#: Offset-addressed dumps, one line each: hexdump -C (``|ascii|``), od -t x1 [z] (``>ascii<``),
#: xxd (``offset: 0106 0400 ...  ascii``), hexdump / od -x (little-endian 16-bit words).
_HEXDUMP_C = re.compile(r"^([0-9A-Fa-f]{6,16})\s\s((?:[0-9A-Fa-f]{2}\s{1,2}){1,32})\s*\|")
_OD_BYTES = re.compile(r"^([0-9A-Fa-f]{6,16})((?:\s[0-9A-Fa-f]{2}){1,32})\s*(?:>.*)?$")
_XXD = re.compile(r"^([0-9A-Fa-f]{6,16}):\s(.*)$")
_WORDS = re.compile(r"^([0-9A-Fa-f]{6,16})((?:\s+[0-9A-Fa-f]{4}){1,16})\s*$")
_OFFSET_ONLY = re.compile(r"^([0-9A-Fa-f]{6,16})\s*$")
_XXD_I_LENGTH = re.compile(r"^\s*unsigned\s+int\s+\w+\s*=\s*\d+\s*;")
#: A CAN log line's timestamp: candump's ``(1700000000.000100)``, the Printer's ``Timestamp: T``.
_CAN_TIMESTAMP = re.compile(r"^\s*(?:\((\d+(?:\.\d+)?)\)|Timestamp:\s*(\S+))")
#: A hex line's leading timestamp (a hand-made or a serial monitor's log): ``12:00:01.5``,
#: ``[12.345]``, ``(1700000000.0001)``; a dot or colon tells it from the hex bytes.
_LINE_TIMESTAMP = re.compile(r"^\s*[(\[]?(\d{1,2}:\d{2}:\d{2}(?:[.,]\d+)?|\d+\.\d+)[)\]]?(?=[\s:])")
_HEX_PAIR = re.compile(r"[0-9A-Fa-f]{2}")
_HEX_RUN = re.compile(r"(?:[0-9A-Fa-f]{2})+")
#: A ``*`` line (a dump's repeated lines left out) may stand for at most this many bytes.
MAX_SQUEEZED = 1 << 20
#: Longest line a capture may have (characters).
MAX_LINE = 1 << 20
#: File name endings python-can's ``can.LogReader`` reads (also with ``.gz``).
CAN_LOG_SUFFIXES = (".asc", ".blf", ".csv", ".db", ".log", ".mf4", ".trc")


def _hex_words(line: str) -> bytes:
    """Bytes from free-form hex: ``01 06 04 ...``, ``0x01,0x06``, ``010604...``, log prefixes.

    When a line has two-digit tokens, only those count (timestamps and labels of hand-made
    logs are skipped); otherwise runs of hex digits are split into bytes.
    """
    tokens = [t.removeprefix("0x").removeprefix("0X") for t in re.split(r"[\s,;{}]+", line.strip()) if t]
    pairs = [t for t in tokens if _HEX_PAIR.fullmatch(t)]
    chosen = pairs if pairs else [t for t in tokens if _HEX_RUN.fullmatch(t)]
    return b"".join(bytes.fromhex(token) for token in chosen)


def _can_line(line: str) -> tuple[bool, Frame | None]:
    """Whether the line is a CAN log line, and its frame (None: a remote or error frame)."""
    stamp = _CAN_TIMESTAMP.match(line)
    when = (stamp.group(1) or stamp.group(2)) if stamp else None
    match = _CANDUMP.match(line)
    if match:
        return True, Frame(bytes.fromhex("".join(match.group(3).split()))[:int(match.group(2))],
                           int(match.group(1), 16), when)
    match = _PRINTER.match(line)
    if match:
        flags = match.group(2).split()
        if "R" in flags or "E" in flags:
            return True, None
        return True, Frame(bytes.fromhex("".join(match.group(4).split()))[:int(match.group(3))],
                           int(match.group(1), 16), when)
    match = _CANDUMP_LOG.search(line)
    if match:
        if match.group(2) == "R":
            return True, None
        return True, Frame(bytes.fromhex(match.group(3)), int(match.group(1), 16), when)
    return False, None


def _dump_line(line: str) -> tuple[str, bytes] | None:
    """(offset, bytes) of a line of hexdump -C, od, xxd or hexdump, or None."""
    match = _HEXDUMP_C.match(line)
    if match:
        return match.group(1), bytes.fromhex("".join(match.group(2).split()))
    match = _OD_BYTES.match(line)
    if match:
        return match.group(1), bytes.fromhex("".join(match.group(2).split()))
    match = _XXD.match(line)
    if match:
        area = match.group(2).split("  ", 1)[0].split()
        if area and all(_HEX_RUN.fullmatch(group) for group in area):
            return match.group(1), bytes.fromhex("".join(area))
        return None
    match = _WORDS.match(line)
    if match:  # 16-bit words in the machine's (little-endian) order
        words = match.group(2).split()
        return match.group(1), b"".join(bytes.fromhex(w)[::-1] for w in words)
    return None


class CaptureReader:
    """Lines of a capture in, frames out as soon as they are whole (memory stays bounded).

    Serial bytes (hex in any usual spelling, or a dump with offsets) form one stream cut into
    9-byte frames; CAN log lines are frames with their ids.  Offset dumps are read by their
    offsets: a ``*`` line stands for repeats of the line before it, and the closing offset
    line gives the length (``hexdump`` without ``-C`` shows an odd last byte as a whole word),
    so a whole dump never ends in an invented torn frame.
    """

    def __init__(self) -> None:
        self.line_number = 0
        self._stream = bytearray()
        #: The last dump line, kept until the next line says how much of it (and what after
        #: a ``*``) belongs to the data.
        self._held: tuple[str, bytes] | None = None
        self._squeezed = False
        self._base: int | None = None
        self._in_dump = False
        #: Bytes taken out of the stream so far, and (stream offset, timestamp) of the lines
        #: with a timestamp whose bytes are still in it: a frame gets its first byte's.
        self._taken = 0
        self._stamps: list[tuple[int, str]] = []

    def feed(self, line: str) -> Iterator[Frame]:
        self.line_number += 1
        if len(line) > MAX_LINE:
            raise CaptureError(f"line {self.line_number} is longer than {MAX_LINE} characters: not a dump")
        try:
            is_can, frame = _can_line(line)
        except ValueError:  # ``can0 123#0``: an odd number of hex digits (issue 36, N9)
            raise CaptureError(f"line {self.line_number}: a CAN log line whose data is not "
                               "whole bytes of hex") from None
        if is_can:
            if frame is not None:
                yield frame
            return
        stripped = line.strip()
        if stripped == "*" and self._in_dump:
            self._squeezed = True
            return
        dump = _dump_line(line)
        if dump is not None:
            self._dump_data(*dump)
        else:
            end = _OFFSET_ONLY.match(stripped) if self._in_dump else None
            if end is not None:
                self._dump_end(end.group(1))
            elif not _XXD_I_LENGTH.match(line):
                self._release()
                stamp = _LINE_TIMESTAMP.match(line)
                if stamp is not None:
                    self._stamps.append((self._taken + len(self._stream), stamp.group(1)))
                    line = line[stamp.end():]
                self._stream += _hex_words(line.split("//")[0].split("#")[0])
        yield from self._frames()

    def finish(self) -> Iterator[Frame]:
        """The end of the input: what is held goes out, and any rest (a real torn frame)."""
        self._release()
        yield from self._frames()
        if self._stream:
            yield self._take(len(self._stream))

    def _frames(self) -> Iterator[Frame]:
        while len(self._stream) >= FRAME_LENGTH:
            yield self._take(FRAME_LENGTH)

    def _take(self, size: int) -> Frame:
        """The next ``size`` bytes of the stream, with the timestamp of the line they began on."""
        stamps, start = self._stamps, self._taken
        when = None
        while stamps and stamps[0][0] <= start:
            when = stamps[0][1]
            if len(stamps) > 1 and stamps[1][0] <= start:
                stamps.pop(0)
            else:
                break
        frame = Frame(bytes(self._stream[:size]), timestamp=when)
        del self._stream[:size]
        self._taken += size
        return frame

    def _release(self) -> None:
        if self._held is not None:
            self._stream += self._held[1]
            self._held = None
        self._squeezed = False
        self._in_dump = False

    def _offset(self, text: str) -> int:
        return int(text, self._base or 16)

    def _dump_data(self, offset: str, data: bytes) -> None:
        held = self._held
        if held is not None:
            self._choose_base(held, offset)
            gap = self._offset(offset) - self._offset(held[0]) - len(held[1])
            self._stream += held[1]
            if self._squeezed and gap > 0:
                self._repeat(held[1], gap)
        self._held = (offset, data)
        self._squeezed = False
        self._in_dump = True

    def _dump_end(self, offset: str) -> None:
        held = self._held
        if held is not None:
            self._choose_base(held, offset)
            length = self._offset(offset) - self._offset(held[0])
            data = held[1]
            if self._squeezed and length > len(data):
                self._stream += data
                self._repeat(data, length - len(data))
            else:
                self._stream += data[:max(length, 0)] if 0 <= length < len(data) else data
            self._held = None
        self._squeezed = False
        self._in_dump = False
        self._base = None

    def _choose_base(self, held: tuple[str, bytes], offset: str) -> None:
        """Offsets are hex (hexdump, xxd, od -A x), octal (od's default) or decimal (od -A d):
        the base in which consecutive offsets step by the lines' lengths."""
        if self._base is not None:
            return
        size = len(held[1])
        for base in (16, 8, 10):
            try:
                step = int(offset, base) - int(held[0], base)
            except ValueError:
                continue
            if step == size or (self._squeezed and size and step > size and step % size == 0):
                self._base = base
                return

    def _repeat(self, pattern: bytes, count: int) -> None:
        if count > MAX_SQUEEZED:
            raise CaptureError(f"line {self.line_number}: a '*' stands for {count} bytes "
                               f"(more than {MAX_SQUEEZED})")
        if pattern:
            self._stream += (pattern * (count // len(pattern) + 1))[:count]
            # frames are taken out after each line, so at most MAX_SQUEEZED bytes wait here


def text_lines(stream: BinaryIO, name: str, keep_ends: bool = False, kind: str = "a dump",
               first: int = 1) -> Iterator[str]:
    """Lines of UTF-8 text, each at most MAX_LINE characters read (bounded memory); errors
    name ``name`` and the line (numbered from ``first``).  ``keep_ends``: a line keeps its
    newline, so a last line without one shows (a capture cut short)."""
    text = io.TextIOWrapper(stream, encoding="utf-8", errors="strict", newline=None)
    number = first - 1
    while True:
        try:
            line = text.readline(MAX_LINE + 1)
        except UnicodeDecodeError as exc:
            raise CaptureError(f"{name}, line {number + 1}: not UTF-8 text ({exc.reason})") from None
        if not line:
            return
        number += 1
        if len(line) > MAX_LINE:
            raise CaptureError(f"{name}, line {number}: longer than {MAX_LINE} characters: not {kind}")
        yield line if keep_ends else line.rstrip("\n")


def read_capture(lines: Iterable[str]) -> Iterator[Frame]:
    """Frames from the lines of a capture, as they come."""
    reader = CaptureReader()
    for line in lines:
        yield from reader.feed(line)
    yield from reader.finish()


def parse_hex(text: str) -> bytes:
    """The serial bytes of a hex text or dump (``01 06 04 ...``, ``0x01,0x06``, ``hexdump -C``)."""
    return b"".join(frame.data for frame in read_capture(text.splitlines()) if frame.can_id is None)


def parse_capture(text: str) -> list[Frame]:
    """Frames from a capture pasted as text (see :class:`CaptureReader`)."""
    return list(read_capture(text.splitlines()))


def is_can_log(path: str | Path) -> bool:
    """Whether python-can reads this file by its name (``.asc``, ``.blf``, ``.trc.gz``, ...)."""
    suffixes = [s.lower() for s in Path(path).suffixes]
    if suffixes and suffixes[-1] == ".gz":
        suffixes.pop()
    return bool(suffixes) and suffixes[-1] in CAN_LOG_SUFFIXES


def read_can_log(path: str | Path) -> Iterator[Frame]:
    """The data frames of a CAN log, read by python-can's ``can.LogReader`` (imported here,
    only when a log is read): ``.asc``, ``.blf``, ``.csv``, ``.db``, ``.log``, ``.trc``, ``.mf4``
    (with asammdf), and what ``python -m can.logger`` writes."""
    import can

    try:
        reader = can.LogReader(str(path))
    except (OSError, ValueError, ImportError) as exc:
        raise CaptureError(f"{path}: python-can cannot open it: {exc}") from None
    count = 0
    try:
        with reader:
            for message in reader:
                count += 1
                if message.is_error_frame or message.is_remote_frame:
                    continue
                yield Frame(bytes(message.data), message.arbitration_id, f"{message.timestamp:.6f}")
    except CaptureError:
        raise
    except Exception as exc:  # the readers raise what their parsers raise
        raise CaptureError(f"{path}: python-can cannot read message {count + 1}: "
                           f"{type(exc).__name__}: {exc}") from None


class Conversation:
    """Decodes frames in order, pairing each reply with the request before it.

    A dump does not say which frames are requests: a frame is taken as the reply to the
    previous request when its layout fits (checksum, a status code, the same opcode; the 136
    string; the 134 record), as a 138 event when it carries status 128, else as a request.
    """

    def __init__(self, words: Vocabulary | None = None, replies_only: bool = False) -> None:
        self.words = words or vocabulary()
        self.replies_only = replies_only
        self._pending: Request | None = None
        #: A request with a wrong checksum: the module answers it with status 1, opcode 0.
        self._bad_checksum: Request | None = None

    def decode(self, frames: Iterable[Frame]) -> Iterator[Decoded]:
        for frame in frames:
            if frame.can_id is None:
                for decoded in self._serial(frame.data):
                    decoded.timestamp = frame.timestamp
                    yield decoded
            else:
                decoded = self._can(frame.can_id, frame.data)
                decoded.timestamp = frame.timestamp
                yield decoded

    # -- serial ------------------------------------------------------------------------------

    def _serial(self, data: bytes) -> Iterator[Decoded]:
        whole = len(data) - len(data) % FRAME_LENGTH
        for start in range(0, whole, FRAME_LENGTH):
            yield self._serial_frame(data[start:start + FRAME_LENGTH])
        if whole < len(data):
            yield Decoded("incomplete", data[whole:],
                          f"{len(data) - whole} bytes left over (a torn frame)")

    def _serial_frame(self, frame: bytes) -> Decoded:
        valid = checksum(frame[:8]) == frame[8]
        value = to_int32(int.from_bytes(frame[4:8], "big"))
        pending = self._pending
        if pending is not None or self._bad_checksum is not None or self.replies_only:
            special = self._special_reply(frame, valid, pending)
            if special is not None:
                return special
            if valid and frame[2] in _STATUS_NAMES and self._answers(frame[2], frame[3], pending):
                if frame[2] == Status.WRONG_CHECKSUM:
                    pending = self._bad_checksum
                self._pending = self._bad_checksum = None
                reply = Reply(frame[0], frame[1], frame[2], frame[3], value)
                return self._reply("reply", frame, reply, pending,
                                   f"module {reply.module} → host {reply.host}")
        if valid and frame[2] == Status.TARGET_REACHED_EVENT and frame[3] == Opcode.TARGET_REACHED_EVENT:
            reply = Reply(frame[0], frame[1], frame[2], frame[3], value)
            return self._reply("event", frame, reply, None, f"module {reply.module} → host {reply.host}")
        request = Request(frame[0], frame[1], frame[2], frame[3], value)
        text = f"to {request.address}: {self._request_text(request)}"
        if not valid:
            self._pending, self._bad_checksum = None, request
            return Decoded("bad-checksum", frame, f"{text} (checksum {frame[8]:#04x}, should be "
                           f"{checksum(frame[:8]):#04x}: the module answers status 1)",
                           fields=_request_fields(request))
        self._pending, self._bad_checksum = request, None
        return Decoded("request", frame, text, fields=_request_fields(request))

    def _answers(self, status: int, opcode: int, pending: Request | None) -> bool:
        """Whether a reply with this status and opcode can answer what was asked."""
        if status == Status.WRONG_CHECKSUM:
            return opcode == 0 and (self._bad_checksum is not None or self.replies_only)
        return (pending is None and self.replies_only) or (pending is not None and opcode == pending.opcode)

    def _special_reply(self, frame: bytes, valid: bool, pending: Request | None) -> Decoded | None:
        if pending is None:
            return None
        if pending.opcode == Opcode.GET_FIRMWARE_VERSION and pending.type == 0 and is_version_string(frame):
            self._pending = None
            return Decoded("version", frame, f"module → host {frame[0]}: {describe_version_string(frame)}",
                           fields={"version": frame[1:9].decode("ascii")})
        if pending.opcode == Opcode.READ_PROGRAM_MEMORY and valid and not (
                frame[2] in _STATUS_NAMES and frame[3] == Opcode.READ_PROGRAM_MEMORY):
            self._pending = None
            return Decoded("program", frame, f"module → host {frame[0]}: "
                           + describe_program_record(frame, pending.value, self.words))
        return None

    def _reply(self, kind: str, data: bytes, reply: Reply, request: Request | None,
               who: str, can_id: int | None = None) -> Decoded:
        subject = self._request_text(request) if request is not None else opcode_name(reply.opcode)
        fields = {"status": reply.status, "status_name": status_name(reply.status),
                  "opcode": reply.opcode, "value": to_int32(reply.value), "module": reply.module}
        return Decoded(kind, data, f"{who}: {subject} {describe_reply(reply, request)}", can_id, fields)

    def _request_text(self, request: Request) -> str:
        return describe_request(request.opcode, request.type, request.motor, request.value, self.words)

    # -- CAN ---------------------------------------------------------------------------------

    def _can(self, can_id: int, data: bytes) -> Decoded:
        pending = self._pending
        if len(data) >= 7:
            value = to_int32(int.from_bytes(data[3:7], "big"))
            if pending is not None and pending.opcode == Opcode.GET_FIRMWARE_VERSION and pending.type == 0 \
                    and is_version_string(b"\0" + data[:8]) and len(data) == 8:
                self._pending = None
                return Decoded("version", data, f"module → id {can_id:03x}: "
                               f'→ "{data[:8].decode("ascii")}"', can_id)
            fits = data[1] in _STATUS_NAMES and (
                (pending is not None and data[2] == pending.opcode) or self.replies_only)
            if fits or (data[1] == Status.TARGET_REACHED_EVENT and data[2] == Opcode.TARGET_REACHED_EVENT):
                self._pending = None if fits else pending
                reply = Reply(0, data[0], data[1], data[2], value)
                return self._reply("reply" if fits else "event", data, reply, pending if fits else None,
                                   f"module {data[0]} → id {can_id:03x}", can_id)
            opcode, type_, motor = data[0], data[1], data[2]
            value = to_int32(int.from_bytes(data[3:7], "big"))
            request = Request(can_id, opcode, type_, motor, value)
            self._pending = request
            return Decoded("request", data, f"to id {can_id:03x}: {self._request_text(request)}", can_id,
                           _request_fields(request))
        return Decoded("incomplete", data, f"{len(data)} data bytes: not a TMCL frame", can_id)


def _request_fields(request: Request) -> dict[str, Any]:
    return {"address": request.address, "opcode": request.opcode, "mnemonic": opcode_name(request.opcode),
            "type": request.type, "motor": request.motor, "value": request.value}


def decode_text(text: str, words: Vocabulary | None = None, replies_only: bool = False) -> list[Decoded]:
    """Everything in a pasted dump or capture file, decoded in order."""
    return list(Conversation(words, replies_only).decode(read_capture(text.splitlines())))
