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

``tmcl_replay("captures/homing.jsonl")`` turns a capture of a real module (``tmcl proxy
--capture``) into a test: it replays it against a fresh simulator and fails with the list of
replies the simulator gives otherwise (docs/capture.md, "Captures as tests").

The package installs this plugin into every pytest run of its environment, also of projects
that never use a fixture: importing it loads nothing of the simulator (the fixtures import
it when a test asks for one), so it adds about a millisecond to pytest's start
(``scripts/bench_startup.py --plugin``).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
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


@pytest.fixture
def tmcl_replay(request: pytest.FixtureRequest) -> Callable[..., Any]:
    """``tmcl_replay(capture, module_type=None, axis_core=None, world=None, state_dir=None,
    tolerance=None)``: replay a capture as ``tmcl replay`` does; the test fails with the
    divergences (or with why the capture cannot be read).  Relative paths are looked up beside
    the test file first.  Returns the result (``divergences``, ``summary``)."""
    here = Path(str(request.node.path)).parent

    def beside_the_test(path: str | Path | None) -> str | None:
        if path is None:
            return None
        found = here / path
        return str(found if not Path(path).is_absolute() and found.exists() else path)

    def replay(capture: str | Path, *, module_type: str | None = None, axis_core: str | None = None,
               world: str | Path | None = None, state_dir: str | Path | None = None,
               tolerance: float | None = None) -> Any:
        from tmcl_server.cli import UsageError  # the simulator: loaded by this call only
        from tmcl_server.decode import CaptureError
        from tmcl_server.replay import DEFAULT_TOLERANCE_S, replay_capture

        path = beside_the_test(capture)
        assert path is not None
        try:
            result = replay_capture(
                path, module_type_name=module_type, axis_core=axis_core,
                world=beside_the_test(world), state_dir=None if state_dir is None else str(state_dir),
                tolerance_s=DEFAULT_TOLERANCE_S if tolerance is None else tolerance)
        except UsageError as exc:
            pytest.fail(f"tmcl_replay: {exc.message}", pytrace=False)
        except CaptureError as exc:
            pytest.fail(f"tmcl_replay: {exc}", pytrace=False)
        if result.summary.exit_code:
            pytest.fail(f"{path}: the simulator answers otherwise\n{result.report()}", pytrace=False)
        return result

    return replay
