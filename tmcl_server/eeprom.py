"""The module's non-volatile memory: one JSON file per module, written atomically.

Without a server every store writes the whole image atomically (a temporary file, fsync,
rename over the old file, fsync the directory), so a crash at any instant leaves either the
old or the new state on disk.  On a server (:meth:`Eeprom.start_journal`) the event loop never
touches the file system for a store beyond one append: each store is one line appended to a
journal file opened at start (``eeprom.journal.0`` / ``.1``), in the operating system's hands
before the reply; a thread of its own (:class:`_SnapshotWriter`) then writes the whole image
as above, at most every :data:`FLUSH_INTERVAL_S`, and empties the journal that image covers.
Creating, renaming and fsyncing files wait for the file system's journal commit (tens of ms
on a loaded disk: the late replies of the million-frame fuzz, issue 36 item 3).  At start the
journals are replayed onto the image (docs/eeprom.md, "On a server: a journal").
A file that cannot be read is never overwritten: the module runs on factory defaults with
persistence switched off and says so (docs/eeprom.md).
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tmcl_server.platform import fsync_directory, open_no_follow

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
#: On a server, the whole image is written (a snapshot) at most this often; the journal
#: holds the stores in between.
FLUSH_INTERVAL_S = 0.1
#: The journal files beside FILE_NAME (on a server).
JOURNAL_NAMES = ("eeprom.journal.0", "eeprom.journal.1")


class _SnapshotWriter:
    """Runs the snapshot jobs the event loop hands it, one at a time, in a daemon thread of
    its own (shared by every module); :meth:`wait` blocks until all are done (shutdown)."""

    def __init__(self) -> None:
        self._jobs: list[Callable[[], None]] = []
        self._busy = 0
        self._condition = threading.Condition()
        self._thread: threading.Thread | None = None

    def submit(self, job: Callable[[], None]) -> None:
        with self._condition:
            self._jobs.append(job)
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="eeprom-snapshots",
                                                daemon=True)
                self._thread.start()
            self._condition.notify()

    def wait(self, timeout: float = 30.0) -> bool:
        with self._condition:
            return self._condition.wait_for(lambda: not self._jobs and not self._busy, timeout)

    def _run(self) -> None:
        while True:
            with self._condition:
                self._condition.wait_for(lambda: bool(self._jobs))
                job = self._jobs.pop(0)
                self._busy += 1
            try:
                job()
            except Exception:  # a bug: the thread must live on for the other modules
                log.exception("EEPROM snapshot failed")
            finally:
                with self._condition:
                    self._busy -= 1
                    self._condition.notify_all()


#: The one snapshot thread every module's EEPROM on a server shares.
WRITER = _SnapshotWriter()


class _Journal:
    """Two append-only files beside ``eeprom.json``.  The event loop appends each store to the
    active one (one ``write`` on a descriptor opened at start: no file is created or renamed);
    a snapshot hand-off makes the other one active, and the snapshot thread empties the old one
    once the snapshot covering it is renamed into place.  Each line carries a sequence number,
    so replay sorts the lines of both files whatever happened in between; replaying a store a
    snapshot already holds changes nothing (every record sets values, replaces a section or
    erases all: the last one wins)."""

    def __init__(self, directory: Path) -> None:
        self.paths = [directory / name for name in JOURNAL_NAMES]
        self.fds: list[int | None] = [None, None]
        #: Bytes in each file (a failed append is cut back to it).
        self.sizes = [0, 0]
        self.active = 0
        self.seq = 0
        #: A failed append may have left part of a line that could not be cut off: the next
        #: line starts on a new line, so replay skips only the torn one.
        self.torn = False

    def open(self) -> None:
        for index, path in enumerate(self.paths):
            if self.fds[index] is None:
                fd = open_no_follow(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT)
                self.fds[index] = fd
                self.sizes[index] = os.fstat(fd).st_size

    def append(self, record: dict[str, Any]) -> None:
        """One store, in the file before this returns (OSError: not written, nothing left)."""
        self.open()
        line = json.dumps({"n": self.seq, **record}, separators=(",", ":")).encode() + b"\n"
        if self.torn:
            line = b"\n" + line
        index = self.active
        fd = self.fds[index]
        assert fd is not None
        try:
            written = 0
            while written < len(line):  # a short write (a file size limit) goes on, and fails
                written += os.write(fd, line[written:])
        except OSError:
            try:
                os.ftruncate(fd, self.sizes[index])
            except OSError:
                self.torn = True
            raise
        self.torn = False
        self.sizes[index] += len(line)
        self.seq += 1

    @property
    def holds_records(self) -> bool:
        return any(self.sizes)

    def swap(self) -> int:
        """Make the other file active (the loop, with no snapshot in flight); the old index."""
        old = self.active
        self.active = 1 - old
        return old

    def empty(self, index: int) -> None:
        """The snapshot thread: the file's stores are in the renamed snapshot."""
        fd = self.fds[index]
        if fd is not None:
            os.ftruncate(fd, 0)
            self.sizes[index] = 0

    def close(self, remove: bool) -> None:
        for index, fd in enumerate(self.fds):
            if fd is not None:
                with contextlib.suppress(OSError):
                    os.close(fd)
                self.fds[index] = None
            if remove:
                with contextlib.suppress(OSError):
                    self.paths[index].unlink()

    @staticmethod
    def replay(directory: Path, data: dict[str, dict[str, Any]]) -> tuple[int, int, int]:
        """Apply the journals' stores onto ``data`` (in place), in sequence order: (records
        applied, lines skipped as torn or malformed, the next sequence number)."""
        records: list[tuple[int, dict[str, Any]]] = []
        skipped = 0
        for name in JOURNAL_NAMES:
            path = directory / name
            try:
                fd = open_no_follow(path, os.O_RDONLY)
            except FileNotFoundError:
                continue
            except OSError as exc:
                raise EepromCorrupt(f"EEPROM journal {path} is unreadable ({exc})") from exc
            with os.fdopen(fd, "rb") as f:
                raw = f.read()
            for line in raw.split(b"\n"):
                if not line.strip():
                    continue
                try:
                    record = json.loads(line)
                    records.append((int(record["n"]), record))
                except (ValueError, TypeError, KeyError, RecursionError):
                    skipped += 1  # a torn line: its store was never answered OK
        records.sort(key=lambda pair: pair[0])
        for _, record in records:
            if not _apply(data, record):
                skipped += 1
        return len(records), skipped, (records[-1][0] + 1 if records else 0)


def _apply(data: dict[str, dict[str, Any]], record: dict[str, Any]) -> bool:
    """One journal record onto the image; False if it is not one we write."""
    op, section, values = record.get("op"), record.get("s"), record.get("v")
    if op == "erase":
        for name in SECTIONS:
            data[name] = {}
        return True
    if section not in SECTIONS or not isinstance(values, dict):
        return False
    if op == "put":
        data[section].update(values)
    elif op == "replace":
        data[section] = dict(values)
    else:
        return False
    return True


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
        #: Writes of the whole file so far (on a server: snapshots, fewer than the stores).
        self.file_writes = 0
        self._schedule: Callable[[float, Callable[[], None]], object] | None = None
        #: On a server: the journal, whether a snapshot is armed or in the thread, and when
        #: the last one was handed off.
        self._journal: _Journal | None = None
        self._snapshot_armed = False
        self._in_flight = False
        self._last_snapshot = float("-inf")
        #: Stores appended since the last snapshot hand-off.
        self._unsaved = 0
        #: The last write failed (logged once until a write succeeds again).
        self.write_failing = False
        #: The last snapshot failed (logged once until one succeeds again).
        self._snapshot_failing = False
        #: Journal records replayed at load (they are in the image; the next start writes them).
        self.replayed = 0
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            if self.path.parent.is_symlink():  # planted in a shared state directory (N5)
                raise OSError(errno.ELOOP, "is a symbolic link: refusing to keep the EEPROM "
                              "through it", str(self.path.parent))
            self._remove_torn_writes(self.path.parent)
            try:
                self._data = self._load(self.path)
                self.replayed, skipped, _ = _Journal.replay(self.path.parent, self._data)
                if skipped:
                    log.warning("EEPROM journal in %s: %d torn or malformed line(s) skipped (a "
                                "store cut by a crash or a full disk, never answered OK)",
                                self.path.parent, skipped)
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

    def _document(self) -> dict[str, Any]:
        return {"format": FORMAT_NAME, "version": FORMAT_VERSION, **self._data}

    def _write(self, document: dict[str, Any] | None = None) -> None:
        """Write the whole image atomically (temporary file, fsync, rename, fsync directory)."""
        assert self.path is not None
        payload = json.dumps(self._document() if document is None else document, indent=1,
                             sort_keys=True).encode()
        directory = self.path.parent
        import tempfile  # only when something is stored

        fd, tmp = tempfile.mkstemp(prefix=TEMPORARY_PREFIX, suffix=TEMPORARY_SUFFIX,
                                   dir=directory)  # O_EXCL and a random name: no planted link
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(payload)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        fsync_directory(directory)

    # -- on a server: the journal and its snapshots -------------------------------------------

    def start_journal(self, schedule: Callable[[float, Callable[[], None]], object]) -> None:
        """A server: stores go to the journal, snapshots to the thread; ``schedule(delay_s,
        callback)`` runs a callback later on the event loop.  :meth:`flush` must run before
        the process ends.  What the journals held at load is written as a snapshot now."""
        self._schedule = schedule
        if not self.persistent:
            return
        assert self.path is not None
        self._journal = _Journal(self.path.parent)
        try:
            self._journal.open()
            if self._journal.holds_records:  # replayed at load: one snapshot, then empty
                self._write()
                self.file_writes += 1
                self._journal.empty(0)
                self._journal.empty(1)
        except OSError as exc:  # a read-only directory: each store tries again, answers 5
            log.debug("EEPROM journal in %s not open yet: %s", self.path.parent, exc)

    def _append(self, record: dict[str, Any]) -> None:
        """A store on a server: in the journal before the reply (status 5 if it cannot be)."""
        assert self._journal is not None
        try:
            self._journal.append(record)
        except OSError as exc:
            self._write_failed(exc)
        if self.write_failing:
            self.write_failing = False
            log.warning("EEPROM file %s: writing works again", self.path)
        self._unsaved += 1
        if not self._snapshot_armed and self._schedule is not None:
            import time

            self._snapshot_armed = True
            self._schedule(max(0.0, self._last_snapshot + FLUSH_INTERVAL_S - time.monotonic()),
                           self._hand_off)

    def _hand_off(self) -> None:
        """The loop's timer: give the snapshot thread the image as it is now, and make the
        other journal active (the thread empties this one once the snapshot is in place)."""

        self._snapshot_armed = False
        journal = self._journal
        if journal is None or not self._unsaved:
            return
        if self._in_flight:  # the last one is still being written: try again later
            self._snapshot_armed = True
            assert self._schedule is not None
            self._schedule(FLUSH_INTERVAL_S, self._hand_off)
            return
        document = self._document_copy()
        old = journal.swap()
        self._unsaved = 0
        self._in_flight = True
        self._last_snapshot = time.monotonic()
        self.file_writes += 1
        WRITER.submit(lambda: self._snapshot(document, old))

    def _document_copy(self) -> dict[str, Any]:
        """The image as it is now, for the thread (values are replaced, never changed in place,
        so two levels of dictionaries are all that can change under it)."""
        return {"format": FORMAT_NAME, "version": FORMAT_VERSION,
                **{name: {key: dict(value) if isinstance(value, dict) else value
                          for key, value in section.items()}
                   for name, section in self._data.items()}}

    def _snapshot(self, document: dict[str, Any], old: int) -> None:
        """The snapshot thread: the whole image written atomically, then the old journal
        emptied.  A failure keeps the journals (a later snapshot or the next start covers
        them) and is logged once per run of failures; no host waits for it."""
        try:
            self._write(document)
            assert self._journal is not None
            self._journal.empty(old)
        except OSError as exc:
            if not self._snapshot_failing:
                self._snapshot_failing = True
                log.error("EEPROM file %s: the snapshot failed (%s); the stores are safe in "
                          "the journal, it is tried again at the next store", self.path, exc)
        else:
            if self._snapshot_failing:
                self._snapshot_failing = False
                log.warning("EEPROM file %s: snapshots work again", self.path)
        finally:
            self._in_flight = False

    def _persist(self, record: dict[str, Any]) -> None:
        """A store happened (``record`` says what, for the journal)."""
        self.stores += 1
        if self._journal is not None:
            self._append(record)
            return
        if self.persistent:
            self.file_writes += 1
        self._save()

    def flush(self) -> None:
        """A server stops: wait for the snapshot in flight, write the last one here, and
        remove the journals it covers (kept if it fails: the next start replays them)."""
        journal = self._journal
        if journal is None:
            return
        WRITER.wait()
        self._journal = None
        remove = not journal.holds_records
        if journal.holds_records:
            try:
                self._write()
                self.file_writes += 1
                remove = True
            except OSError as exc:
                log.error("EEPROM file %s: the last snapshot failed (%s); the journal keeps "
                          "the stores for the next start", self.path, exc)
        journal.close(remove)

    # -- access -------------------------------------------------------------------------------

    def get(self, section: str, key: int | str, default: Any = None) -> Any:
        return self._data[section].get(str(key), default)

    def items(self, section: str) -> list[tuple[str, Any]]:
        return list(self._data[section].items())

    def put(self, section: str, key: int | str, value: Any) -> None:
        self.put_many(section, {key: value})

    def put_many(self, section: str, values: dict[Any, Any]) -> None:
        """Store several values with a single atomic write."""
        changed = {}
        target = self._data[section]
        for key, value in values.items():
            if target.get(str(key)) != value:
                target[str(key)] = value
                changed[str(key)] = value
        if changed or self.write_failing:  # a failed write is retried, not reported as done
            self._persist({"op": "put", "s": section,
                           "v": changed or {str(k): v for k, v in values.items()}})
        else:
            self.stores += 1  # the part writes the same value again

    def replace_section(self, section: str, values: dict[Any, Any]) -> None:
        self._data[section] = {str(k): v for k, v in values.items()}
        self._persist({"op": "replace", "s": section, "v": self._data[section]})

    def erase(self) -> None:
        """Factory reset: forget everything stored (command 137)."""
        self._data = {s: {} for s in SECTIONS}
        self._persist({"op": "erase"})
