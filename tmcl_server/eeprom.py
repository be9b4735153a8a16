"""The module's non-volatile memory: one JSON file per module, written atomically.

Every store is written atomically (write a temporary file, fsync, rename over the old file,
fsync the directory), so a crash at any instant leaves either the old or the new state on disk.
A store from a host command is in the file before the reply; stores a TMCL program makes in a
loop are coalesced when a server lends a timer (:meth:`Eeprom.coalesce`): at most one file write
per :data:`FLUSH_INTERVAL_S` (docs/eeprom.md, "Write time and coalescing").  On a server the two
fsyncs run in a thread of their own (:class:`_Syncer`) right after the rename: the event loop,
and every other host, never waits for the disk (an fsync took 20 ms here, over 100 ms on a
loaded disk: the stalls of the million-frame fuzz).
A file that cannot be read is never overwritten: the module runs on factory defaults with
persistence switched off and says so (docs/eeprom.md).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tmcl_server.platform import fsync_directory

log = logging.getLogger(__name__)

FORMAT_NAME = "tmcl-sim-eeprom"
FORMAT_VERSION = 1
FILE_NAME = "eeprom.json"
#: Name of the file being written before it is renamed over FILE_NAME.
TEMPORARY_PREFIX, TEMPORARY_SUFFIX = ".eeprom-", ".tmp"

#: Sections of the file; each maps a decimal key to a JSON value.
SECTIONS = ("globals", "user_variables", "coordinates", "axis_parameters", "program")
#: Simulated time one store takes (an EEPROM write cycle, docs/eeprom.md): a TMCL program's
#: store instruction lasts this long, so a store loop cannot outrun the part.
WRITE_TIME_NS = 5_000_000
#: While coalescing, stores within this many seconds of the last file write share one write.
FLUSH_INTERVAL_S = 0.1


class _Syncer:
    """Makes renamed files durable (fsync the file, then its directory) in a daemon thread of
    its own, so the thread that wrote them goes on at once.  Requests for one path coalesce;
    :meth:`wait` blocks until everything asked for is synced (a server's shutdown)."""

    def __init__(self) -> None:
        self._pending: dict[Path, None] = {}
        self._busy = 0
        self._condition = threading.Condition()
        self._thread: threading.Thread | None = None
        #: Paths whose last sync failed (logged once until one succeeds).
        self._failing: set[Path] = set()

    def request(self, path: Path) -> None:
        with self._condition:
            self._pending[path] = None
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="eeprom-sync", daemon=True)
                self._thread.start()
            self._condition.notify()

    def wait(self, timeout: float = 30.0) -> bool:
        with self._condition:
            return self._condition.wait_for(lambda: not self._pending and not self._busy, timeout)

    def _run(self) -> None:
        while True:
            with self._condition:
                self._condition.wait_for(lambda: bool(self._pending))
                path = next(iter(self._pending))
                del self._pending[path]
                self._busy += 1
            try:
                self._sync(path)
            finally:
                with self._condition:
                    self._busy -= 1
                    self._condition.notify_all()

    def _sync(self, path: Path) -> None:
        try:
            fd = os.open(path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            fsync_directory(path.parent)
        except OSError as exc:
            if path not in self._failing:
                self._failing.add(path)
                log.error("EEPROM file %s: cannot make the write durable (%s); it is in the "
                          "file, a power loss may lose it", path, exc)
            return
        self._failing.discard(path)


#: The one syncer every module's EEPROM on a server shares.
SYNCER = _Syncer()


class EepromCorrupt(RuntimeError):
    """The state file exists but cannot be used."""


class EepromWriteError(OSError):
    """A store could not be written to disk (read-only or full state directory): the command
    that stored answers status 5, the value stays in the RAM image (docs/eeprom.md)."""


class Eeprom:
    """Sectioned key/value memory, persisted to ``directory/eeprom.json`` when a directory is set."""

    def __init__(self, directory: str | os.PathLike[str] | None = None) -> None:
        self.path: Path | None = Path(directory) / FILE_NAME if directory is not None else None
        self._data: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
        #: Set when the file on disk was unusable; persistence is then off for this run.
        self.problem: str | None = None
        #: Store operations so far (each one write cycle of the part, whatever it changed).
        self.stores = 0
        #: Writes of the file so far (fewer than stores while a program's stores coalesce).
        self.file_writes = 0
        #: Set while a TMCL program's command runs: its stores may be coalesced.
        self.deferring = False
        self._schedule: Callable[[float, Callable[[], None]], object] | None = None
        self._clock: Callable[[], float] = time.monotonic
        self._dirty = False  # a coalesced store is not on disk yet
        self._last_write = float("-inf")
        #: The last write failed (logged once until a write succeeds again).
        self.write_failing = False
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._remove_torn_writes(self.path.parent)
            try:
                self._data = self._load(self.path)
            except EepromCorrupt as exc:
                self.problem = str(exc)
                self._warn()

    @staticmethod
    def _remove_torn_writes(directory: Path) -> None:
        """Delete temporary files a crash left mid-write (never renamed, so never the state).

        A state directory belongs to one server: no other process can be writing them.
        """
        for leftover in directory.glob(f"{TEMPORARY_PREFIX}*{TEMPORARY_SUFFIX}"):
            try:
                leftover.unlink()
            except OSError as exc:
                log.warning("cannot remove %s left by an interrupted write: %s", leftover, exc)

    @property
    def persistent(self) -> bool:
        return self.path is not None and self.problem is None

    @staticmethod
    def _load(path: Path) -> dict[str, dict[str, Any]]:
        if not path.exists():
            return {s: {} for s in SECTIONS}
        try:
            raw = json.loads(path.read_bytes())
        except (OSError, ValueError, RecursionError) as exc:
            raise EepromCorrupt(f"EEPROM file {path} is unreadable ({exc})") from exc
        if not isinstance(raw, dict) or raw.get("format") != FORMAT_NAME:
            raise EepromCorrupt(f"EEPROM file {path} is not a {FORMAT_NAME} file")
        version = raw.get("version")
        if version != FORMAT_VERSION:
            raise EepromCorrupt(f"EEPROM file {path} has format version {version!r}; "
                                f"this simulator reads version {FORMAT_VERSION}")
        unknown = sorted(set(raw) - {"format", "version", *SECTIONS})
        if unknown:
            raise EepromCorrupt(f"EEPROM file {path}: field {unknown[0]!r}: not a field of "
                                f"version {FORMAT_VERSION}")
        data = {s: raw.get(s, {}) for s in SECTIONS}
        for section, value in data.items():
            if not isinstance(value, dict):
                raise EepromCorrupt(f"EEPROM file {path}: field {section!r}: expected an object, "
                                    f"found {type(value).__name__}")
        return data

    def sections(self) -> dict[str, dict[str, Any]]:
        """The image as loaded (read only), for checking it against a module type."""
        return self._data

    def reject(self, reason: str) -> None:
        """The loaded image is unusable (``reason`` names the field): factory defaults, the
        file left as it is, nothing saved this run."""
        self.problem = f"EEPROM file {self.path}: {reason}"
        self._data = {s: {} for s in SECTIONS}
        self._warn()

    def _warn(self) -> None:
        log.warning("%s; starting from factory defaults, the file is left untouched and "
                    "nothing is saved this run", self.problem)

    def _save(self) -> None:
        if not self.persistent:
            return
        try:
            self._write()
        except OSError as exc:
            self._write_failed(exc)
        else:
            if self.write_failing:
                self.write_failing = False
                log.warning("EEPROM file %s: writing works again", self.path)

    def _write_failed(self, exc: OSError) -> None:
        """Log the first of a run of failed writes (one line, no traceback) and raise."""
        if not self.write_failing:
            self.write_failing = True
            log.error("EEPROM file %s: cannot write (%s); commands that store answer status 5 "
                      "until it can be written again", self.path, exc)
        raise EepromWriteError(exc.errno, f"cannot write {self.path}: {exc}") from exc

    def _write(self) -> None:
        """Write the whole image atomically (temporary file, fsync, rename, fsync directory)."""
        assert self.path is not None
        document = {"format": FORMAT_NAME, "version": FORMAT_VERSION, **self._data}
        payload = json.dumps(document, indent=1, sort_keys=True).encode()
        directory = self.path.parent
        import tempfile  # only when something is stored

        fd, tmp = tempfile.mkstemp(prefix=TEMPORARY_PREFIX, suffix=TEMPORARY_SUFFIX,
                                   dir=directory)
        in_background = self._schedule is not None  # a server: the loop must not wait
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(payload)
                f.flush()
                if not in_background:
                    os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        if in_background:
            SYNCER.request(self.path)
        else:
            fsync_directory(directory)

    # -- write scheduling ---------------------------------------------------------------------

    def coalesce(self, schedule: Callable[[float, Callable[[], None]], object],
                 clock: Callable[[], float] | None = None) -> None:
        """Coalesce program stores: ``schedule(delay_s, callback)`` runs a callback later (the
        server's event loop), ``clock()`` tells the seconds the interval is measured in (the
        wall's monotonic clock unless a test gives its own); :meth:`flush` must run before the
        process ends."""
        self._schedule = schedule
        self._clock = clock or time.monotonic

    def _persist(self) -> None:
        """A store happened: write the file now, or once the flush interval is over when a
        program stores in quick succession (the file stays atomic either way)."""
        self.stores += 1
        if self._schedule is not None and self.deferring and self.persistent:
            wait = self._last_write + FLUSH_INTERVAL_S - self._clock()
            if wait > 0 or self._dirty:
                if not self._dirty:
                    self._dirty = True
                    self._schedule(wait, self._flush_later)
                return
        self._write_now()

    def _write_now(self) -> None:
        self._dirty = False
        if self.persistent:
            self.file_writes += 1
        if self._schedule is not None:
            self._last_write = self._clock()
        self._save()

    def flush(self) -> None:
        """Write a coalesced store now (the timer, and shutdown)."""
        if self._dirty:
            self._write_now()

    def wait_durable(self, timeout: float = 30.0) -> bool:
        """Block until what was written is synced to disk (a server's shutdown)."""
        return SYNCER.wait(timeout)

    def _flush_later(self) -> None:
        """The timer's flush: no command waits for it, so a failure is only logged (by
        _write_failed, once per run of failures); the next store retries."""
        with contextlib.suppress(OSError):
            self.flush()

    @property
    def pending(self) -> bool:
        """A coalesced store waits for its file write."""
        return self._dirty

    # -- access -------------------------------------------------------------------------------

    def get(self, section: str, key: int | str, default: Any = None) -> Any:
        return self._data[section].get(str(key), default)

    def items(self, section: str) -> list[tuple[str, Any]]:
        return list(self._data[section].items())

    def put(self, section: str, key: int | str, value: Any) -> None:
        self.put_many(section, {key: value})

    def put_many(self, section: str, values: dict[Any, Any]) -> None:
        """Store several values with a single atomic write."""
        changed = False
        target = self._data[section]
        for key, value in values.items():
            if target.get(str(key)) != value:
                target[str(key)] = value
                changed = True
        if changed or self.write_failing:  # a failed write is retried, not reported as done
            self._persist()
        else:
            self.stores += 1  # the part writes the same value again

    def replace_section(self, section: str, values: dict[Any, Any]) -> None:
        self._data[section] = {str(k): v for k, v in values.items()}
        self._persist()

    def erase(self) -> None:
        """Factory reset: forget everything stored (command 137)."""
        self._data = {s: {} for s in SECTIONS}
        self._persist()
