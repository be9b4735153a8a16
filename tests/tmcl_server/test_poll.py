"""Host code that polls and sleeps, unchanged, against the lockstep clock (README, "Host tests
that poll"): it finishes at once and sees the same replies on every run."""

from __future__ import annotations

import itertools
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.modules import TMCM6212

from tests.conftest import RawClient
from tests.helpers.processes import ServerProcess
from tmcl_server.embed import SimulatorThread
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP, GP

ROOT = Path(__file__).resolve().parents[2]


def move_and_poll(endpoint: str, poll_s: float | None) -> list[int]:
    """What a user's script does: start a move, then poll the position until it arrives."""
    seen = []
    with ConnectionManager(f"--interface socket_serial_tmcl --port {endpoint}").connect() as iface:
        motor = TMCM6212(iface).motors[0]
        motor.set_axis_parameter(AP.MAX_ACCELERATION, 25600)
        motor.move_to(51200)
        while not motor.get_position_reached():
            seen.append(motor.actual_position)
            if poll_s is not None:
                time.sleep(poll_s)
    return seen


@pytest.mark.tmcl_sim(clock="lockstep")
def test_unchanged_poll_and_sleep_code_finishes_quickly(tmcl_sim: SimulatorThread) -> None:
    started = time.perf_counter()
    seen = move_and_poll(tmcl_sim.tcp, 0.1)
    assert time.perf_counter() - started < 2.0  # a 2.8 s move, polled every 0.1 s: no real waiting
    assert 25 <= len(seen) <= 30 and seen == sorted(seen)
    now = tmcl_sim.call(lambda: tmcl_sim.simulation.now_ns) / 1e9
    assert 2.8 < now < 3.2  # the sleeps and the requests' time on the wire, nothing else


def test_what_the_host_sees_is_the_same_on_every_run(
        tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    runs = []
    for _ in range(2):
        sim = tmcl_sim_factory(clock="lockstep")
        runs.append(move_and_poll(sim.tcp, 0.05))
        sim.stop()
    assert runs[0] == runs[1] and len(runs[0]) > 40


def test_busy_polling_without_sleep_finishes_too(tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    sim = tmcl_sim_factory(clock="lockstep", request_time=0.005)  # a slow bus: 5 ms a request
    seen = move_and_poll(sim.tcp, None)
    assert 250 < len(seen) < 320  # 2.8 s / (two requests of 5 ms per poll)
    client = RawClient(sim.tcp)
    ticks = [client.request(1, Opcode.GGP, GP.TICK_TIMER, 0).value for _ in range(3)]
    assert [b - a for a, b in itertools.pairwise(ticks)] == [5, 5]  # ms, per request
    client.close()


def test_other_threads_still_sleep_for_real(tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    import threading

    sim = tmcl_sim_factory(clock="lockstep")
    before = sim.call(lambda: sim.simulation.now_ns)
    worker = threading.Thread(target=time.sleep, args=(0.05,))
    started = time.perf_counter()
    worker.start()
    worker.join()
    assert time.perf_counter() - started >= 0.05
    assert sim.call(lambda: sim.simulation.now_ns) == before


PLUGIN_TESTS = '''
import time
import pytest

def test_default(tmcl_sim):
    assert tmcl_sim.config.clock == "{expected}"

@pytest.mark.tmcl_sim(clock="virtual", modules=2)
def test_marker_wins(tmcl_sim):
    assert tmcl_sim.config.clock == "virtual" and tmcl_sim.config.addresses == [1, 2]
'''


@pytest.mark.parametrize(("how", "expected"), [
    (["-o", "tmcl_sim_clock=lockstep"], "lockstep"),
    (["--tmcl-sim-clock", "lockstep"], "lockstep"),
])
def test_the_clock_is_chosen_by_ini_option_or_command_line(tmp_path: Path, how: list[str],
                                                            expected: str) -> None:
    (tmp_path / "test_choice.py").write_text(textwrap.dedent(PLUGIN_TESTS.format(expected=expected)))
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    result = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                             "-p", "no:xdist", *how, str(tmp_path)], capture_output=True, text=True,
                            timeout=120, cwd=tmp_path)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "2 passed" in result.stdout


HOST_SCRIPT = '''
import sys
from pytrinamic.connections import ConnectionManager
from pytrinamic.modules import TMCM6212

with ConnectionManager(f"--interface socket_serial_tmcl --port {sys.argv[1]}").connect() as iface:
    motor = TMCM6212(iface).motors[0]
    motor.move_to(20000)
    while not motor.get_position_reached():
        print(motor.actual_position, motor.actual_velocity)
'''


def test_a_host_in_another_process_sees_the_same_motion_every_run(tmp_path: Path) -> None:
    script = tmp_path / "host.py"
    script.write_text(HOST_SCRIPT)
    outputs = []
    for run in range(2):
        server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--clock", "lockstep",
                               "--request-time", "0.01")
        try:
            host = subprocess.run([sys.executable, str(script), server.endpoints["tcp"][0]],
                                  capture_output=True, text=True, timeout=60, cwd=ROOT)
            assert host.returncode == 0, host.stderr
            outputs.append(host.stdout)
        finally:
            code, _, err = server.stop()
        assert code == 0, (run, err)
    assert outputs[0] == outputs[1] and len(outputs[0].splitlines()) > 20
