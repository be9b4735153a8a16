"""Capture files: what ``tmcl proxy --capture`` writes and ``tmcl replay`` reads (docs/capture.md).

A capture is JSON lines: a header line (format name, version, the module link, the module's
identity from command 136), then one line per frame as it crossed the proxy, with its monotonic
instant since the capture started, its direction, the host endpoint, the module address and
the raw bytes.  Each line is written and flushed as the frame passes, so a proxy stopped by
Ctrl-C or killed leaves a capture that reads up to its last whole line; a last line cut short
is left out with a note, never an error.

``tmcl replay`` also reads what others capture: python-can's logs (``can.LogReader``: .asc,
.blf, .csv, .log, ...) and the dumps ``tmcl decode`` reads.  Those do not say which frame is a
request; :class:`tmcl_server.decode.Conversation` tells them apart as ``tmcl decode`` does.
Client side: this module loads nothing of the simulator.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any

from tmcl_server.decode import (
    MAX_LINE,
    CaptureError,
    Conversation,
    Frame,
    is_can_log,
    read_can_log,
    read_capture,
    text_lines,
)
from tmcl_spec.numbers import NS_PER_S
from tmcl_spec.package import package_version

#: The ``format`` of a capture's header line.
FORMAT = "tmcl-capture"
#: The version this code writes and the newest it reads.  A reader refuses a newer version
#: (its lines may mean something else) and ignores keys it does not know within its own.
VERSION = 1

#: Frame directions.
REQUEST = "request"
REPLY = "reply"
NO_REPLY = "no-reply"
UNSOLICITED = "unsolicited"
DIRECTIONS = (REQUEST, REPLY, NO_REPLY, UNSOLICITED)


@dataclass(frozen=True, slots=True)
class CapturedFrame:
    """One frame as captured."""

    #: Nanoseconds since the capture started (monotonic); None where the source has no time.
    t_ns: int | None
    direction: str
    #: The host side: ``tcp 127.0.0.1:40522``, ``pty /tmp/ttyHOST``, ``can`` for a CAN log.
    endpoint: str
    #: The module address the request went to (the serial address byte, or the CAN id).
    address: int | None
    data: bytes
    #: Set for CAN frames (the data is then the CAN payload, not a 9-byte frame).
    can_id: int | None = None


@dataclass
class Capture:
    """A capture file opened for reading: the header's facts, then :meth:`frames`."""

    path: Path
    #: What the source is: ``tmcl capture v1``, ``python-can log``, ``hex dump``.
    kind: str
    #: The module link the proxy used (``tcp 10.0.0.5:4001``), where the capture says.
    link: str | None = None
    #: Command 136's answers at the start: ``version`` (``6212V105``), ``module_number``,
    #: ``firmware``, ``type``; None when not asked (``--no-identify``) or not recorded.
    identity: dict[str, Any] | None = None
    #: What the reader left out, one line each (a last line cut short).
    notes: list[str] = field(default_factory=list)
    #: Whether this is a capture of our own format (else a CAN log or a dump).
    own: bool = False

    def frames(self) -> Iterator[CapturedFrame]:
        """The frames in order; each call reads the file again from the start."""
        if not self.own:
            yield from _foreign_frames(self.path, self.kind)
            return
        try:
            stream = self.path.open("rb")
        except OSError as exc:
            raise CaptureError(f"{self.path}: {exc.strerror or exc}") from None
        with stream:
            stream.readline(MAX_LINE + 1)  # the header, read by open_capture
            self.notes.clear()
            yield from self._own_frames(text_lines(stream, str(self.path), keep_ends=True,
                                                   kind="a capture line", first=2))

    def _own_frames(self, lines: Iterator[str]) -> Iterator[CapturedFrame]:
        held: tuple[int, str] | None = None  # a line is judged once we know if it is the last
        for number, line in enumerate(lines, 2):
            if held is not None:
                yield self._frame(*held)
            held = (number, line) if line.strip() else None
        if held is not None:
            number, line = held
            if line.endswith("\n"):
                yield self._frame(number, line)
                return
            try:
                yield self._frame(number, line)
            except CaptureError:
                self.notes.append(f"{self.path}, line {number}: cut short (the capture was "
                                  "stopped while writing it): left out")

    def _frame(self, number: int, line: str) -> CapturedFrame:
        where = f"{self.path}, line {number}"
        try:
            record = json.loads(line)
        except json.JSONDecodeError as exc:
            raise CaptureError(f"{where}: not a JSON line ({exc.msg})") from None
        return _record_frame(record, where)


def _record_frame(record: Any, where: str) -> CapturedFrame:
    if not isinstance(record, dict):
        raise CaptureError(f"{where}: a frame line is a JSON object")
    direction = record.get("dir")
    if direction not in DIRECTIONS:
        raise CaptureError(f"{where}: 'dir' is {direction!r}, not one of {', '.join(DIRECTIONS)}")
    t = record.get("t")
    if not isinstance(t, (int, float)) or isinstance(t, bool) or t < 0:
        raise CaptureError(f"{where}: 't' must be seconds since the start, got {t!r}")
    try:
        data = bytes.fromhex(record.get("bytes", ""))
    except (TypeError, ValueError):
        raise CaptureError(f"{where}: 'bytes' must be hex, got {record.get('bytes')!r}") from None
    address, can_id = record.get("address"), record.get("can_id")
    for name, value in (("address", address), ("can_id", can_id)):
        if value is not None and (not isinstance(value, int) or isinstance(value, bool)):
            raise CaptureError(f"{where}: {name!r} must be a whole number, got {value!r}")
    return CapturedFrame(round(t * NS_PER_S), direction, str(record.get("endpoint", "")),
                         address, data, can_id)


def open_capture(path: str | Path) -> Capture:
    """Open a capture of any kind ``tmcl replay`` reads; CaptureError (one line) if it cannot."""
    path = Path(path)
    first = _first_line(path)
    header = _header(first)
    if header is None and f'"{FORMAT}"' in first:
        raise CaptureError(f"{path}: its header line is cut short (the capture stopped before "
                           "its first frame)")
    if header is None:
        return Capture(path, "python-can log" if is_can_log(path) else "hex dump")
    _check_header(header, path)
    return Capture(path, f"{FORMAT} v{header['version']}", header.get("link"),
                   header.get("identity"), own=True)


def _first_line(path: Path) -> str:
    """The file's first line as text ("" when it is not UTF-8: a binary CAN log, or not a
    capture at all); CaptureError for a file that is missing or cannot be read."""
    if not path.is_file():
        raise CaptureError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    try:
        stream = path.open("r", encoding="utf-8", newline="")
    except OSError as exc:
        raise CaptureError(f"{path}: {exc.strerror or exc}") from None
    try:
        return stream.readline(MAX_LINE + 1)
    except UnicodeDecodeError:
        return ""
    except OSError as exc:
        raise CaptureError(f"{path}: {exc.strerror or exc}") from None
    finally:
        stream.close()


def _header(line: str) -> dict[str, Any] | None:
    if not line.lstrip().startswith("{"):
        return None
    try:
        record = json.loads(line)
    except ValueError:
        return None
    return record if isinstance(record, dict) and record.get("format") == FORMAT else None


def _check_header(header: dict[str, Any], path: Path) -> None:
    version = header.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or version < 1:
        raise CaptureError(f"{path}: the header's version is {version!r}, not a capture version")
    if version > VERSION:
        raise CaptureError(f"{path}: capture version {version}, written by a newer tmcl-sim; "
                           f"this one reads up to version {VERSION}")
    identity = header.get("identity")
    if identity is not None and not isinstance(identity, dict):
        raise CaptureError(f"{path}: the header's identity must be an object or null")


def _foreign_frames(path: Path, kind: str) -> Iterator[CapturedFrame]:
    """A python-can log or a dump: requests and replies told apart as ``tmcl decode`` does."""
    if kind == "python-can log":
        frames: Iterator[Frame] = read_can_log(path)
    else:
        frames = read_capture(_dump_lines(path))
    conversation = Conversation()
    origin: float | None = None
    for frame in frames:
        t_ns, when = None, frame.time  # (parsed from the capture's text at each access)
        if when is not None:
            origin = when if origin is None else origin
            t_ns = round((when - origin) * NS_PER_S)
        for decoded in conversation.decode([frame]):
            direction = _DIRECTION_OF_KIND.get(decoded.kind)
            if direction is None:
                continue  # a torn frame: nothing to replay
            address = decoded.fields.get("address") if direction == REQUEST else None
            if frame.can_id is not None and direction == REQUEST:
                address = frame.can_id
            yield CapturedFrame(t_ns, direction, "can" if frame.can_id is not None else "serial",
                                address, decoded.data, frame.can_id)


_DIRECTION_OF_KIND = {"request": REQUEST, "bad-checksum": REQUEST, "reply": REPLY,
                      "version": REPLY, "program": REPLY, "event": UNSOLICITED}


def _dump_lines(path: Path) -> Iterator[str]:
    with path.open("rb") as stream:
        yield from text_lines(stream, str(path))


class CaptureWriter:
    """Writes a capture as frames pass: one JSON line each, flushed at once (a proxy stopped
    at any moment leaves every frame it forwarded on disk, at most the last line cut short)."""

    def __init__(self, stream: IO[bytes], link: str, identity: dict[str, Any] | None,
                 start_ns: int | None = None) -> None:
        #: Unbuffered: each line is one write to the file, at once.
        self._stream = stream
        self._quoted: dict[str, str] = {}
        #: The monotonic instant ``t`` counts from.
        self.start_ns = time.monotonic_ns() if start_ns is None else start_ns
        header = {"format": FORMAT, "version": VERSION,
                  "created": datetime.now(UTC).isoformat(timespec="seconds"),
                  "clock": "monotonic", "tool": f"tmcl-sim {package_version()}", "link": link,
                  "identity": identity}
        self._write(json.dumps(header) + "\n")

    @classmethod
    def create(cls, path: str | Path, link: str, identity: dict[str, Any] | None) -> CaptureWriter:
        return cls(Path(path).open("wb", buffering=0), link, identity)

    def frame(self, t_ns: int, direction: str, endpoint: str, address: int | None,
              data: bytes = b"") -> None:
        """One frame's line (written by hand: this runs for every frame the proxy forwards)."""
        quoted = self._quoted.get(endpoint)
        if quoted is None:
            if len(self._quoted) >= 1024:  # hosts that connect once each: keep it bounded
                self._quoted.clear()
            quoted = self._quoted[endpoint] = json.dumps(endpoint)
        seconds = (t_ns - self.start_ns) / NS_PER_S
        self._write(f'{{"t": {seconds:.9f}, "dir": "{direction}", "endpoint": {quoted}, '
                    f'"address": {"null" if address is None else address}, '
                    f'"bytes": "{data.hex()}"}}\n')

    def _write(self, line: str) -> None:
        data = line.encode()
        while data:  # an unbuffered file takes it whole; a pipe may take part
            data = data[self._stream.write(data) or 0:]

    def close(self) -> None:
        self._stream.close()
