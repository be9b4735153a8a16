"""A pty link: a stable path (``/tmp/ttyTMCL0``) pointing at a pseudo-terminal, and the lock
that keeps a second program from taking over a link a live one serves.

Used by the server's ``--pty`` (tmcl_server/transports/pty.py) and by ``tmcl proxy
--listen-pty`` (tmcl_server/tool/proxy.py): the client loads nothing of the server, so this
lives apart from the transport.  A lock file beside the link (``.NAME.lock``, held with
``flock`` while the program runs) names the holder; the kernel drops the lock when its holder
dies, so a killed program leaves nothing that blocks the next one.  The POSIX calls themselves
are in tmcl_server/platform.py.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from pathlib import Path

from tmcl_server.platform import lock_exclusively, open_no_follow


class LinkInUseError(FileExistsError):
    """Another live program serves the pty link."""


def replace_symlink(target: str, link: Path) -> None:
    """Point ``link`` at ``target`` atomically; refuse to clobber anything but a symlink.

    The directory must exist: a mistyped path is reported, not created.
    """
    if link.exists() and not link.is_symlink():
        raise FileExistsError(f"{link} exists and is not a symlink; not replacing it")
    if not link.parent.is_dir():
        raise FileNotFoundError(f"cannot create the pty link {link}: directory {link.parent} "
                                "does not exist")
    tmp = link.with_name(f".{link.name}.{os.getpid()}.tmp")
    tmp.unlink(missing_ok=True)
    os.symlink(target, tmp)
    os.replace(tmp, link)


def remove_link(link: Path, device: str | None) -> None:
    """Remove ``link`` if it still points at our ``device`` (not at a successor's)."""
    with contextlib.suppress(OSError):
        if device is not None and link.is_symlink() and os.readlink(link) == device:
            link.unlink()


class LinkLock:
    """An exclusive claim on a pty link path, held while the program serves it."""

    def __init__(self, link: Path, holder: str = "tmcl-server") -> None:
        self.path = link.with_name(f".{link.name}.lock")
        #: What the refusal calls the other holder ("another tmcl-server").
        self.holder = holder
        self._fd: int | None = None

    def acquire(self, link: Path) -> None:
        if not link.parent.is_dir():
            raise FileNotFoundError(f"cannot create the pty link {link}: directory "
                                    f"{link.parent} does not exist")
        while True:
            fd = open_no_follow(self.path, os.O_RDWR | os.O_CREAT)  # N5: a planted link
            if not stat.S_ISREG(os.fstat(fd).st_mode):  # a FIFO or device planted there
                os.close(fd)
                raise OSError(errno.EEXIST, "is not a regular file: refusing it as the lock",
                              str(self.path))
            try:
                lock_exclusively(fd)
            except BlockingIOError:
                owner = os.read(fd, 32).decode(errors="replace").strip() or "?"
                os.close(fd)
                raise LinkInUseError(
                    f"{link} is already served by another {self.holder} (pid {owner}, lock "
                    f"{self.path}); stop it or choose another path") from None
            # The previous holder may have removed the file between our open and our lock:
            # then the lock is on a file nobody else sees, so take the new one instead.
            with contextlib.suppress(FileNotFoundError):
                if os.fstat(fd).st_ino == os.stat(self.path).st_ino:
                    break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            self.path.unlink()  # while still locked, so nobody holds a lock on a removed file
        os.close(self._fd)
        self._fd = None
