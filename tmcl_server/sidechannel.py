"""What runs beside the modules (the trace, the recorder, the MQTT bridge's events, the
dashboard) must never stop them answering: a :class:`SideChannel` turns its first failure
into one warning and stops itself, and a :class:`RotatingFile` keeps a file under a size
limit (docs/observe.md, "When the disk is full").

Both are called from inside a request (the recorder samples while the clock catches up for
one; the trace notes each exchange), so neither may raise into it.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO, TypeVar

from tmcl_server.platform import open_no_follow

log = logging.getLogger("tmcl_server.sidechannel")

F = TypeVar("F", bound=Callable[..., Any])
#: The suffix the previous file gets when a file is rotated (one is kept).
ROTATED_SUFFIX = ".1"


class SideChannel:
    """One channel on the side.  :meth:`fail` (or an exception in a :meth:`guard`-ed call)
    logs one warning naming the channel and the cause, marks it stopped and calls
    ``on_stop`` once; afterwards its guarded calls do nothing."""

    def __init__(self, name: str, on_stop: Callable[[], None] | None = None) -> None:
        self.name = name
        self.on_stop = on_stop
        self.stopped = False
        #: Why it stopped (the warning's text), for tests and status pages.
        self.reason: str | None = None

    def fail(self, exc: BaseException, doing: str = "") -> None:
        if self.stopped:
            return
        self.stopped = True
        cause = (exc.strerror if isinstance(exc, OSError) and exc.strerror
                 else f"{type(exc).__name__}: {exc}")
        self.reason = f"{self.name} stopped{f' ({doing})' if doing else ''}: {cause}"
        log.warning("%s; the modules go on without it", self.reason)
        if self.on_stop is not None:
            try:
                self.on_stop()
            except Exception as stop_exc:  # stopping must not fail the caller either
                log.debug("%s: stopping failed: %s", self.name, stop_exc)

    def guard(self, fn: F, doing: str = "") -> F:
        """``fn`` such that an exception stops this channel instead of reaching the caller."""
        def guarded(*args: Any, **kwargs: Any) -> Any:
            if self.stopped:
                return None
            try:
                return fn(*args, **kwargs)
            except Exception as exc:
                self.fail(exc, doing)
                return None
        return guarded  # type: ignore[return-value]


def _create(path: Path) -> TextIO:
    """A new (or emptied) text file, never through a symbolic link planted at its name (issue
    36, N5: ``--trace``/``--record`` in a shared folder overwrote the link's target); the
    system's own links under /dev (``/dev/stdout``) are followed."""
    if path.parts[:2] == ("/", "dev"):
        return open(path, "w", encoding="utf-8", newline="")
    fd = open_no_follow(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    return open(fd, "w", encoding="utf-8", newline="")


class RotatingFile:
    """A text file written through one :class:`SideChannel`: past ``max_bytes`` it becomes
    ``FILE.1`` (replacing an older one) and a fresh ``FILE`` starts, headed by ``header()``
    (a CSV header); a write that fails (a full disk, a file size limit, an I/O error) stops
    the channel, and later writes are dropped.  ``max_bytes`` 0: no limit.  Also stands in
    for standard error (``path`` None): no rotation there."""

    def __init__(self, path: str | os.PathLike[str] | None, channel: SideChannel, max_bytes: int = 0,
                 stream: TextIO | None = None) -> None:
        self.path = None if path is None else Path(path)
        self.channel = channel
        self.max_bytes = max_bytes if path is not None else 0
        #: Called after a rotation; its text starts the new file.
        self.header: Callable[[], str] | None = None
        self.rotations = 0
        self.size = 0
        self._own = stream is None
        if stream is None:
            assert self.path is not None
            stream = _create(self.path)
        self._stream: TextIO | None = stream

    @property
    def closed(self) -> bool:
        return self._stream is None

    def write(self, text: str) -> int:
        stream = self._stream
        if stream is None or self.channel.stopped:
            return 0
        size = len(text) if text.isascii() else len(text.encode("utf-8"))
        try:
            if self.max_bytes and self.size and self.size + size > self.max_bytes:
                stream = self._rotate(stream)
            stream.write(text)
        except (OSError, ValueError) as exc:
            self._failed(exc, "writing")
            return 0
        self.size += size
        return len(text)

    def flush(self) -> None:
        if self._stream is None or self.channel.stopped:
            return
        try:
            self._stream.flush()
        except (OSError, ValueError) as exc:
            self._failed(exc, "writing")

    def _rotate(self, stream: TextIO) -> TextIO:
        assert self.path is not None
        stream.close()
        os.replace(self.path, self.path.with_name(self.path.name + ROTATED_SUFFIX))
        self._stream = stream = _create(self.path)
        self.rotations += 1
        self.size = 0
        if self.header is not None:
            head = self.header()
            stream.write(head)
            self.size = len(head.encode("utf-8"))
        return stream

    def _failed(self, exc: BaseException, doing: str) -> None:
        where = f"{doing} {self.path}" if self.path is not None else doing
        self.close()
        self.channel.fail(exc, where)

    def close(self) -> None:
        stream, self._stream = self._stream, None
        if stream is None or not self._own:
            return
        with contextlib.suppress(OSError, ValueError):  # what the buffer held is lost; said so
            stream.close()
