"""Shared fixtures: modules in-process, and a raw TMCL client over a real socket."""

from __future__ import annotations

import contextlib
import fcntl
import os
import socket
from collections.abc import Iterator

import pytest
from hypothesis import HealthCheck, settings

from tests.helpers.requirements import MISSING_MARK
from tmcl_server.clock import VirtualClock
from tmcl_server.eeprom import Eeprom
from tmcl_server.module import TMCM6212
from tmcl_server.protocol import Reply, Request, decode_reply
from tmcl_server.simulation import Simulation

#: The suite's one hypothesis profile: no deadline and no "too slow" health check, so that a
#: loaded machine (other engineers' runs, a CPU hog) cannot fail a test that a quiet one
#: passes; a test that must be fast is a benchmark (scripts/bench*.py), not a timed test.
#: A test's own @settings (max_examples, ...) override only what they name.
settings.register_profile("tmcl-sim", deadline=None, suppress_health_check=[HealthCheck.too_slow],
                          print_blob=True)
#: CI's profile (.ci/run sets TMCL_SIM_HYPOTHESIS=ci): the same examples on every run, so that
#: a landing is judged on the code and not on the draw; a developer's runs and the fuzz scripts
#: (scripts/fuzz*.py) keep drawing new ones.  (CI once drew two TMC4361A law failures, a speed
#: landing exactly on 0 or on VMAX inside a segment, that 30,000 fresh examples here had not
#: drawn, and its log kept no reproduction: see pytest_terminal_summary.)
settings.register_profile("ci", settings.get_profile("tmcl-sim"), derandomize=True,
                          database=None)
settings.load_profile(os.environ.get("TMCL_SIM_HYPOTHESIS", "tmcl-sim"))


class Collector:
    """A reply sink that records unsolicited replies (command 138 events)."""

    def __init__(self) -> None:
        self.replies: list[Reply] = []

    def send_unsolicited(self, reply: Reply) -> None:
        self.replies.append(reply)


class Bench:
    """One module on a virtual clock, driven through the router exactly like a transport."""

    def __init__(self, module: TMCM6212) -> None:
        self.module = module
        self.simulation = Simulation([module], VirtualClock())
        self.sink = Collector()

    def send(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0,
             address: int | None = None) -> Reply | None:
        frame = Request(self.module.address if address is None else address,
                        opcode, type_, motor, value).encode()
        routed = self.simulation.handle_serial_frame(frame, self.sink)
        if not routed:
            return None
        (_, reply), = routed
        return reply  # type: ignore[return-value]

    def ok(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        reply = self.send(opcode, type_, motor, value)
        assert reply is not None and reply.status == 100, reply
        return reply.value

    def status(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        reply = self.send(opcode, type_, motor, value)
        assert reply is not None
        return reply.status

    def advance(self, seconds: float) -> None:
        self.simulation.advance(seconds)


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--soak", action="store_true", default=False,
                     help="also run the long soak/fuzz tests (marked @pytest.mark.soak)")


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A program the test needs is missing and TMCL_SIM_REQUIRE_ALL=1 (tests/helpers/requirements.py)."""
    for mark in item.iter_markers(MISSING_MARK):
        pytest.fail(mark.args[0], pytrace=False)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    """Each failed hypothesis test's falsifying example and reproduction blob, once more at the
    very end: a CI log that keeps only its tail still says how to reproduce the failure."""
    lines = []
    for report in terminalreporter.stats.get("failed", []):
        found, example = [], 0
        for line in getattr(report, "longreprtext", "").splitlines():
            text = line.strip().removeprefix("E").strip().removeprefix("|").strip()
            if text.startswith(("Falsifying example", "Failing test case")):
                example = 40  # the example's lines, to its closing parenthesis
            if example or "@reproduce_failure(" in text:
                found.append(text)
                example = 0 if example and text == ")" else max(example - 1, 0)
        if found:
            lines += [report.nodeid, *found[:120]]
    if lines:
        terminalreporter.section("how to reproduce the hypothesis failures")
        for line in lines:
            terminalreporter.write_line(line)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--soak"):
        return
    skip = pytest.mark.skip(reason="soak test: run with --soak")
    for item in items:
        if "soak" in item.keywords:
            item.add_marker(skip)


@pytest.fixture(autouse=True)
def _exclusive_if_marked(request: pytest.FixtureRequest,
                         tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """``@pytest.mark.exclusive`` tests (wall-clock timing) run while no other test does, also
    across xdist workers: every test holds a shared lock on a file all workers see, an exclusive
    test the exclusive lock.  A gate keeps new tests from slipping in while one waits."""
    directory = tmp_path_factory.getbasetemp().parent  # shared by the workers of one run
    exclusive = request.node.get_closest_marker("exclusive") is not None
    with open(directory / "tests-gate.lock", "a") as gate, open(directory / "tests-run.lock", "a") as run:
        fcntl.flock(gate, fcntl.LOCK_EX)
        if not exclusive:
            fcntl.flock(gate, fcntl.LOCK_UN)
        fcntl.flock(run, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        if exclusive:
            fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            with contextlib.suppress(OSError):
                fcntl.flock(run, fcntl.LOCK_UN)


@pytest.fixture
def bench(tmp_path) -> Bench:
    return Bench(TMCM6212(1, Eeprom(tmp_path / "module-1")))


class RawClient:
    """A socket speaking raw 9-byte frames, with explicit timeouts (no sleeping)."""

    def __init__(self, endpoint: str, timeout: float = 2.0) -> None:
        host, port = endpoint.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def recv_exact(self, n: int) -> bytes:
        data = b""
        while len(data) < n:
            chunk = self.sock.recv(n - len(data))
            if not chunk:
                raise ConnectionError("server closed the connection")
            data += chunk
        return data

    def request(self, address: int, opcode: int, type_: int = 0, motor: int = 0,
                value: int = 0) -> Reply:
        self.send_raw(Request(address, opcode, type_, motor, value).encode())
        return decode_reply(self.recv_exact(9))

    def expect_silence(self, seconds: float = 0.2) -> None:
        """Assert that nothing arrives within ``seconds`` (a bound, not a sleep-and-hope)."""
        self.sock.settimeout(seconds)
        try:
            data = self.sock.recv(64)
        except TimeoutError:
            return
        finally:
            self.sock.settimeout(2.0)
        raise AssertionError(f"expected silence, got {data.hex(' ')}")

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def raw_client_factory() -> Iterator:
    clients: list[RawClient] = []

    def make(endpoint: str) -> RawClient:
        client = RawClient(endpoint)
        clients.append(client)
        return client

    yield make
    for client in clients:
        client.close()
