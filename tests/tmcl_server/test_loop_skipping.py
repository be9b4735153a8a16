"""Loops that change nothing are skipped exactly as stepping would run them (docs/scheduling.md).

Every scenario runs twice on the virtual clock: with loop skipping (the default) and in the
stepping reference (``Interpreter.skip_loops = False``, every instruction executed), with the
same program, world and host.  Both must see the same events at the same instants, the same
replies to host requests made mid-loop, and end in the same state.  Hypothesis makes random
programs (loops of GAP/GIO/GGP/COMP/JC/CALC/ROR/SAP/AAP/SIO/WAIT, timers) and worlds (switches,
inputs changed by the test, host requests arriving mid-loop).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from interpreter.assembler import assemble
from tmcl_server.clock import VirtualClock
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import Reply, Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode

MS = 1_000_000

#: Reads a polling loop makes: (source, what it reads).
READS = [
    "GAP 8, 0", "GAP 1, 0", "GAP 1, 1", "GAP 3, 0", "GAP 10, 0", "GAP 11, 0", "GAP 4, 0",
    "GAP 250, 0", "GIO 0, 0", "GIO 1, 1", "GIO 2, 2", "GGP 0, 2", "GGP 132, 0", "GAP 206, 0",
    "GAP 209, 0", "GAP 8, 1", "RFS STATUS, 0", "GAP 3, 1", "GAP 1, 1",
    "GAP 180, 0", "GAP 207, 0", "GAP 206, 1", "GAP 180, 1",
]
#: Writes that change nothing once they are in force (and some that always change).
WRITES = [
    "SAP 4, 0, 100000", "SAP 4, 0, 120000", "ROR 1, 30000", "ROR 1, 40000", "AAP 2, 1",
    "SIO 0, 2, 1", "SGP 1, 2, 7", "AGP 2, 2", "MST 1", "SCO 1, 0, 5",
    "SAP 172, 0, 0", "SAP 181, 0, 0",
]
#: stallGuard and coolStep as a program sets them up (AP 168-174, 181-182; issue 34).
STALLGUARD_SETUPS = [
    [], ["SAP 172, 0, 2", "SAP 170, 0, 1", "SAP 169, 0, 2", "SAP 182, 0, 20000"],
    ["SAP 172, 1, 1", "SAP 173, 1, 1", "SAP 171, 1, 3"],
    ["SAP 174, 0, 2", "SAP 181, 0, 10000", "SAP 173, 0, 1"],
    ["SAP 174, 1, 1", "SAP 181, 1, 20000", "SAP 172, 1, 3", "SAP 182, 1, 0"],
]
CONDITIONS = ["EQ", "NE", "GT", "GE", "LT", "LE", "ZE", "NZ"]


@st.composite
def programs(draw: st.DrawFn) -> str:
    """A set-up, then a main loop polling something, with an exit to a second loop."""
    lines = [
        f"SAP 4, 0, {draw(st.sampled_from([20000, 100000, 300000]))}",
        f"SAP 5, 0, {draw(st.sampled_from([50000, 400000, 2000000]))}",
        *draw(st.sampled_from(STALLGUARD_SETUPS)),
        f"MVP ABS, 0, {draw(st.integers(-60000, 60000))}",
    ]
    if draw(st.booleans()):
        lines.append(f"ROR 1, {draw(st.sampled_from([-40000, 30000]))}")
    if draw(st.booleans()):  # a timer interrupt whose handler counts
        lines += ["VECT 0, Tick", f"SGP 0, 3, {draw(st.integers(1, 30))}", "EI 0", "EI 255"]
    lines.append("Main:")
    body: list[str] = []
    for _ in range(draw(st.integers(1, 5))):
        kind = draw(st.sampled_from(["read", "read", "compare", "write", "calc", "wait"]))
        if kind == "read":
            body.append(draw(st.sampled_from(READS)))
        elif kind == "compare":
            body.append(f"COMP {draw(st.integers(-70000, 70000))}")
            target = draw(st.sampled_from(["Main", "Next", "Next2"]))
            body.append(f"JC {draw(st.sampled_from(CONDITIONS))}, {target}")
        elif kind == "write":
            body.append(draw(st.sampled_from(WRITES)))
        elif kind == "calc":
            body.append(draw(st.sampled_from(["CALC ADD, 1", "CALC LOAD, 5", "CALC MUL, 2",
                                              "CALC SUB, 3", "CALCX LOAD"])))
        else:
            body.append(f"WAIT TICKS, 0, {draw(st.integers(0, 3))}")
    lines += body
    lines.append("JA Main")
    lines += ["Next:", f"MVP ABS, 0, {draw(st.integers(-60000, 60000))}", "Next2:",
              draw(st.sampled_from(READS)), f"COMP {draw(st.integers(-70000, 70000))}",
              f"JC {draw(st.sampled_from(CONDITIONS))}, Next2", "JA Main",
              "Tick:", "GGP 3, 2", "CALC ADD, 1", "AGP 3, 2", "RETI"]
    return "\n".join(lines)


@dataclass
class World:
    switch_at: int | None
    #: (time ms, action): toggle input 0 / set analogue 1 / host GAP / host SAP / move the switch.
    actions: list[tuple[int, str, int]] = field(default_factory=list)
    end_ms: int = 300
    core: str = "tmc4210"
    #: Load zones (axis, from, to, load value): light, heavy, blocked (0) stretches.
    loads: list[tuple[int, int, int, int]] = field(default_factory=list)


@st.composite
def worlds(draw: st.DrawFn) -> World:
    actions = draw(st.lists(st.tuples(st.integers(1, 299), st.sampled_from(
        ["input", "analog", "gap", "sap", "sgp", "switch", "ror"]), st.integers(-50000, 50000)),
        max_size=6))
    loads = draw(st.lists(st.tuples(st.integers(0, 1), st.integers(-60000, 50000),
                                    st.integers(100, 30000), st.sampled_from([0, 20, 300, 900])),
                          max_size=3))
    return World(draw(st.none() | st.integers(-50000, 50000)), sorted(actions),
                 core=draw(st.sampled_from(["tmc4210", "tmc4361a", "tmc429"])),
                 loads=[(axis, start, start + length, load) for axis, start, length, load in loads])


def run(source: str, world: World, skip: bool) -> list[object]:
    module = TMCLModule(kind="tmcm-6212", chip_core=world.core)
    sim = Simulation([module], VirtualClock())
    module.program.interpreter.skip_loops = skip
    seen: list[object] = []

    def listen(event: ModuleEvent) -> None:
        seen.append((event.time_ns, event.kind, event.axis, sorted(event.data.items())))

    module.listeners.append(listen)
    if world.switch_at is not None:
        module.set_switch(0, "right", world.switch_at)
    for axis in (0, 1):
        zones = [(start, end, load) for on, start, end, load in world.loads if on == axis]
        if zones:
            module.set_load(axis, zones)

    def host(opcode: int, type_: int, motor: int, value: int) -> None:
        reply = module.execute(Request(1, opcode, type_, motor, value))
        assert isinstance(reply, Reply)
        seen.append(("reply", sim.now_ns, opcode, reply.status, reply.value))
        sim.replan(module)

    for opcode, type_, motor, value in [(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0),
                                        *assemble(source).instructions,
                                        (Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0),
                                        (Opcode.RUN_APPLICATION, 0, 0, 0)]:
        module.execute(Request(1, opcode, type_, motor, value))
    sim.replan(module)
    for at_ms, action, value in world.actions:
        # not on a millisecond boundary
        sim.advance_to_ns(max(sim.now_ns, at_ms * MS + value % 997 * 1000))
        if action == "input":
            module.set_digital_input(0, not module.digital_input(0))
        elif action == "analog":
            module.set_analog_input(1, abs(value) % 4096)
        elif action == "gap":
            host(Opcode.GAP, 1, 0, 0)
            host(Opcode.GET_APPLICATION_STATUS, 2, 0, 0)  # the accumulator
        elif action == "sap":
            host(Opcode.SAP, 4, 0, abs(value) * 4 + 1000)
        elif action == "sgp":
            host(Opcode.SGP, 0, 2, value)
        elif action == "ror":
            host(Opcode.ROR, 0, 1, value)
        else:
            module.set_switch(0, "left", value)
        sim.replan(module)
        seen.append(("state", sim.now_ns, *registers(module)))
    sim.advance_to_ns(world.end_ms * MS)
    seen.append(("end", *registers(module)))
    seen.append(("skipped", module.program.interpreter.loops_skipped) if skip else ("skipped", 0))
    return seen


def registers(module: TMCLModule) -> tuple[object, ...]:
    interp = module.program.interpreter
    return (interp.pc, interp.accumulator, interp.x, interp.zero_source, interp.compare_source,
            interp.errors, tuple(interp.stack), interp.executed, interp.time_ns,
            dict(module.globals[2]), [module.axis(i).get_parameter(1) for i in range(6)],
            list(module.outputs))


POLL_TARGET = """
    SAP 4, 0, 100000
    MVP ABS, 0, 50000
Wait:
    GAP 8, 0
    COMP 1
    JC NE, Wait
    GAP 1, 0
    AGP 9, 2
    MVP ABS, 0, -20000
Out:
    GAP 1, 0
    COMP 0
    JC GT, Out
    GAP 1, 0
    AGP 10, 2
    STOP
"""


POLL_SPEED = """
    SAP 5, 0, 20000
    ROR 0, 8000
Up:
    GAP 3, 0
    COMP 6000
    JC LT, Up
    GAP 1, 0
    AGP 9, 2
    ROR 0, -3000
Down:
    GAP 3, 0
    COMP -1000
    JC GT, Down
    GAP 1, 0
    AGP 10, 2
    STOP
"""


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(programs(), worlds())
@example(POLL_TARGET, World(None, [(20, "gap", 0), (300, "sap", 30000)], 600))
@example(POLL_SPEED, World(None, [(100, "gap", 0), (500, "gap", 0)], 900))
# a moving read left in the accumulator, which the next pass compares: equal to the one the
# pass found only by chance (the rotation had not yet made a step), so no skipping
@example("SAP 4, 0, 20000\nMVP ABS, 0, 0\nROR 1, -40000\nMain:\nCOMP 0\nJC NE, Main\n"
         "GAP 8, 0\nGAP 1, 1\nJA Main\nNext:\nNext2:\nJA Main\nTick:\nRETI", World(None, []))
@example(POLL_SPEED, World(None, [(100, "gap", 0), (500, "gap", 0)], 900, "tmc4361a"))
# issue 33's D1: coolStep read after a poll of the position through a ramp (it read 11 stepping
# and 7 skipping), and issue 34's item 2: a stall the program's reads must not postpone
@example("SAP 172, 0, 2\nSAP 169, 0, 2\nSAP 182, 0, 10000\nSAP 5, 0, 20000\nROR 0, 40000\n"
         "Main:\nGAP 1, 0\nCOMP 5000\nJC LT, Main\nGAP 180, 0\nAGP 0, 2\nNext:\nNext2:\n"
         "GAP 180, 0\nJA Next2\nTick:\nRETI", World(None, [], 400, loads=[(0, -90000, 90000, 600)]))
@example("SAP 173, 0, 1\nSAP 174, 0, 1\nSAP 181, 0, 29000\nROL 0, 30000\nMain:\nGAP 3, 0\n"
         "COMP 0\nJC NE, Main\nNext:\nNext2:\nJA Next2\nTick:\nRETI",
         World(None, [(5, "gap", 0)], 900, loads=[(0, -9000, -3000, 0)]))
def test_skipping_loops_is_exactly_as_stepping(source: str, world: World) -> None:
    fast, slow = run(source, world, skip=True), run(source, world, skip=False)
    assert fast[:-1] == slow[:-1]  # the last entry: how many passes were skipped


def test_a_polling_loop_is_skipped_not_stepped() -> None:
    """The skipping actually happens: a poll of "position reached" over a long move executes
    a few hundred instructions, not one per 10 us of the move."""
    module = TMCLModule(kind="tmcm-6212")
    sim = Simulation([module], VirtualClock())
    for ins in [(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0), *assemble(POLL_TARGET).instructions,
                (Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0), (Opcode.RUN_APPLICATION, 0, 0, 0)]:
        module.execute(Request(1, *ins))
    sim.replan(module)
    sim.advance(10.0)
    interp = module.program.interpreter
    # the first read at or below 0 ends the second poll: a step or three past it at 100 kpps
    assert module.globals[2][9] == 50000 and -4 <= module.globals[2][10] <= 0
    assert interp.loops_skipped > 10_000  # passes of ~30 us over a ~1 s move each way
    assert interp.executed > 3 * interp.loops_skipped  # counted as if executed


def test_the_server_option_steps_every_instruction() -> None:
    """``--step-every-instruction`` (ServerConfig.skip_loops = False) is the stepping reference."""
    from tmcl_server.server import ServerConfig, build_simulation

    stepping = build_simulation(ServerConfig(endpoints={}, clock="virtual", skip_loops=False))
    skipping = build_simulation(ServerConfig(endpoints={}, clock="virtual"))
    assert not stepping.modules[0].program.skip_loops
    assert skipping.modules[0].program.skip_loops
