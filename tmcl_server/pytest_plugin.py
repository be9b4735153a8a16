"""pytest plugin (entry point ``pytest11``): simulated TMCM-6212 modules as fixtures.

    def test_move(tmcl_sim):
        iface = SocketTmclInterface(tmcl_sim.tcp)   # pytrinamic, unchanged
        ...
        tmcl_sim.advance(2.0)                       # virtual clock: no sleeping

``tmcl_sim`` is one module at address 1 with a TCP endpoint on a free loopback port;
``tmcl_sim_factory(**kwargs)`` builds others (see SimulatorThread).  Their clock is chosen,
in this order, by the factory's ``clock=`` argument, ``@pytest.mark.tmcl_sim(clock=...)``,
``--tmcl-sim-clock`` and the ``tmcl_sim_clock`` ini option:

* ``virtual`` (default): time moves only by ``sim.advance()`` / ``sim.advance_until()``.
* ``lockstep``: time moves with what the host does.  Every request takes ``request_time``
  (default 1 ms) and every ``time.sleep(s)`` of the test's own thread advances the simulation
  by ``s`` instead of sleeping, so unchanged poll-and-sleep host code finishes at once and
  sees the same replies on every run (README, "Host tests that poll").
* ``real``: simulated time is wall time (``speed=X`` to run it X times faster).

The marker's other keywords (``modules=3``, ``request_time=0.01``, ...) are defaults for
every simulator the test makes; ``faults=["noreply:opcode=GAP"]`` injects faults from the start,
``with tmcl_sim.fault("delay", ms=50): ...`` for a block (docs/faults.md).

The package installs this plugin into every pytest run of its environment, also of projects
that never use a fixture: importing it loads nothing of the simulator (the fixtures import
it when a test asks for one), so it adds about a millisecond to pytest's start
(``scripts/bench_startup.py --plugin``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from tmcl_server.embed import SimulatorThread

CLOCKS = ("virtual", "lockstep", "real")
INI_CLOCK = "tmcl_sim_clock"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addini(INI_CLOCK, f"clock of the tmcl_sim fixtures: {', '.join(CLOCKS)} (default virtual)",
                  default="virtual")
    parser.getgroup("tmcl-sim").addoption(
        "--tmcl-sim-clock", choices=CLOCKS, default=None,
        help="clock of the tmcl_sim fixtures (overrides the tmcl_sim_clock ini option)")


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "tmcl_sim(**settings): settings for the tmcl_sim fixtures of a test, e.g. "
        "clock='lockstep', request_time=0.001, modules=2")


class _SleepAdvancesTime:
    """``time.sleep`` for a lockstep test: the test's thread advances its simulators instead."""

    def __init__(self, host: threading.Thread, real_sleep: Callable[[float], None]) -> None:
        self.host = host
        self.real_sleep = real_sleep
        self.simulators: list[SimulatorThread] = []

    def __call__(self, seconds: float) -> None:
        if threading.current_thread() is not self.host or seconds <= 0 or not self.simulators:
            self.real_sleep(seconds)
            return
        for sim in self.simulators:
            if sim.running:
                sim.advance(seconds)
        self.real_sleep(0)  # give other threads their turn, as a sleep would


def _default_settings(request: pytest.FixtureRequest) -> dict[str, Any]:
    settings: dict[str, Any] = {}
    marker = request.node.get_closest_marker("tmcl_sim")
    if marker is not None:
        settings.update(marker.kwargs)
    if "clock" not in settings:
        settings["clock"] = (request.config.getoption("--tmcl-sim-clock", default=None)
                             or request.config.getini(INI_CLOCK) or "virtual")
    if settings["clock"] not in CLOCKS:
        raise pytest.UsageError(f"tmcl_sim clock must be one of {', '.join(CLOCKS)}, "
                                f"not {settings['clock']!r}")
    return settings


@pytest.fixture
def tmcl_sim_factory(request: pytest.FixtureRequest,
                     monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., SimulatorThread]]:
    started: list[SimulatorThread] = []
    defaults = _default_settings(request)
    sleeper: _SleepAdvancesTime | None = None

    def make(**kwargs: Any) -> SimulatorThread:
        from tmcl_server.embed import SimulatorThread

        nonlocal sleeper
        for key, value in defaults.items():
            kwargs.setdefault(key, value)
        if not any(k in kwargs for k in ("tcp", "pty", "serial", "config")):
            kwargs["tcp"] = ["127.0.0.1:0"]
        sim = SimulatorThread(**kwargs).start()
        started.append(sim)
        if sim.config.clock == "lockstep":
            if sleeper is None:
                sleeper = _SleepAdvancesTime(threading.current_thread(), time.sleep)
                monkeypatch.setattr(time, "sleep", sleeper)
            sleeper.simulators.append(sim)
        return sim

    yield make
    if sleeper is not None:
        sleeper.simulators.clear()
    for sim in reversed(started):
        sim.stop()


@pytest.fixture
def tmcl_sim(tmcl_sim_factory: Callable[..., SimulatorThread]) -> SimulatorThread:
    return tmcl_sim_factory()
