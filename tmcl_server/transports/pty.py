"""A virtual serial port: a pseudo-terminal in raw mode behind a stable symlink.

Hosts open the link (for example ``/tmp/ttyTMCL0``) exactly like a USB or RS-485 adapter:
pytrinamic's ``serial_tmcl``, minicom, or any pyserial program.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import os
import tty
from pathlib import Path

from tmcl_server.simulation import Simulation
from tmcl_server.transports.base import ByteSession, StreamSession, Transport

log = logging.getLogger(__name__)


def replace_symlink(target: str, link: Path) -> None:
    """Point ``link`` at ``target`` atomically; refuse to clobber anything but a symlink."""
    if link.exists() and not link.is_symlink():
        raise FileExistsError(f"{link} exists and is not a symlink; not replacing it")
    link.parent.mkdir(parents=True, exist_ok=True)
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    os.symlink(target, tmp)
    os.replace(tmp, link)


class PtyTransport(Transport):
    kind = "pty"

    def __init__(self, simulation: Simulation, link: str) -> None:
        self.simulation = simulation
        self.link = Path(link)
        self.device: str | None = None
        self._master: int | None = None
        self._slave: int | None = None
        self._session: ByteSession | None = None

    async def start(self) -> list[str]:
        loop = asyncio.get_running_loop()
        master, slave = os.openpty()
        # Keep our own slave descriptor open: the master then never sees EIO/hang-up when a
        # client closes the port, so the next client finds the port just as it was.
        tty.setraw(slave)
        os.set_blocking(master, False)
        self._master, self._slave = master, slave
        self.device = os.ttyname(slave)
        replace_symlink(self.device, self.link)
        self._session = self._make_session(loop)
        loop.add_reader(master, self._on_readable)
        return [str(self.link)]

    def _make_session(self, loop: asyncio.AbstractEventLoop) -> ByteSession:
        """What speaks on the port: 9-byte TMCL here, SLCAN in the CAN adapter (slcan.py)."""
        return StreamSession(self.simulation, self._write, loop, f"pty {self.link}")

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
        assert self._master is not None
        try:
            written = os.write(self._master, data)
        except BlockingIOError:
            log.warning("pty %s: nobody reads the port, reply dropped", self.link)
            return
        if written < len(data):
            log.warning("pty %s: output buffer full, %d bytes dropped", self.link,
                        len(data) - written)

    async def close(self) -> None:
        if self._session is not None:
            self._session.close()
        if self._master is not None:
            asyncio.get_running_loop().remove_reader(self._master)
            for fd in (self._master, self._slave):
                if fd is not None:
                    with contextlib.suppress(OSError):
                        os.close(fd)
            self._master = self._slave = None
        with contextlib.suppress(OSError):
            if self.link.is_symlink() and os.readlink(self.link) == self.device:
                self.link.unlink()
