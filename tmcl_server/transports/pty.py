"""A virtual serial port: a pseudo-terminal in raw mode behind a stable symlink.

Hosts open the link (for example ``/tmp/ttyTMCL0``) exactly like the module's USB port or an
RS-485 adapter: pytrinamic's ``serial_tmcl``, minicom, or any pyserial program.  ``--pty
PATH[,mode=usb|rs485]`` chooses how frames are addressed (docs/protocol.md).  A lock file
beside the link (``.NAME.lock``, held with ``flock`` while the server runs) keeps a second
server from taking over a link that a live one serves; the kernel drops the lock when its
holder dies, so a killed server leaves nothing that blocks the next one (the link and its lock:
tmcl_server/ptylink.py, shared with ``tmcl proxy --listen-pty``).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

from tmcl_server.platform import bytes_waiting, open_raw_pty, require_pseudo_terminals
from tmcl_server.ptylink import LinkInUseError, LinkLock, remove_link, replace_symlink
from tmcl_server.simulation import Simulation
from tmcl_server.transports.base import (
    ByteSession,
    LinkMode,
    StreamSession,
    Transport,
    TransportHost,
    link_mode,
    split_endpoint_options,
)

if TYPE_CHECKING:
    from tmcl_server.transports.wire import WireTiming

log = logging.getLogger(__name__)

__all__ = ["LinkInUseError", "PtyTransport"]


#: Output held back while the pty is full (only after a write it took in part).
MAX_PENDING = 4096


class PtyTransport(Transport):
    kind = "pty"

    def __init__(self, simulation: Simulation, link: str, mode: LinkMode = LinkMode.RS485,
                 wire: WireTiming | None = None, baud: int | None = None) -> None:
        self.simulation = simulation
        self.link = Path(link)
        self.mode = mode
        #: ``--wire-timing``: bytes at ``baud`` (default: GP 65), see transports/wire.py.
        self.wire = wire
        self.baud = baud
        self.device: str | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._session: ByteSession | None = None
        self._lock = LinkLock(self.link)
        #: The rest of output the pty took only in part: written when it has room again, so
        #: the host never reads a cut reply (at most MAX_PENDING bytes more are queued).
        self._pending = bytearray()

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> PtyTransport:
        """``PATH[,mode=usb|rs485][,baud=N]``; without a mode: USB for one module, RS-485 for
        several; ``baud`` paces the line with ``--wire-timing`` (default: GP 65)."""
        from tmcl_server.transports.wire import WireTiming, parse_baud

        path, options = split_endpoint_options(argument, ("mode", "baud"))
        return cls(host.simulation, path, link_mode(host.simulation, options, f"--pty {path}"),
                   WireTiming.of(host), parse_baud(options.get("baud"), f"--pty {path}"))

    async def start(self) -> list[str]:
        loop = asyncio.get_running_loop()
        require_pseudo_terminals()  # before the lock file: nothing is left behind on Windows
        self._lock.acquire(self.link)
        # Keep our own slave descriptor open: the master then never sees EIO/hang-up when a
        # client closes the port, so the next client finds the port just as it was.
        master, slave, self.device = open_raw_pty()
        self._master, self._slave = master, slave
        replace_symlink(self.device, self.link)
        self._session = self._make_session(loop)
        loop.add_reader(master, self._on_readable)
        return [str(self.link)]

    def _make_session(self, loop: asyncio.AbstractEventLoop) -> ByteSession:
        """What speaks on the port: 9-byte TMCL here, SLCAN in the CAN adapter (slcan.py)."""
        if self.wire is not None:
            from tmcl_server.transports.wire import LineRate, PacedStreamSession

            first = self.simulation.modules[0] if self.simulation.modules else None
            return PacedStreamSession(self.simulation, self._write, loop, self.mode, f"pty {self.link}",
                                      baud=LineRate.uart(first, self.baud), timing=self.wire)
        return StreamSession(self.simulation, self._write, loop, self.mode, f"pty {self.link}",
                             partial(bytes_waiting, self._master) if self._master is not None else None)

    def _on_readable(self) -> None:
        assert self._master is not None and self._session is not None
        try:
            data = os.read(self._master, 4096)
        except BlockingIOError:
            return
        except OSError as exc:
            if exc.errno != errno.EIO:
                log.warning("pty %s read failed: %s", self.link, exc)
            return
        if data:
            self._session.feed(data)

    def _write(self, data: bytes) -> None:
        """Like a port whose host stopped reading: output is lost in whole writes (whole
        replies or lines), never cut.  What the pty took only in part is finished first when
        it has room, new output queues behind it up to MAX_PENDING bytes, beyond that it is
        dropped."""
        assert self._master is not None
        if self._pending:
            if len(self._pending) + len(data) <= MAX_PENDING:
                self._pending += data
            else:
                self._lost(len(data))
            return
        try:
            written = os.write(self._master, data)
        except BlockingIOError:
            written = 0
        if written == len(data):
            self._delivered()
        elif written == 0:
            self._lost(len(data))
        else:
            self._set_pending(data[written:])  # a cut reply: its rest must follow

    def _delivered(self) -> None:
        """A write went out whole (the SLCAN adapter clears its overrun warning)."""

    def _lost(self, size: int) -> None:
        """Output dropped because nobody reads the port."""
        log.warning("pty %s: nobody reads the port, %d bytes of replies dropped", self.link, size)

    def _set_pending(self, data: bytes | bytearray) -> None:
        loop = asyncio.get_running_loop()
        if data and not self._pending and self._master is not None:
            loop.add_writer(self._master, self._flush_pending)
        elif not data and self._pending and self._master is not None:
            loop.remove_writer(self._master)
        self._pending[:] = data

    def _flush_pending(self) -> None:
        if self._master is None:
            return
        try:
            written = os.write(self._master, self._pending)
        except BlockingIOError:
            return
        except OSError:
            written = len(self._pending)
        self._set_pending(self._pending[written:])

    async def close(self) -> None:
        if self._session is not None:
            self._session.close()
        if self._master is not None and self._pending:
            asyncio.get_running_loop().remove_writer(self._master)
            self._pending.clear()
        if self._master is not None:
            asyncio.get_running_loop().remove_reader(self._master)
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
        remove_link(self.link, self.device)
        self._lock.release()
