"""pytest plugin (entry point ``pytest11``): simulated TMCM-6212 modules as fixtures.

    def test_move(tmcl_sim):
        iface = SocketTmclInterface(tmcl_sim.tcp)   # pytrinamic, unchanged
        ...
        tmcl_sim.advance(2.0)                       # virtual clock: no sleeping

``tmcl_sim`` is one module at address 1 on a virtual clock with a TCP endpoint on a free
loopback port.  ``tmcl_sim_factory(**kwargs)`` builds others (see SimulatorThread).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import pytest

from tmcl_server.embed import SimulatorThread


@pytest.fixture
def tmcl_sim_factory() -> Iterator[Callable[..., SimulatorThread]]:
    started: list[SimulatorThread] = []

    def make(**kwargs: object) -> SimulatorThread:
        kwargs.setdefault("clock", "virtual")
        if not any(k in kwargs for k in ("tcp", "pty", "serial", "config")):
            kwargs["tcp"] = ["127.0.0.1:0"]
        sim = SimulatorThread(**kwargs).start()  # type: ignore[arg-type]
        started.append(sim)
        return sim

    yield make
    for sim in reversed(started):
        sim.stop()


@pytest.fixture
def tmcl_sim(tmcl_sim_factory: Callable[..., SimulatorThread]) -> SimulatorThread:
    return tmcl_sim_factory()
