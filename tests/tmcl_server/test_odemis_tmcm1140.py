"""Odemis' ``TestActuatorAbsEnc`` against a simulated TMCM-1140, replayed on a real pty.

Odemis (``delmic/odemis``) is not installable from PyPI, so its driver cannot run here.  This
file replays, byte for byte, what its ``odemis.driver.tmcm.TMCLController`` sends for that test
class (``src/odemis/driver/test/tmcm_test.py``: ``KWARGS_AENC``: port ``/dev/ttyTMCM*``, one
axis "x", ``ustepsize`` 122e-9 rad, ``abs_encoder=[True]``, no referencing procedure, the
default ``minpower`` 10.8 V) and checks what its code and the test's assertions check:

* the port is found by a glob, opened at 9600 baud 8N1 with a 0.1 s timeout and locked with
  ``flock``; the link is resynchronised with nine zero bytes, which must be answered with one
  9-byte reply (status 2, a valid checksum) whose byte 1 becomes the address of every frame;
* replies are 9 bytes, checksummed, for the command sent, with status 100 or 101;
* the constructor's sequence: 136 type 1 (a known model, using the TMC429's units), GAP 1
  (the axis exists), GIO 8, 1 (at least 10.8 V), GGP 0, 2 (the user configuration header),
  GAP 207, GAP 209 (the position), GAP 4 and 154 (the speed), GAP 5, 154, 153 (acceleration);
* ``moveRel``: GAP 212 (0: no reset of AP 1), MVP REL; ``moveAbs``: MST, GAP 209, GAP 1,
  SAP 1 = AP 209, MVP ABS; then the wait loop (GAP 8, GAP 207, GAP 209 every 0.1 s, MST on
  timeout or cancel), with Odemis' own duration estimate from the 16 MHz TMC429 speed law;
* each inherited test's assertions (``test_simple`` ... ``test_future_callback``), ``setUp``
  (a new controller) and ``tearDown`` (one second, then back to the start, ``terminate``).

Odemis runs moves in a thread and sleeps in wall time; the replay runs them one after the
other on the virtual clock, a sleep being ``sim.advance``, and a move Odemis cancels while
it may already have started is replayed as started (the more demanding case).  Its 0.1 s
read timeout becomes a fail-safe (``WAIT_S``): the answers come at once in simulated time,
but a loaded machine must not fail the replay in wall time.  No Odemis code
is copied: the sequence is read from its source (docs/compatibility.md, "Odemis").
"""

from __future__ import annotations

import glob
import itertools
import math
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import serial

from tmcl_server.embed import SimulatorThread
from tmcl_server.platform import lock_exclusively
from tmcl_spec.commands import Opcode, Status

USTEP = 122e-9  # rad per microstep (KWARGS_AENC)
KNOWN_MODELS = {1140, 3110, 6110, 3214, 6214, 1211}  # Odemis' tested models
USE_INTERNAL_UNIT_429 = {1110, 1140, 3110, 6110}  # speeds in TMC429 register units
TMCL_OK_STATUS = {Status.OK, Status.LOADED}
MINPOWER = 10.8  # V
F_CLK = 16e6  # Odemis' TMC429 clock
#: Odemis reads with a 0.1 s timeout; the simulator answers at once in simulated time, but a
#: loaded machine may take longer in wall time: reads wait up to this (a fail-safe), and the
#: checks for bytes beyond a reply look at what has arrived.
WAIT_S = 5.0


class TMCLError(Exception):
    """A reply with a status outside 100/101 (Odemis raises its own TMCLError)."""


class OdemisCancelled(Exception):
    """The replayed move was cancelled (Odemis' future raises CancelledError)."""


class NoPower(Exception):
    """GIO 8, 1 below ``minpower`` (Odemis raises HwError "... has no power")."""


class MoveTimeout(Exception):
    """The move outlasted twice Odemis' estimate plus one second."""


def estimate_move_duration(distance: float, speed: float, accel: float) -> float:
    """The trapezoid profile Odemis assumes (``odemis.util.driver.estimateMoveDuration``)."""
    if distance > speed ** 2 / accel:
        return distance / speed + speed / accel
    return 2 * math.sqrt(distance / accel)


@dataclass
class Controller:
    """What ``TMCLController(**KWARGS_AENC)`` does on the wire, replayed on the virtual clock."""

    sim: SimulatorThread
    pattern: str
    port: serial.Serial = field(init=False)
    target: int = field(init=False)
    sent: list[tuple[int, int, int, int]] = field(default_factory=list)
    positions: list[float] = field(default_factory=list)  # every position update, rad

    # -- the link -------------------------------------------------------------------------

    def open(self) -> None:
        names = glob.glob(self.pattern)
        assert len(names) == 1, names  # "/dev/ttyTMCM*" finds the simulated module
        self.port = serial.Serial(names[0], baudrate=9600, bytesize=serial.EIGHTBITS,
                                  parity=serial.PARITY_NONE, stopbits=serial.STOPBITS_ONE,
                                  timeout=WAIT_S, write_timeout=1)
        lock_exclusively(self.port.fileno())  # Odemis: flock(LOCK_EX | LOCK_NB)
        self.target = self.resynchronise()

    def resynchronise(self) -> int:
        self.port.reset_input_buffer()
        assert self._pending() == b""  # nothing left over from an earlier controller
        self.port.write(bytes(9))
        self.port.flush()
        reply = self.port.read(9)
        assert len(reply) == 9 and self._pending() == b"", reply  # Odemis reads 10: exactly 9
        _, address, status, _, _, checksum = struct.unpack(">BBBBiB", reply)
        assert status == Status.INVALID_COMMAND  # "Unknown command (expected)"
        assert checksum == sum(reply[:-1]) & 0xFF
        return address

    def _pending(self) -> bytes:
        """What the port holds right now (Odemis drains and checks with 0.1 s reads)."""
        self.port.timeout = 0
        try:
            return self.port.read(1000)
        finally:
            self.port.timeout = WAIT_S

    def send(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        frame = struct.pack(">BBBBi", self.target, opcode, type_, motor, value)
        self.port.write(frame + bytes([sum(frame) & 0xFF]))
        self.sent.append((opcode, type_, motor, value))
        while True:
            reply = self.port.read(9)
            assert len(reply) == 9, (opcode, type_, motor, reply)
            _, address, status, number, result, checksum = struct.unpack(">BBBBiB", reply)
            assert checksum == sum(reply[:-1]) & 0xFF
            assert address == self.target
            if number != opcode:
                continue  # Odemis skips replies to other instructions
            if status not in TMCL_OK_STATUS:
                raise TMCLError(status, result, (opcode, type_, motor, value))
            return result

    # -- time -----------------------------------------------------------------------------

    def now(self) -> float:
        return self.sim.call(lambda: self.sim.simulation.now_ns) / 1e9

    def sleep(self, seconds: float) -> None:
        self.sim.advance(seconds)

    # -- the constructor and the attributes it reads ----------------------------------------

    def start(self) -> None:
        self.open()
        value = self.send(Opcode.GET_FIRMWARE_VERSION, 1)
        self.model, self.version = value >> 16, ((value >> 8) & 0xFF, value & 0xFF)
        assert self.model in KNOWN_MODELS and self.model in USE_INTERNAL_UNIT_429
        self.send(Opcode.GAP, 1, 0)  # the highest axis exists (else "doesn't support N axes")
        if 0.1 * self.send(Opcode.GIO, 8, 1) < MINPOWER:
            raise NoPower
        header = self.send(Opcode.GGP, 0, 2)  # user config: skipped unless format 1
        assert (header >> 8) & 0xFF != 1  # a fresh module has none: a warning, nothing applied
        self.check_error_flag()  # old errors only warned at start
        self.update_position()
        self.speed = self.read_speed()
        self.accel = self.read_accel()
        assert self.speed > 0 and self.accel > 0

    def read_speed(self) -> float:
        velocity = self.send(Opcode.GAP, 4, 0)
        pulse_div = self.send(Opcode.GAP, 154, 0)
        return F_CLK * velocity / (2 ** pulse_div * 2048 * 32) * USTEP

    def read_accel(self) -> float:
        accel = self.send(Opcode.GAP, 5, 0)
        pulse_div = self.send(Opcode.GAP, 154, 0)
        ramp_div = self.send(Opcode.GAP, 153, 0)
        return F_CLK ** 2 * accel / 2 ** (pulse_div + ramp_div + 29) * USTEP

    def update_position(self) -> float:
        self.position = self.send(Opcode.GAP, 209, 0) * USTEP
        self.positions.append(self.position)
        return self.position

    def check_error_flag(self) -> int:
        flags = self.send(Opcode.GAP, 207, 0)
        if flags & 2:  # Odemis reads both positions to report the deviation
            self.send(Opcode.GAP, 1, 0)
            self.send(Opcode.GAP, 209, 0)
        return flags

    # -- moves ----------------------------------------------------------------------------

    def move_rel(self, shift: float, cancel_after: float | None = None) -> bool:
        """``moveRel({"x": shift})`` and its wait; returns False if it was dropped."""
        if abs(shift) < USTEP:  # "Dropped too small move"
            return False
        usteps = round(shift / USTEP)
        if self.send(Opcode.GAP, 212, 0) > 0:
            self.reset_actual_position()
        self.send(Opcode.MVP, 1, 0, usteps)
        self.wait(abs(usteps) * USTEP, cancel_after)
        return True

    def move_abs(self, position: float, cancel_after: float | None = None) -> None:
        old = self.position
        self.reset_actual_position()
        self.send(Opcode.MVP, 0, 0, round(position / USTEP))
        self.wait(abs(position - old), cancel_after)

    def reset_actual_position(self) -> None:
        self.send(Opcode.MST, 0, 0)
        encoder = self.send(Opcode.GAP, 209, 0)
        self.send(Opcode.GAP, 1, 0)
        self.send(Opcode.SAP, 1, 0, encoder)

    def wait(self, distance: float, cancel_after: float | None) -> None:
        """Odemis' wait loop: GAP 8 and GAP 207 each turn, the position every 0.1 s,
        sleeping half the time left (0.001..0.1 s); MST on timeout or cancel."""
        start = last_update = self.now()
        duration = max(0.01, min(estimate_move_duration(distance, self.speed, self.accel), 100))
        timeout = start + duration * 2 + 1
        end = start + duration
        try:
            while True:
                if cancel_after is not None and self.now() - start >= cancel_after:
                    self.send(Opcode.MST, 0, 0)
                    raise OdemisCancelled
                reached = self.send(Opcode.GAP, 8, 0) != 0
                assert self.check_error_flag() & 1 == 0, "Stall detected"
                if reached:
                    return
                now = self.now()
                if now > timeout:
                    self.send(Opcode.MST, 0, 0)
                    raise MoveTimeout(now - start, duration)
                if now - last_update > 0.1:
                    self.update_position()
                    last_update = now
                pause = max(0.001, min((end - now) / 2, 0.1))
                if cancel_after is not None:
                    pause = min(pause, max(0.0, start + cancel_after - now)) or 0.001
                self.sleep(pause)
        finally:
            self.update_position()

    def stop(self) -> None:
        self.send(Opcode.MST, 0, 0)

    def terminate(self) -> None:
        self.stop()
        self.port.close()


# == the test class, replayed ===================================================================


@dataclass
class AbsEncTest:
    """``TestActuatorAbsEnc``: setUp, one test's body, tearDown, on one module."""

    sim: SimulatorThread
    pattern: str
    dev: Controller = field(init=False)

    def set_up(self) -> None:
        self.dev = Controller(self.sim, self.pattern)
        self.dev.start()
        self.orig_pos = self.dev.position

    def tear_down(self) -> None:
        self.dev.sleep(1)
        self.dev.move_abs(self.orig_pos)
        self.dev.terminate()

    def run(self, body: Callable[[Controller], None]) -> None:
        self.set_up()
        body(self.dev)
        self.tear_down()


def odemis_simple(dev: Controller) -> None:
    assert not dev.move_rel(0.01e-6)  # below one microstep: no traffic
    dev.sleep(0.1)
    assert dev.position == pytest.approx(0.01e-6, abs=5e-8)  # assertAlmostEqual, 7 places


def odemis_sync(dev: Controller) -> None:
    started = dev.now()
    dev.move_rel(100e-6)
    took_forth = dev.now() - started
    assert took_forth > 0  # the move takes time (sync is slower than async)
    dev.move_rel(-100e-6)
    dev.send(Opcode.MVP, 1, 0, round(1e-3 / USTEP))  # f = moveRel(1e-3)
    dev.sleep(0.001)
    assert dev.send(Opcode.GAP, 8, 0) == 0  # f.result(timeout=0.001) times out
    dev.send(Opcode.MST, 0, 0)  # f.cancel()
    dev.update_position()


def odemis_linear_pos(dev: Controller) -> None:
    for direction in (1, -1):
        first = len(dev.positions)
        dev.move_rel(direction * 10e-3)
        seen = dev.positions[first - 1:]
        assert len(set(seen)) > 5  # positions seen on the way (a move of about 1.3 s)
        steps = [b - a for a, b in itertools.pairwise(seen)]
        assert all(step * direction > -20e-6 for step in steps), steps


def odemis_stop(dev: Controller) -> None:
    dev.stop()
    with pytest.raises(OdemisCancelled):  # f.cancel() right after moveRel
        dev.move_rel(100e-6, cancel_after=0)
    with pytest.raises(OdemisCancelled):  # dev.stop() cancels it too
        dev.move_rel(-100e-6, cancel_after=0)
    dev.stop()


def odemis_queue(dev: Controller) -> None:
    started = dev.now()
    expected = 4 * 1e-3 / dev.speed
    for shift in (1e-3, -1e-3, 1e-3, -1e-3):
        dev.move_rel(shift)
    assert dev.now() - started >= expected  # not faster than the TMC429's speed law


def odemis_cancel(dev: Controller) -> None:
    with pytest.raises(OdemisCancelled):
        dev.move_rel(1e-3, cancel_after=0.01)  # still running after 10 ms, then cancelled
    assert abs(dev.position - 1e-3) > 5e-8  # assertNotAlmostEqual
    dev.move_rel(1e-3)  # f1; f2 is cancelled in the queue before it starts


def odemis_not_cancel(dev: Controller) -> None:
    started = dev.now()
    dev.move_rel(0.1e-3)
    assert dev.now() - started < 1  # done within the test's one-second sleep
    dev.move_rel(0.1e-3)
    dev.move_rel(0.1e-3)


def odemis_future_callback(dev: Controller) -> None:
    dev.move_rel(1e-3)
    dev.move_rel(-1e-3)
    dev.move_rel(1e-3)
    with pytest.raises(OdemisCancelled):
        dev.move_rel(12e-3, cancel_after=0)


def _noop(dev: Controller) -> None:
    """The tests TestActuatorAbsEnc overrides with ``pass`` still run setUp and tearDown; so
    does its ``test_reference``, which sends nothing: an absolute axis is referenced from the
    start (``reference()`` returns an InstantaneousFuture)."""


#: The inherited tests in unittest's (alphabetical) order, no-ops included.
SEQUENCE: dict[str, Callable[[Controller], None]] = {
    "test_cancel": odemis_cancel, "test_close_shutter": _noop,
    "test_future_callback": odemis_future_callback, "test_led_protection_referencing": _noop,
    "test_linear_pos": odemis_linear_pos, "test_move_circle": _noop,
    "test_not_cancel": odemis_not_cancel, "test_open_shutter": _noop, "test_protection": _noop,
    "test_queue": odemis_queue, "test_ref_cancel": _noop, "test_reference": _noop,
    "test_simple": odemis_simple, "test_stop": odemis_stop, "test_sync": odemis_sync,
}


@pytest.fixture
def simulator(tmp_path: Path) -> Iterator[SimulatorThread]:
    with SimulatorThread(clock="virtual", module_type="tmcm-1140",
                         pty=[str(tmp_path / "ttyTMCM0")]) as sim:
        yield sim


@pytest.mark.parametrize("name", [n for n, body in SEQUENCE.items() if body is not _noop])
def test_each_odemis_test_on_a_fresh_tmcm_1140(simulator: SimulatorThread, tmp_path: Path,
                                                name: str) -> None:
    AbsEncTest(simulator, str(tmp_path / "ttyTMCM*")).run(SEQUENCE[name])


def test_the_whole_class_in_order_on_one_module(simulator: SimulatorThread,
                                                tmp_path: Path) -> None:
    case = AbsEncTest(simulator, str(tmp_path / "ttyTMCM*"))
    for body in SEQUENCE.values():
        case.run(body)
        assert case.dev.positions[-1] == pytest.approx(case.orig_pos, abs=5e-8)
    assert case.orig_pos == 0.0  # every tearDown brought the encoder back to its start


def test_the_constructor_sequence_is_what_odemis_sends(simulator: SimulatorThread,
                                                        tmp_path: Path) -> None:
    dev = Controller(simulator, str(tmp_path / "ttyTMCM*"))
    dev.start()
    assert (dev.model, dev.version) == (1140, (1, 27))
    assert dev.sent == [(136, 1, 0, 0), (6, 1, 0, 0), (15, 8, 1, 0), (10, 0, 2, 0),
                        (6, 207, 0, 0), (6, 209, 0, 0), (6, 4, 0, 0), (6, 154, 0, 0),
                        (6, 5, 0, 0), (6, 154, 0, 0), (6, 153, 0, 0)]
    assert dev.position == 0.0
    # the speed and acceleration Odemis computes from the power-on values
    assert dev.speed == pytest.approx(16e6 * 1000 / (4 * 2048 * 32) * USTEP)
    assert dev.accel == pytest.approx(16e6 ** 2 * 500 / 2 ** 34 * USTEP)
    dev.terminate()


def test_a_sagging_supply_fails_odemis_power_check(simulator: SimulatorThread,
                                                   tmp_path: Path) -> None:
    simulator.call(simulator.module().set_supply_voltage, 10.7)
    dev = Controller(simulator, str(tmp_path / "ttyTMCM*"))
    with pytest.raises(NoPower):
        dev.start()
    dev.port.close()
