"""A progress bar for uploads and long waits, drawn on stderr only when it is a terminal."""

from __future__ import annotations

import sys
import time
from typing import TextIO

_WIDTH = 30
_SPINNER = "|/-\\"


class Progress:
    """``label [#####.....] 12/40`` (or a spinner with the elapsed time when the total is unknown).

    It draws nothing when the stream is not a terminal (pipes, CI logs, tests), so a script's
    output stays clean.
    """

    def __init__(self, label: str, total: int | None = None, stream: TextIO | None = None,
                 enabled: bool | None = None) -> None:
        self.label = label
        self.total = total
        self.stream = stream or sys.stderr
        self.enabled = self.stream.isatty() if enabled is None else enabled
        self.done = 0
        self._start = time.monotonic()
        self._drawn = 0.0

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def advance(self, steps: int = 1, note: str = "") -> None:
        self.done += steps
        self.draw(note)

    def draw(self, note: str = "") -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._drawn < 0.05 and (self.total is None or self.done < self.total):
            return  # at most 20 redraws a second
        self._drawn = now
        if self.total:
            filled = min(_WIDTH, _WIDTH * self.done // self.total)
            bar = f"[{'#' * filled}{'.' * (_WIDTH - filled)}] {self.done}/{self.total}"
        else:
            bar = f"{_SPINNER[int(now * 8) % 4]} {now - self._start:5.1f} s"
        self.stream.write(f"\r{self.label} {bar} {note}\x1b[K")
        self.stream.flush()

    def close(self) -> None:
        if self.enabled:
            self.stream.write("\r\x1b[K")
            self.stream.flush()
