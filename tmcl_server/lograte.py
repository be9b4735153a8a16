"""Rate-limited logging for what a host can trigger at will (docs/robustness.md, item 6).

A host that never reads its pty, floods over-speed ROR commands or opens connections until
the descriptors run out would otherwise make the server write one line (or one traceback) per
frame: megabytes a second.  :class:`RepeatFilter` lets the first record from each call site
through, then at most one every :data:`REPEAT_INTERVAL_S`, which says how many it held back.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

#: At most one record per call site in this many seconds (after the first).
REPEAT_INTERVAL_S = 5.0

#: The loggers of our modules that log what the wire drives (transports, the axes' speed limits).
OWN_WIRE_LOGGERS = (
    "tmcl_server.transports.base",
    "tmcl_server.transports.tcp",
    "tmcl_server.transports.pty",
    "tmcl_server.transports.serial_port",
    "tmcl_server.transports.wire",
    "tmcl_server.transports.can.bus",
    "tmcl_server.transports.can.python_can",
    "tmcl_server.transports.can.slcan",
    "tmcl_server.transports.can.socketcand",
    "tmcl_server.transports.mqtt.bridge",
    "tmcl_server.simulation",
    "tmcl_server.dashboard.web",
    "axes.chips.tmc42x.firmware",
)
#: Libraries' loggers a host can make talk: the loop's own reports ("socket.accept() out of
#: system resource", ...) and aiohttp's about a request or WebSocket message it could not handle
#: (aiohttp/log.py names them).
LIBRARY_LOGGERS = ("asyncio", "aiohttp.server", "aiohttp.web", "aiohttp.websocket")
#: Every logger the filter goes on.
WIRE_LOGGERS: tuple[str, ...] = (*OWN_WIRE_LOGGERS, *LIBRARY_LOGGERS)


class RepeatFilter(logging.Filter):
    """Pass the first record of each call site (logger, level, message template); then hold
    back repeats for ``interval_s`` and let the next one through with a count of those held
    back: ``... (repeated 9,812 times in the last 5.0 s)``.  Repeats that end inside a window
    are not reported (nothing new happened)."""

    def __init__(self, interval_s: float = REPEAT_INTERVAL_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        super().__init__()
        self.interval_s = interval_s
        self._clock = clock
        #: call site -> [start of its window, records held back in it]
        self._sites: dict[tuple[str, int, object], list[float]] = {}

    def filter(self, record: logging.LogRecord) -> bool:
        key = (record.name, record.levelno, record.msg)
        now = self._clock()
        site = self._sites.get(key)
        if site is None:
            if len(self._sites) >= 1024:  # templates are few; a formatted message is a bug
                self._sites.clear()
            self._sites[key] = [now, 0]
            return True
        if now - site[0] < self.interval_s:
            site[1] += 1
            return False
        held, began = int(site[1]), site[0]
        site[0], site[1] = now, 0
        if held:
            record.msg = f"{record.msg} (repeated {held:,} times in the last {now - began:.1f} s)"
        return True

    def reset(self) -> None:
        self._sites.clear()


#: The one filter every wire logger shares.
REPEATS = RepeatFilter()


def limit_repeats(names: tuple[str, ...] = WIRE_LOGGERS, repeat_filter: RepeatFilter = REPEATS) -> None:
    """Put the filter on these loggers (idempotent; loggers exist before their modules load)."""
    for name in names:
        logging.getLogger(name).addFilter(repeat_filter)
