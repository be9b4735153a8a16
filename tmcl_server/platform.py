"""The one place that knows the operating system: every POSIX-only call the server makes.

Signal handlers, directory fsync, pseudo-terminals, file locks and terminal queues exist on
Linux and macOS but not (or not the same way) on Windows, where most TMCL-IDE users are.
The rest of the server calls these small functions, so supporting another system changes
this file only.  Nothing here is imported lazily by accident: the POSIX modules are imported
inside the functions that need them.

Test switch: ``TMCL_SIM_EMULATE_WINDOWS=1`` in the environment (read once, at import) makes
:data:`POSIX` false on Linux too, so that a test can run the server down its Windows branches
(tests/tmcl_server/test_windows.py; docs/windows.md says what that emulation covers).
"""

from __future__ import annotations

import contextlib
import errno
import os
import signal
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING

from tmcl_spec.package import doc

if TYPE_CHECKING:
    import asyncio
    import socket

#: prctl option: the calling thread's timer slack in ns (linux/prctl.h).
PR_SET_TIMERSLACK = 29
#: The environment variable that makes this module take its Windows branches on any system.
EMULATE_WINDOWS = "TMCL_SIM_EMULATE_WINDOWS"
#: Whether this is a POSIX system (pseudo-terminals, fcntl, termios, signal handlers).
POSIX = os.name == "posix" and os.environ.get(EMULATE_WINDOWS, "") in ("", "0")


def _windows_alternatives() -> str:
    """What to use instead of the POSIX-only endpoints (said by every refusal)."""
    return f"on Windows use --serial COMx with a com0com pair, or --tcp (see {doc('windows.md')})"


class PlatformUnsupported(RuntimeError):
    """A feature this operating system does not have (the message says which and what to use)."""


def add_stop_handlers(loop: asyncio.AbstractEventLoop, stop: Callable[[], None]) -> bool:
    """Call ``stop`` on SIGINT and SIGTERM; False where the loop cannot watch signals
    (Windows: Ctrl-C then arrives as KeyboardInterrupt, which the caller handles)."""
    try:
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, stop)
    except (NotImplementedError, AttributeError, RuntimeError, ValueError):
        _wake_on_signal(loop)
        return False
    return True


def _wake_on_signal(loop: asyncio.AbstractEventLoop) -> None:
    """Let a signal wake a loop that sleeps in select(): Windows does not interrupt select()
    for Ctrl-C, so Python's handler (asyncio.Runner's, which cancels the main task) would wait
    for the next timer.  The C-level handler writes a byte to a socket the loop watches."""
    import socket

    try:
        receiver, sender = socket.socketpair()
    except OSError:
        return
    receiver.setblocking(False)
    sender.setblocking(False)

    def drain() -> None:
        with contextlib.suppress(OSError):
            receiver.recv(4096)

    try:
        loop.add_reader(receiver.fileno(), drain)
        signal.set_wakeup_fd(sender.fileno(), warn_on_full_buffer=False)
    except (NotImplementedError, OSError, RuntimeError, ValueError):
        # a loop that watches no sockets (Windows' proactor sets its own wake-up socket),
        # or not the main thread: Python's handler runs at the loop's next turn
        with contextlib.suppress(NotImplementedError, OSError, RuntimeError, ValueError):
            loop.remove_reader(receiver.fileno())
        receiver.close()
        sender.close()
        return
    # kept open for as long as the loop lives; closed with it
    _keep_until_closed(loop, (receiver, sender))


def _keep_until_closed(loop: asyncio.AbstractEventLoop,
                       sockets: tuple[socket.socket, socket.socket]) -> None:
    """Undo the wake-up when the loop closes (asyncio.Runner closes it on the way out)."""
    original_close = loop.close

    def close() -> None:
        with contextlib.suppress(ValueError):
            signal.set_wakeup_fd(-1)
        with contextlib.suppress(NotImplementedError, OSError, RuntimeError):
            loop.remove_reader(sockets[0].fileno())
        for sock in sockets:
            sock.close()
        original_close()

    loop.close = close  # type: ignore[method-assign]


def standard_event_loop() -> asyncio.AbstractEventLoop:
    """asyncio's own loop, one that can watch sockets: on Windows the selector loop, not the
    default proactor, because aiomqtt (paho) needs ``add_reader`` (docs/windows.md)."""
    import asyncio

    if POSIX:
        return asyncio.new_event_loop()
    return asyncio.SelectorEventLoop()


def can_watch_descriptors() -> bool:
    """Whether the event loop can watch a serial port's descriptor: any descriptor on POSIX;
    Windows' select() watches sockets only, so a port there is read by a thread."""
    return POSIX


def dump_stacks_on_signal() -> None:
    """``kill -USR1 PID`` prints every thread's Python stack to standard error (POSIX only)."""
    import faulthandler

    if hasattr(signal, "SIGUSR1"):
        # standard error may be no file (an embedding program, a test capturing it)
        with contextlib.suppress(OSError, ValueError, RuntimeError):
            faulthandler.register(signal.SIGUSR1, all_threads=True)


def fsync_directory(directory: os.PathLike[str] | str) -> None:
    """Make a rename in ``directory`` durable.  POSIX needs the directory itself flushed;
    Windows cannot open a directory, and its rename (MoveFileEx) is journaled by NTFS.  Where
    the directory cannot be opened (Windows, or no read permission on it) the file's own
    flush and the rename, both done, stand: the store is in place, so it is not failed."""
    if not POSIX:
        return
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def open_no_follow(path: os.PathLike[str] | str, flags: int, mode: int = 0o644) -> int:
    """``os.open`` that never follows a symbolic link planted at the path's last component
    (issue 36, N5: a lock file, a trace or an EEPROM journal in a shared folder): POSIX has
    ``O_NOFOLLOW``; Windows has none, so a path that is a link (or a junction) is refused
    before it is opened, and creating a link there needs a privilege an attacker lacks.
    A link raises OSError ELOOP naming the path."""
    if POSIX and hasattr(os, "O_NOFOLLOW"):
        try:
            return os.open(path, flags | os.O_NOFOLLOW | getattr(os, "O_CLOEXEC", 0), mode)
        except OSError as exc:
            if exc.errno != errno.ELOOP:
                raise
    elif not (os.path.islink(path) or _is_junction(path)):
        return os.open(path, flags | getattr(os, "O_BINARY", 0) | getattr(os, "O_NOINHERIT", 0),
                       mode)
    raise OSError(errno.ELOOP, "is a symbolic link: refusing to follow it", os.fspath(path))


def _is_junction(path: os.PathLike[str] | str) -> bool:
    is_junction = getattr(os.path, "isjunction", None)  # Python 3.12+
    return bool(is_junction and is_junction(path))


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


def require_pseudo_terminals() -> None:
    """Raise PlatformUnsupported (one line: what is missing, what to use instead) where this
    system has no pseudo-terminals: Windows, or a Python without pty, tty and fcntl."""
    needs = "a pseudo-terminal needs a POSIX system (Linux, macOS)"
    if not POSIX or not hasattr(os, "openpty"):
        raise PlatformUnsupported(f"{needs}; {_windows_alternatives()}")
    try:
        import fcntl  # noqa: F401  (the link lock)
        import tty  # noqa: F401
    except ImportError as exc:
        raise PlatformUnsupported(f"{needs}, and this Python has no module {exc.name}; "
                                  f"{_windows_alternatives()}") from None


def open_raw_pty() -> tuple[int, int, str]:
    """A new pseudo-terminal in raw mode: (master, slave, the slave's device path); the
    master does not block."""
    require_pseudo_terminals()
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
