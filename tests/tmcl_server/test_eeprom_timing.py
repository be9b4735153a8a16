"""The EEPROM's write time and coalesced file writes (issue 11, item 3; docs/eeprom.md).

A store takes the part's write cycle (``WRITE_TIME_NS``): a TMCL program that stores in a loop
advances at that pace, on every clock.  On a server the program's stores share file writes
(at most one per ``FLUSH_INTERVAL_S``), so a store loop neither floods the disk nor starves
direct mode; a host's own store is on disk before its reply.
"""

from __future__ import annotations

import json
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from interpreter.assembler import assemble
from tests.conftest import RawClient
from tmcl_server.clock import VirtualClock
from tmcl_server.eeprom import FILE_NAME, FLUSH_INTERVAL_S, WRITE_TIME_NS, WRITER, Eeprom
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCM6212
from tmcl_server.protocol import Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import ApplicationStatus, Opcode, Status
from tmcl_spec.parameters import GP

MS = 1_000_000
#: A program that counts in user variable 1 and stores it on every pass.
STORE_LOOP = """
Loop:
    GGP 1, 2
    CALC ADD, 1
    AGP 1, 2
    STGP 1, 2
    JA Loop
"""


def _download(execute, source: str) -> None:
    assert execute(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0).status == Status.OK
    for ins in assemble(source).instructions:
        assert execute(*ins).status == Status.LOADED
    assert execute(Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0).status == Status.OK


def _bench(tmp_path: Path) -> tuple[TMCM6212, Simulation]:
    module = TMCM6212(1, Eeprom(tmp_path / "module-1"))
    return module, Simulation([module], VirtualClock())


def test_n_stores_take_n_write_cycles_on_the_virtual_clock(tmp_path: Path) -> None:
    module, sim = _bench(tmp_path)
    stores = 10
    _download(lambda *a: module.execute(Request(1, *a)),
              "\n".join(f"STGP {n}, 2" for n in range(stores)) + "\nSTOP")
    t0 = sim.now_ns
    assert module.execute(Request(1, Opcode.RUN_APPLICATION, 0, 0, 0)).status == Status.OK
    status = lambda: module.read_global(GP.APPLICATION_STATUS, 0)  # noqa: E731
    sim.advance_to_ns(t0 + stores * WRITE_TIME_NS - MS // 10)
    assert status() == ApplicationStatus.RUN  # still storing: the tenth write is not over
    sim.advance_to_ns(t0 + stores * WRITE_TIME_NS + MS // 10)
    assert status() == ApplicationStatus.STOP
    assert module.program.interpreter.time_ns - t0 == stores * WRITE_TIME_NS + 10_000  # + STOP


def test_a_store_loop_runs_at_the_pace_of_the_part(tmp_path: Path) -> None:
    module, sim = _bench(tmp_path)
    _download(lambda *a: module.execute(Request(1, *a)), STORE_LOOP)
    stores = module.eeprom.stores
    module.execute(Request(1, Opcode.RUN_APPLICATION, 0, 0, 0))
    sim.advance(1.0)
    passes = module.globals[2][1]
    pass_ns = WRITE_TIME_NS + 4 * 10_000  # the store's write cycle and four instructions
    assert passes == pytest.approx(1e9 / pass_ns, abs=1)
    assert module.eeprom.stores - stores == passes
    assert Eeprom(tmp_path / "module-1").get("user_variables", 1) in (passes, passes - 1)


def test_on_a_server_stores_go_to_the_journal_and_snapshots_are_paced(tmp_path: Path) -> None:
    """With a scheduler (a server's loop), every store (a program's or a host's) is one line
    in the journal at once (a fresh Eeprom replays it), and the whole file is written at most
    once per FLUSH_INTERVAL_S, by the snapshot thread, which then empties the old journal."""
    later: list[tuple[float, Callable[[], None]]] = []
    eeprom = Eeprom(tmp_path)
    eeprom.start_journal(lambda delay, callback: later.append((delay, callback)))
    on_disk = lambda: Eeprom(tmp_path).get("user_variables", 1)  # noqa: E731
    eeprom.put("user_variables", 1, 1)
    assert on_disk() == 1 and not (tmp_path / FILE_NAME).exists()  # in the journal
    for value in range(2, 50):
        eeprom.put("user_variables", 1, value)
    assert on_disk() == 49 and eeprom.file_writes == 0
    assert len(later) == 1 and 0 <= later[0][0] <= FLUSH_INTERVAL_S
    later.pop()[1]()  # the timer hands the image to the thread
    assert WRITER.wait(10)
    assert json.loads((tmp_path / FILE_NAME).read_text())["user_variables"]["1"] == 49
    assert eeprom.file_writes == 1
    eeprom.put("user_variables", 2, 7)
    assert on_disk() == 49 and Eeprom(tmp_path).get("user_variables", 2) == 7
    assert len(later) == 1 and 0 < later[0][0] <= FLUSH_INTERVAL_S  # paced from the last one
    eeprom.flush()  # the server stops: the last snapshot, and no journal left behind
    assert sorted(p.name for p in tmp_path.iterdir()) == [FILE_NAME]
    assert json.loads((tmp_path / FILE_NAME).read_text())["user_variables"] == {"1": 49, "2": 7}
    assert eeprom.stores == 50


def test_the_event_loop_creates_renames_and_syncs_no_file_for_a_store(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 36, item 3: creating, renaming and syncing a file wait for the file system's
    journal (tens of ms on a loaded disk); on a server none of it happens on the event loop's
    thread any more (the code before created the temporary file and renamed it there, before
    each host store's reply)."""
    import os
    import tempfile
    import threading

    calls: list[tuple[str, str]] = []

    def spy(name: str, real: Callable[..., object]) -> Callable[..., object]:
        def wrapped(*args: object, **kwargs: object) -> object:
            calls.append((name, threading.current_thread().name))
            return real(*args, **kwargs)
        return wrapped

    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], state_dir=str(tmp_path)) as sim:
        loop_thread = sim.call(lambda: threading.current_thread().name)
        for name, module in (("mkstemp", tempfile), ("replace", os), ("fsync", os)):
            monkeypatch.setattr(module, name, spy(name, getattr(module, name)))
        client = RawClient(sim.tcp)
        try:
            for value in range(20):
                assert client.request(1, Opcode.SGP, 7, 2, value).status == Status.OK
                assert client.request(1, Opcode.STGP, 7, 2).status == Status.OK
                assert client.request(1, Opcode.SAP, 4, 0, 1000 + value).status == Status.OK
                assert client.request(1, Opcode.STAP, 4, 0).status == Status.OK
            assert sim.call(lambda: WRITER.wait(10))
        finally:
            client.close()
        on_loop = [name for name, thread in calls if thread == loop_thread]
        assert calls and not on_loop, calls
    monkeypatch.undo()
    assert Eeprom(tmp_path / "module-1").get("user_variables", 7) == 19


@pytest.mark.exclusive
def test_a_store_loop_does_not_starve_direct_mode_on_a_real_clock(tmp_path: Path) -> None:
    """A STGP loop on a server with a state directory and a real clock: a host's GAP is
    answered within a few ms, the file is written a bounded number of times per second, and
    the program counts at the pace of the part."""
    with SimulatorThread(tcp=["127.0.0.1:0"], clock="real", state_dir=str(tmp_path)) as sim:
        client = RawClient(sim.tcp)
        try:
            _download(lambda *a: client.request(1, *a), STORE_LOOP)
            eeprom = sim.module(1).eeprom
            assert client.request(1, Opcode.RUN_APPLICATION).status == Status.OK
            start, writes0 = time.monotonic(), eeprom.file_writes
            latencies = []
            while time.monotonic() - start < 1.5:
                sent = time.perf_counter()
                reply = client.request(1, Opcode.GAP, 4, 0)
                latencies.append(time.perf_counter() - sent)
                assert reply.status == Status.OK
            elapsed = time.monotonic() - start
            writes = eeprom.file_writes - writes0
            passes = client.request(1, Opcode.GGP, 1, 2).value
        finally:
            client.close()
    p50 = statistics.median(latencies)
    assert p50 < 0.020, f"GAP median {p50 * 1e3:.1f} ms under a store loop"
    assert writes <= elapsed / FLUSH_INTERVAL_S + 2, f"{writes} file writes in {elapsed:.2f} s"
    assert 0 < passes <= (elapsed + 0.5) * 1e9 / WRITE_TIME_NS  # no faster than the part
    assert (tmp_path / "module-1" / FILE_NAME).exists()
    assert Eeprom(tmp_path / "module-1").get("user_variables", 1) >= passes  # flushed at stop


def test_kill_9_during_a_store_loop_leaves_a_valid_file_old_or_new(tmp_path: Path) -> None:
    """A server process whose program stores a counter in a loop (coalesced writes) is killed
    with SIGKILL at random instants, five times on the same state directory: every time the
    file is valid and the counter on disk never goes back (each value old or new), and a
    SIGTERM at the end writes what was pending."""
    import random
    import signal

    from tests.helpers.processes import ServerProcess

    rng = random.Random(11)
    state = tmp_path / "state"
    seen = 0
    for run in range(6):
        server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state))
        client = RawClient(server.endpoints["tcp"][0])
        counted = seen
        try:
            if run == 0:
                _download(lambda *a, c=client: c.request(1, *a), STORE_LOOP)
            assert client.request(1, Opcode.GGP, 1, 2).value == seen  # restored at power-up
            assert client.request(1, Opcode.RUN_APPLICATION).status == Status.OK
            deadline = time.monotonic() + rng.uniform(0.05, 0.4)
            while time.monotonic() < deadline:  # the program runs meanwhile
                counted = client.request(1, Opcode.GGP, 1, 2).value
        finally:
            client.close()
        last = run == 5
        server.stop(signal.SIGTERM if last else signal.SIGKILL)
        eeprom = Eeprom(state / "module-1")  # what the next start-up reads
        assert eeprom.problem is None
        stored = eeprom.get("user_variables", 1, 0)
        # old or new: never torn, never back in time, never ahead of what the program counted
        # (it goes on for a moment between the last GGP and the kill: 5 ms per pass)
        assert seen <= stored <= counted + 100
        if last:
            assert stored >= counted  # SIGTERM flushed the pending store
        seen = stored


def test_a_slow_disk_holds_up_no_host_on_a_server(tmp_path: Path,
                                                  monkeypatch: pytest.MonkeyPatch) -> None:
    """Issue 27, item 9: an fsync of 300 ms (a loaded disk) used to hold the event loop, so
    every host waited behind a store.  On a server the store is in the journal before its
    reply and the snapshots (with their fsyncs) run beside the loop; the shutdown waits for
    them."""
    import os

    real_fsync = os.fsync
    synced: list[float] = []

    def slow_fsync(fd: int) -> None:
        time.sleep(0.3)
        real_fsync(fd)
        synced.append(time.monotonic())

    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], state_dir=str(tmp_path)) as sim:
        monkeypatch.setattr(os, "fsync", slow_fsync)
        storer, other = RawClient(sim.tcp), RawClient(sim.tcp)
        try:
            for value in range(5):
                began = time.monotonic()
                assert storer.request(1, Opcode.SGP, 7, 2, value).status == Status.OK
                assert storer.request(1, Opcode.STGP, 7, 2).status == Status.OK
                stored = time.monotonic() - began
                began = time.monotonic()
                assert other.request(1, Opcode.GAP, 4, 0).status == Status.OK
                assert stored < 0.25 and time.monotonic() - began < 0.25
                # on disk before the reply: what the next start-up reads
                assert Eeprom(tmp_path / "module-1").get("user_variables", 7) == value
        finally:
            storer.close()
            other.close()
    assert synced and WRITER.wait(0)  # the shutdown waited for every snapshot
    monkeypatch.undo()
    assert Eeprom(tmp_path / "module-1").get("user_variables", 7) == 4
