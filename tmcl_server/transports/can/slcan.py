"""A virtual SLCAN (Lawicel) USB-CAN adapter on a pseudo-terminal, plugged into the simulated bus.

Hosts open the link (``--slcan-pty /tmp/ttySLCAN0``) like a CANable or CANUSB dongle:
python-can's ``slcan`` interface, pytrinamic's ``slcan_tmcl``, slcand, ... The adapter speaks
the ASCII protocol: ``Sn``/``sxxyy`` bit rate, ``O``/``L`` open (listen-only), ``C`` close,
``t``/``T``/``r``/``R`` transmit (answered ``z``/``Z``), ``F`` status, ``V``/``N`` version
and serial number, ``Z`` time stamps; CR acknowledges, BEL refuses.  While open, every frame
another party puts on the bus arrives as a ``t``/``T``/``r``/``R`` line.
"""

from __future__ import annotations

import asyncio
import logging
import re
import time
from collections import Counter
from collections.abc import Callable
from typing import ClassVar

import can

from tmcl_server.platform import discard_input
from tmcl_server.simulation import Simulation
from tmcl_server.transports.base import ByteSession, TransportHost
from tmcl_server.transports.can.bus import SimulatedCanBus
from tmcl_server.transports.pty import PtyTransport

log = logging.getLogger(__name__)

OK = b"\r"
ERROR = b"\a"
#: Longest command line kept (``T`` + 8 id + 1 dlc + 16 data = 26); longer lines are junk.
MAX_LINE = 64
#: Lawicel ``Sn`` codes.
BITRATES = {0: 10_000, 1: 20_000, 2: 50_000, 3: 100_000, 4: 125_000, 5: 250_000,
            6: 500_000, 7: 800_000, 8: 1_000_000}
HARDWARE_VERSION = b"V1013"
SERIAL_NUMBER = b"NTMCL"
#: ``F`` status bit 3: a frame for the host was lost (nobody read the port).
STATUS_DATA_OVERRUN = 0x08

#: ``t``/``T``/``r``/``R`` lines: id, one-digit DLC, then two hex digits per data byte.
_TRANSMIT = {
    ord("t"): (re.compile(rb"t([0-9A-Fa-f]{3})([0-8])([0-9A-Fa-f]*)"), False, False),
    ord("T"): (re.compile(rb"T([0-9A-Fa-f]{8})([0-8])([0-9A-Fa-f]*)"), True, False),
    ord("r"): (re.compile(rb"r([0-9A-Fa-f]{3})([0-8])"), False, True),
    ord("R"): (re.compile(rb"R([0-9A-Fa-f]{8})([0-8])"), True, True),
}


def encode_slcan_frame(frame: can.Message, timestamp_ms: int | None = None) -> bytes | None:
    """The line an adapter prints for a received frame (None: not representable in SLCAN)."""
    if frame.is_error_frame or frame.is_fd:
        return None
    if frame.is_extended_id:
        head = f"{'R' if frame.is_remote_frame else 'T'}{frame.arbitration_id:08X}{frame.dlc}"
    else:
        head = f"{'r' if frame.is_remote_frame else 't'}{frame.arbitration_id:03X}{frame.dlc}"
    body = "" if frame.is_remote_frame else frame.data.hex().upper()
    stamp = "" if timestamp_ms is None else f"{timestamp_ms % 60_000:04X}"
    return f"{head}{body}{stamp}\r".encode("ascii")


def decode_slcan_transmit(line: bytes) -> can.Message | None:
    """Parse a ``t``/``T``/``r``/``R`` command; None if it is malformed."""
    spec = _TRANSMIT.get(line[0]) if line else None
    if spec is None:
        return None
    pattern, extended, remote = spec
    match = pattern.fullmatch(line)
    if match is None:
        return None
    can_id, dlc = int(match[1], 16), int(match[2])
    if can_id > (0x1FFF_FFFF if extended else 0x7FF):
        return None
    if not remote and len(match[3]) != 2 * dlc:
        return None  # two hex digits per data byte, as many bytes as the DLC says
    data = b"" if remote else bytes.fromhex(match[3].decode("ascii"))
    return can.Message(arbitration_id=can_id, is_extended_id=extended, is_remote_frame=remote,
                       dlc=dlc, data=data)


class SlcanSession:
    """One adapter: Lawicel commands in, answers and received frames out."""

    def __init__(self, bus: SimulatedCanBus, write: Callable[[bytes], None],
                 discard_output: Callable[[], None]) -> None:
        self.bus = bus
        self._write_out = write
        #: While a write from the host is handled, what goes back is collected here and
        #: written at once: one write per request (the ack and the reply together).
        self._batch: list[bytes] | None = None
        self._discard_output = discard_output
        self._line = bytearray()
        self._junk = False  # the current line overflowed: answer BEL at its end
        self.open = False
        self.listen_only = False
        self.bitrate = BITRATES[8]
        self.timestamps = False
        self.status = 0
        self.stats: Counter[str] = Counter()
        bus.attach(self)

    # -- host -> adapter ----------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        if self._batch is None:
            self._write_out(data)
        else:
            self._batch.append(data)

    def feed(self, data: bytes) -> None:
        self._batch = []
        try:
            self._feed(data)
        finally:
            out, self._batch = self._batch, None
            if out:
                self._write_out(b"".join(out))

    def _feed(self, data: bytes) -> None:
        if (not self._line and not self._junk and len(data) <= MAX_LINE
                and data.find(b"\r") == len(data) - 1 and b"\n" not in data):
            # one whole command, the usual case of a lockstep host: no splitting
            if answer := self._command(data[:-1]):
                self._write(answer)
            return
        for chunk in re.split(rb"(\r)", data.replace(b"\n", b"")):
            if chunk == b"\r":
                line, self._line = bytes(self._line), bytearray()
                if self._junk:
                    self._junk = False
                    self.stats["bad_commands"] += 1
                    self._write(ERROR)
                elif answer := self._command(line):
                    self._write(answer)
            elif chunk and not self._junk:
                self._line += chunk
                if len(self._line) > MAX_LINE:
                    self._line.clear()
                    self._junk = True

    def _command(self, line: bytes) -> bytes:
        if line[:1] in (b"t", b"T", b"r", b"R"):
            return self._transmit(line)
        answer = self._control(line)
        if answer == ERROR:
            self.stats["bad_commands"] += 1
        return answer

    def _transmit(self, line: bytes) -> bytes:
        frame = decode_slcan_transmit(line)
        if frame is None or not self.open or self.listen_only:
            self.stats["bad_commands"] += 1
            return ERROR
        self.stats["transmitted"] += 1
        # The adapter acknowledges once the frame is queued, before any answer can arrive.
        self._write(b"Z\r" if frame.is_extended_id else b"z\r")
        self.bus.send(frame, self)
        return b""

    def _control(self, line: bytes) -> bytes:
        """Any command but a frame: its handler in ``_CONTROL`` checks the argument's shape
        (ERROR when it is wrong, or for an unknown command); an empty line is OK."""
        if not line:
            return OK
        handler = self._CONTROL.get(line[:1])
        return handler(self, line[:1], line[1:]) if handler is not None else ERROR

    def _open_channel(self, command: bytes, argument: bytes) -> bytes:
        """``O`` (open) or ``L`` (open listening only)."""
        if argument or self.open:
            return ERROR
        self._discard_output()  # whatever a previous host left unread is stale now
        self.open, self.listen_only = True, command == b"L"
        return OK

    def _close_channel(self, command: bytes, argument: bytes) -> bytes:
        if argument:
            return ERROR
        self._discard_output()
        self.open = self.listen_only = False
        return OK

    def _set_bitrate(self, command: bytes, argument: bytes) -> bytes:
        """``S0``..``S8``, only while closed."""
        if len(argument) != 1 or argument[0] - ord("0") not in BITRATES or self.open:
            return ERROR
        self.bitrate = BITRATES[argument[0] - ord("0")]
        return OK

    def _set_btr(self, command: bytes, argument: bytes) -> bytes:
        """``sXXYY``: a bit timing register pair, taken (and ignored) only while closed."""
        return OK if re.fullmatch(rb"[0-9A-Fa-f]{4}", argument) and not self.open else ERROR

    def _read_flags(self, command: bytes, argument: bytes) -> bytes:
        """``F``: the status flags since the last read (open only), then cleared."""
        if argument or not self.open:
            return ERROR
        status, self.status = self.status, 0
        return f"F{status:02X}\r".encode("ascii")

    def _version(self, command: bytes, argument: bytes) -> bytes:
        return ERROR if argument else HARDWARE_VERSION + OK

    def _serial_number(self, command: bytes, argument: bytes) -> bytes:
        return ERROR if argument else SERIAL_NUMBER + OK

    def _set_timestamps(self, command: bytes, argument: bytes) -> bytes:
        if argument not in (b"0", b"1"):
            return ERROR
        self.timestamps = argument == b"1"
        return OK

    def _set_filter(self, command: bytes, argument: bytes) -> bytes:
        """``M``/``m``: acceptance filters are accepted but every frame passes."""
        return OK if re.fullmatch(rb"[0-9A-Fa-f]{8}", argument) else ERROR

    def _set_mode(self, command: bytes, argument: bytes) -> bytes:
        """``X``, ``Q``, ``W`` 0..2: auto poll, auto start, filter mode; accepted, no effect."""
        return OK if len(argument) == 1 and argument in b"012" else ERROR

    #: Command letter -> its handler (called with the session, the letter, the argument).
    _CONTROL: ClassVar[dict[bytes, Callable[[SlcanSession, bytes, bytes], bytes]]] = {
        b"O": _open_channel, b"L": _open_channel, b"C": _close_channel, b"S": _set_bitrate,
        b"s": _set_btr, b"F": _read_flags, b"V": _version, b"N": _serial_number,
        b"Z": _set_timestamps, b"M": _set_filter, b"m": _set_filter, b"X": _set_mode,
        b"Q": _set_mode, b"W": _set_mode,
    }

    # -- bus -> host --------------------------------------------------------------------------

    def on_frame(self, frame: can.Message) -> None:
        if not self.open:
            return
        stamp = time.monotonic_ns() // 1_000_000 if self.timestamps else None
        line = encode_slcan_frame(frame, stamp)
        if line is not None:
            self.stats["received"] += 1
            self._write(line)

    def overrun(self) -> None:
        self.status |= STATUS_DATA_OVERRUN
        self.stats["overruns"] += 1

    def close(self) -> None:
        self.open = False
        self.bus.detach(self)


class SlcanPtyTransport(PtyTransport):
    kind = "slcan"

    def __init__(self, simulation: Simulation, link: str, bus: SimulatedCanBus) -> None:
        super().__init__(simulation, link)
        self.bus = bus
        self.session: SlcanSession | None = None
        self._warned_full = False

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> SlcanPtyTransport:
        return cls(host.simulation, argument, host.can_bus())

    def _make_session(self, loop: asyncio.AbstractEventLoop) -> ByteSession:
        self.session = SlcanSession(self.bus, self._write, self._discard_output)
        return self.session

    def _discard_output(self) -> None:
        self._set_pending(b"")
        if self._slave is not None:
            discard_input(self._slave)

    def _delivered(self) -> None:
        self._warned_full = False

    def _lost(self, size: int) -> None:
        """Like a USB adapter whose host stopped reading: frames are lost, the F flags say so."""
        if self.session is not None:
            self.session.overrun()
        if not self._warned_full:
            self._warned_full = True
            log.warning("slcan %s: nobody reads the port, frames dropped", self.link)

