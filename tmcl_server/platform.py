"""The one place that knows the operating system: every POSIX-only call the server makes.

Signal handlers, directory fsync, pseudo-terminals, file locks and terminal queues exist on
Linux and macOS but not (or not the same way) on Windows, where most TMCL-IDE users are.
The rest of the server calls these small functions, so supporting another system changes
this file only.  Nothing here is imported lazily by accident: the POSIX modules are imported
inside the functions that need them.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import asyncio

#: prctl option: the calling thread's timer slack in ns (linux/prctl.h).
PR_SET_TIMERSLACK = 29
#: Whether this is a POSIX system (pseudo-terminals, fcntl, termios, signal handlers).
POSIX = os.name == "posix"


class PlatformUnsupported(RuntimeError):
    """A feature this operating system does not have (the message says which and what to use)."""


def add_stop_handlers(loop: asyncio.AbstractEventLoop, stop: Callable[[], None]) -> bool:
    """Call ``stop`` on SIGINT and SIGTERM; False where the loop cannot watch signals
    (Windows: Ctrl-C then arrives as KeyboardInterrupt, which the caller handles)."""
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop)
    except (NotImplementedError, AttributeError, RuntimeError, ValueError):
        return False
    return True


def dump_stacks_on_signal() -> None:
    """``kill -USR1 PID`` prints every thread's Python stack to standard error (POSIX only)."""
    import faulthandler

    if hasattr(signal, "SIGUSR1"):
        # standard error may be no file (an embedding program, a test capturing it)
        with contextlib.suppress(OSError, ValueError, RuntimeError):
            faulthandler.register(signal.SIGUSR1, all_threads=True)


def fsync_directory(directory: os.PathLike[str] | str) -> None:
    """Make a rename in ``directory`` durable.  POSIX needs the directory itself flushed;
    Windows cannot open a directory, and its rename (MoveFileEx) is journaled by NTFS."""
    if not POSIX:
        return
    fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def bytes_waiting(fd: int) -> int:
    """Bytes the kernel holds for reading on ``fd`` (a socket, a pty master, a tty): 0 if it
    cannot tell (then a torn frame is judged by the pause alone)."""
    try:
        import fcntl
        import termios

        return int.from_bytes(fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"), sys.byteorder,
                              signed=True)
    except (ImportError, OSError, ValueError):
        return 0


def open_raw_pty() -> tuple[int, int, str]:
    """A new pseudo-terminal in raw mode: (master, slave, the slave's device path); the
    master does not block."""
    if not POSIX:
        raise PlatformUnsupported("--pty needs a POSIX system (Linux, macOS); on Windows use "
                                  "--serial COMx with a com0com pair, or --tcp")
    import tty

    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    return master, slave, os.ttyname(slave)


def lock_exclusively(fd: int) -> None:
    """Hold an exclusive lock on the open file ``fd``; BlockingIOError if another process
    holds it."""
    import fcntl

    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)


def discard_input(fd: int) -> None:
    """Drop what waits unread in a terminal's input queue (nothing where there is none)."""
    with contextlib.suppress(ImportError, OSError):
        import termios

        with contextlib.suppress(termios.error):
            termios.tcflush(fd, termios.TCIFLUSH)


def descriptor_limit() -> int | None:
    """The process's soft limit on open descriptors, None if unlimited or unknown."""
    try:
        import resource
    except ImportError:
        return None
    soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    return None if soft == resource.RLIM_INFINITY else soft


def tight_timer_slack() -> None:
    """Linux lets a sleeping thread wake up to 50 µs late to save power (its timer slack); the
    wire thread asks for 1 µs.  Elsewhere, or if refused, the default stays."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_TIMERSLACK, 1000, 0, 0, 0)
    except (OSError, AttributeError, TypeError):
        pass
