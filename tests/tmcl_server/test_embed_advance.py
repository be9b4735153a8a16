"""``SimulatorThread.advance(s, wait=False)`` from the test's thread owes the time and
returns at once; the loop applies it before anything else reaches the simulation
(tmcl_server/embed.py; issue 33, item 6: each call used to wait for a hand-off to the loop's
thread, which the default still does where a transport could carry a frame, and not where
none can)."""

from __future__ import annotations

import socket
import threading

import pytest

from interpreter.assembler import assemble
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_reply
from tmcl_spec.commands import Opcode

MS = 1_000_000


def _blocked(sim: SimulatorThread) -> tuple[threading.Event, threading.Event]:
    """Hold the simulator's loop until the first event is set; the second is set when the
    loop is free again (or the hold timed out: the test failed)."""
    release, freed = threading.Event(), threading.Event()

    def hold() -> None:
        release.wait(timeout=5)
        freed.set()

    assert sim._loop is not None
    sim._loop.call_soon_threadsafe(hold)
    return release, freed


def _start_program(sim: SimulatorThread, source: str) -> None:
    """Download ``source`` to module 1 and run it (on the simulator's thread)."""
    def load() -> None:
        module = sim.simulation.modules[0]
        for ins in [(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0), *assemble(source).instructions,
                    (Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0), (Opcode.RUN_APPLICATION, 0, 0, 0)]:
            module.execute(Request(1, *ins))

    sim.call(load)


def test_advance_returns_without_waiting_for_the_loop() -> None:
    """A hundred 1 ms steps while the loop is busy with something else return before the loop
    is free (they used to wait for it, one hand-off each); the next call sees all of them."""
    with SimulatorThread(clock="virtual") as sim:
        release, freed = _blocked(sim)
        for _ in range(100):
            sim.advance(0.001, wait=False)
        assert not freed.is_set()  # every call returned while the loop was held
        release.set()
        assert sim.call(lambda: sim.simulation.now_ns) == 100 * MS


def test_without_a_transport_the_default_does_not_wait_and_the_stop_applies_what_is_owed(
        tmp_path) -> None:
    """No endpoint, no CAN bus: no frame can be in flight, so advance() owes by default (the
    steps return while the loop is held); with an endpoint it waits as before.  The stop
    applies what is owed: a program's store to the EEPROM in that time is kept."""
    source = "WAIT TICKS, 0, 50\nSGP 0, 2, 7\nSTGP 0, 2\nSTOP"
    with SimulatorThread(clock="virtual", state_dir=str(tmp_path)) as sim:
        _start_program(sim, source)
        release, freed = _blocked(sim)
        for _ in range(600):
            sim.advance(0.001)
        assert not freed.is_set()  # owed, not waited for
        release.set()
    with SimulatorThread(clock="virtual", state_dir=str(tmp_path)) as again:
        assert again.call(lambda: again.simulation.modules[0].globals[2][0]) == 7
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
        release, freed = _blocked(sim)
        done = threading.Event()
        waiting = threading.Thread(target=lambda: (sim.advance(0.001), done.set()))
        waiting.start()
        assert not done.wait(0.2)  # waits for the held loop: a frame sent before is served first
        release.set()
        waiting.join(timeout=10)
        assert done.is_set()


def test_time_owed_is_applied_before_a_request_and_a_recording_is_read() -> None:
    """A program counting milliseconds (WAIT TICKS, 1 per 10 ms), advanced in 1 ms and odd
    steps: a request over TCP right after sees the count of the whole time, as one call
    would give, and so do the recording's rows."""
    source = "Loop:\nWAIT TICKS, 0, 1\nGGP 0, 2\nCALC ADD, 1\nAGP 0, 2\nJA Loop"
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
        _start_program(sim, source)
        recording = sim.record(0.01, axes=[0])
        for step in [0.001] * 500 + [0.00037] * 1000 + [0.13]:
            sim.advance(step, wait=False)
        host, port = sim.tcp.rsplit(":", 1)
        with socket.create_connection((host, int(port)), timeout=10) as link:
            link.sendall(Request(1, Opcode.GGP, 0, 2, 0).encode())
            reply = b""
            while len(reply) < 9:
                reply += link.recv(9 - len(reply))
        # 1,000 ms of simulated time, a count every 10 ms (plus its instructions' 40 us)
        assert decode_reply(reply).value == 1_000 * MS // (10 * MS + 40_000)
        assert len(recording.rows) == 101
        recording.stop()


def test_advance_refuses_what_it_refused() -> None:
    """Bad input still gets its answer at the call: a real clock, negative time."""
    for wait in (True, False):
        with (SimulatorThread(clock="virtual") as sim,
              pytest.raises(ValueError, match="backwards")):
            sim.advance(-0.001, wait=wait)
        with SimulatorThread(clock="real") as sim, pytest.raises(RuntimeError, match="virtual"):
            sim.advance(0.001, wait=wait)
