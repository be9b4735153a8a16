"""The server's timer on a real clock: how a busy program shares the loop with requests
(docs/scheduling.md).  The clock and the wall clock are held still by the test, so what
one timer slice does is exact."""

from __future__ import annotations

import asyncio
import itertools

import pytest

from interpreter.assembler import assemble
from tests.helpers.clocks import ManualClock
from tmcl_server.module import TMCM6212
from tmcl_server.protocol import Request
from tmcl_server.server import (
    PROGRAM_CHUNK_TRAFFIC_NS,
    PROGRAM_PRIORITY_LAG_NS,
    PROGRAM_SHARE_TRAFFIC,
    Server,
)
from tmcl_server.simulation import PROGRAM_CHUNK_NS, REQUEST_TURN_NS, Simulation
from tmcl_spec.commands import Opcode

BUSY = """
Loop:
    CALC ADD, 1
    JA Loop
"""


@pytest.fixture
def busy_server():
    clock = ManualClock()
    module = TMCM6212()
    simulation = Simulation([module], clock)
    module.program.interpreter.load(assemble(BUSY).instructions)
    module.program.interpreter.start(0)
    simulation.replan()  # as a RUN APPLICATION command would
    server = Server(simulation=simulation)
    loop = asyncio.new_event_loop()
    server._loop = loop
    ticks = itertools.count()
    server.wall_s = lambda: float(next(ticks))  # every chunk outlasts its slice
    yield server, module, clock
    loop.close()


def test_a_quiet_server_runs_a_busy_program_in_long_chunks(busy_server):
    server, module, clock = busy_server
    clock.t = 20_000_000  # the program is 20 ms behind the clock
    server._on_timer()
    assert module.now_ns == PROGRAM_CHUNK_NS
    server._on_timer()
    assert module.now_ns == 2 * PROGRAM_CHUNK_NS


def test_while_hosts_send_the_program_runs_in_short_chunks(busy_server):
    server, module, clock = busy_server
    clock.t = 20_000_000
    gap = Request(1, Opcode.GAP, 1, 0, 0).encode()
    server.simulation.handle_serial_frame(gap)  # one instruction before it is served
    assert module.now_ns == REQUEST_TURN_NS
    server._on_timer()  # a request came since the last slice: a short one
    assert module.now_ns == REQUEST_TURN_NS + PROGRAM_CHUNK_TRAFFIC_NS
    assert PROGRAM_CHUNK_TRAFFIC_NS < PROGRAM_CHUNK_NS
    server.simulation.handle_serial_frame(gap)  # the timer left it behind: no turn here
    server._on_timer()
    assert module.now_ns == REQUEST_TURN_NS + 2 * PROGRAM_CHUNK_TRAFFIC_NS
    server._on_timer()  # nobody asked since: long chunks again
    assert module.now_ns == REQUEST_TURN_NS + 2 * PROGRAM_CHUNK_TRAFFIC_NS + PROGRAM_CHUNK_NS


def test_a_slice_that_has_wall_time_left_catches_the_program_up(busy_server):
    server, module, clock = busy_server
    server.wall_s = lambda: 0.0  # a machine fast enough that no slice runs out
    clock.t = 20_000_000
    server._on_timer()
    assert module.now_ns == 20_000_000
    # 10 us each, from 0 up to and including the one that starts at 20 ms
    assert module.program.interpreter.executed == 20_000_000 // 10_000 + 1


def test_a_program_falling_behind_gets_the_long_chunks_back_despite_hosts(busy_server):
    server, module, clock = busy_server
    clock.t = 40_000_000  # far behind: past PROGRAM_PRIORITY_LAG_NS, short of MAX_LAG_NS
    gap = Request(1, Opcode.GAP, 1, 0, 0).encode()
    server.simulation.handle_serial_frame(gap)
    server._on_timer()  # a short slice: the lag was not known yet
    assert module.now_ns == REQUEST_TURN_NS + PROGRAM_CHUNK_TRAFFIC_NS
    assert server.simulation.lag_ns > PROGRAM_PRIORITY_LAG_NS
    server.simulation.handle_serial_frame(gap)
    server._on_timer()  # hosts still send, but the program must catch up first
    assert module.now_ns == REQUEST_TURN_NS + PROGRAM_CHUNK_TRAFFIC_NS + PROGRAM_CHUNK_NS


def test_a_host_polling_right_after_run_sees_the_first_instruction_done() -> None:
    """A real module's main loop executes an instruction between two host requests: right
    after command 129 a host's next request sees what the program's first instruction did,
    not the state from before (issue 24, item 7)."""
    clock = ManualClock()
    module = TMCM6212()
    simulation = Simulation([module], clock)
    program = assemble("SGP 0, 2, 1234\nLoop:\n    JA Loop").instructions
    frames = [Request(1, Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0), *(Request(1, *i) for i in program),
              Request(1, Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0), Request(1, Opcode.RUN_APPLICATION, 0, 0, 0)]
    for request in frames:
        simulation.handle_serial_frame(request.encode())
    clock.t += 200_000  # the host asks 0.2 ms later; the server's timer has not fired
    (_, reply), = simulation.handle_serial_frame(Request(1, Opcode.GGP, 0, 2, 0).encode())
    assert reply.value == 1234


def test_a_program_that_cannot_keep_up_leaves_the_hosts_their_share(busy_server):
    """Issue 36, N11: a program that lost time anyway (it fell past MAX_LAG_NS and skipped)
    gets no priority while hosts send: after its slice the timer waits three slices' time
    (PROGRAM_SHARE_TRAFFIC) and the hosts have the loop; a request to it runs no instruction
    of its own (one may cost far more CPU than its 10 us) and is served at its present."""
    server, module, clock = busy_server
    loop = server._loop
    ticks = itertools.count()
    slice_s = 0.001
    server.wall_s = lambda: next(ticks) * slice_s  # every chunk outlasts its slice
    clock.t = 200_000_000  # far past MAX_LAG_NS: the timer's run skips time
    gap = Request(1, Opcode.GAP, 1, 0, 0).encode()
    server.simulation.handle_serial_frame(gap)
    server._on_timer()
    assert server.simulation.skipped_ns[0] > 0
    executed = module.program.interpreter.executed
    now = module.now_ns
    server.simulation.handle_serial_frame(gap)  # the program is behind: no turn for it
    assert (module.program.interpreter.executed, module.now_ns) == (executed, now)
    server._on_timer()
    assert isinstance(server._timer, asyncio.TimerHandle)  # not call_soon: the hosts' turn
    hosts_s = slice_s * (1 - PROGRAM_SHARE_TRAFFIC) / PROGRAM_SHARE_TRAFFIC
    assert server._timer.when() >= loop.time() + hosts_s - 1e-3
    server._timer.cancel()
    server._on_timer()  # nobody asked since: the program runs on at once again
    assert not isinstance(server._timer, asyncio.TimerHandle)


def test_a_new_program_gets_its_first_turn_at_the_next_request(busy_server):
    server, module, clock = busy_server
    clock.t = 200_000_000
    gap = Request(1, Opcode.GAP, 1, 0, 0).encode()
    server.simulation.handle_serial_frame(gap)
    server._on_timer()  # left behind
    for opcode in (Opcode.STOP_APPLICATION, Opcode.RUN_APPLICATION):
        server.simulation.handle_serial_frame(Request(1, opcode, 1, 0, 0).encode())
    executed = module.program.interpreter.executed
    server.simulation.handle_serial_frame(gap)
    assert module.program.interpreter.executed == executed + 1
