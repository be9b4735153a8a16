"""Windows' constraints, emulated on Linux for a child process (tests/tmcl_server/test_windows.py).

Put this directory first on PYTHONPATH and Python imports it at start-up (``site`` runs
``sitecustomize``).  What it takes away, as Windows lacks it:

* the modules ``pty``, ``fcntl``, ``termios``, ``tty``, ``resource`` and ``uvloop``: importing
  one raises ModuleNotFoundError (``importlib.util.find_spec`` raises it too);
* signal handlers on the event loop: ``add_signal_handler`` raises NotImplementedError, so
  Ctrl-C (SIGINT) arrives as Python's KeyboardInterrupt, as on Windows;
* readers and writers on anything but a socket (Windows' select() watches sockets only);
* ``os.open`` on a directory: PermissionError, as Windows refuses to open one;
* ``signal.SIGUSR1`` and the other POSIX-only signals.

``TMCL_SIM_EMULATE_WINDOWS=1`` (read by tmcl_server/platform.py) also sends the server down its
Windows branches; without it the constraints alone apply (os.name stays "posix").  pyserial is
imported before ``fcntl`` goes away when TMCL_SIM_EMULATE_PYSERIAL=1: on Windows its own win32
backend loads, which needs none of the POSIX modules.
"""

from __future__ import annotations

import asyncio
import errno
import importlib.abc
import os
import signal
import stat
import sys

ABSENT = frozenset({"pty", "fcntl", "termios", "tty", "resource", "uvloop"})

if os.environ.get("TMCL_SIM_EMULATE_PYSERIAL") == "1":
    import serial  # noqa: F401  (stands in for its win32 backend)


class _Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name: str, path: object = None, target: object = None) -> None:
        if name.partition(".")[0] in ABSENT:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None


for _name in [n for n in sys.modules if n.partition(".")[0] in ABSENT]:
    del sys.modules[_name]
sys.meta_path.insert(0, _Absent())


def _no_signal_handlers(self: object, sig: int, *args: object) -> None:
    raise NotImplementedError


def _sockets_only(original):  # type: ignore[no-untyped-def]
    def watch(self, fd, callback, *args):  # type: ignore[no-untyped-def]
        number = fd if isinstance(fd, int) else fd.fileno()
        if not stat.S_ISSOCK(os.fstat(number).st_mode):
            raise OSError(errno.ENOTSOCK, "select() on Windows watches sockets only")
        return original(self, fd, callback, *args)
    return watch


_loop_class = asyncio.SelectorEventLoop
_loop_class.add_signal_handler = _no_signal_handlers  # type: ignore[method-assign]
_loop_class.remove_signal_handler = _no_signal_handlers  # type: ignore[method-assign]
_loop_class.add_reader = _sockets_only(_loop_class.add_reader)  # type: ignore[method-assign]
_loop_class.add_writer = _sockets_only(_loop_class.add_writer)  # type: ignore[method-assign]

_os_open = os.open


def _open_no_directory(path, flags, mode=0o777, *, dir_fd=None):  # type: ignore[no-untyped-def]
    if dir_fd is None and os.path.isdir(path):
        raise PermissionError(errno.EACCES, "Permission denied", path)
    return _os_open(path, flags, mode, dir_fd=dir_fd)


os.open = _open_no_directory

for _signal in ("SIGUSR1", "SIGUSR2", "SIGHUP", "SIGQUIT", "SIGALRM", "SIGCHLD", "SIGPIPE"):
    if hasattr(signal, _signal):
        delattr(signal, _signal)
