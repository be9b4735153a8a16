"""The interpreter on its own, against a scripted module port (no server, no axes)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from interpreter import interrupts
from interpreter.assembler import assemble
from interpreter.interrupts import Trigger
from interpreter.isa import CALL_STACK_DEPTH, PROGRAM_MEMORY_SIZE, WAIT_TICK_NS, Instruction
from interpreter.machine import INSTRUCTION_NS, Interpreter, calculate, wrap32
from tmcl_spec.commands import ApplicationStatus, CalcOp, Condition, ErrorFlag, Opcode

MS = 1_000_000
INT32 = st.integers(-(2**31), 2**31 - 1)


class FakePort:
    """Records module commands; axis parameters and search state are set by the test."""

    def __init__(self) -> None:
        self.commands: list[tuple[int, int, int, int, int]] = []
        self.axis: dict[tuple[int, int], int] = {}
        self.searching: set[int] = set()
        self.replies: dict[int, int] = {}
        self.events: list[tuple[int, str, dict[str, int]]] = []

    def execute(self, time_ns: int, opcode: int, type_: int, motor: int,
                value: int) -> tuple[int, int, bool]:
        self.commands.append((time_ns, opcode, type_, motor, value))
        return 100, self.replies.get(opcode, value), True

    def probe(self, time_ns: int, opcode: int, type_: int, motor: int,
              value: int) -> tuple[int, int, bool, int]:
        status, result, _ = self.execute(time_ns, opcode, type_, motor, value)
        return status, result, True, 0  # a recording port: every command counts

    def first_time_at(self, time_ns: int, opcode: int, type_: int, motor: int,
                      values: tuple[int, ...]) -> int:
        return 0

    def axis_parameter(self, time_ns: int, motor: int, number: int) -> int:
        return self.axis.get((motor, number), 0)

    def reference_search_active(self, time_ns: int, motor: int) -> bool:
        return motor in self.searching

    def steady_until(self, time_ns: int, opcode: int, type_: int, motor: int) -> int:
        return 1 << 62  # the test changes axis values between runs: something intervening

    def program_event(self, time_ns: int, kind: str, **data: int) -> None:
        self.events.append((time_ns, kind, data))

    def program_events(self, time_ns: int, period_ns: int, repeat: int, kind: str,
                       **data: int) -> None:
        for index in range(repeat):
            self.program_event(time_ns + index * period_ns, kind, **data)

    def epoch(self) -> int:
        return len(self.commands)  # every command counts as something intervening

    def user_variable(self, number: int) -> int | None:
        return None


def machine(source: str) -> tuple[Interpreter, FakePort]:
    port = FakePort()
    interp = Interpreter(port)
    interp.load(assemble(source).instructions)
    return interp, port


def run(interp: Interpreter, until_ns: int, now_ns: int = 0) -> None:
    """Drive like the module does: batches, re-planning after module commands."""
    while interp.run_until(max(now_ns, 0), until_ns):
        pass


def start(interp: Interpreter, until_ns: int) -> None:
    interp.start(0)
    run(interp, until_ns)


# -- arithmetic ---------------------------------------------------------------------------------

def c_div(a: int, b: int) -> int:
    """Reference: C99 truncating division, computed in a different way from the model."""
    if b == 0:
        return 0
    sign = -1 if (a < 0) ^ (b < 0) else 1
    return wrap32(sign * (abs(a) // abs(b)))


@given(INT32, INT32)
def test_calc_matches_32_bit_c_arithmetic(a: int, b: int) -> None:
    assert calculate(CalcOp.ADD, a, b) == wrap32(a + b)
    assert calculate(CalcOp.SUB, a, b) == wrap32(a - b)
    assert calculate(CalcOp.MUL, a, b) == wrap32(a * b)
    assert calculate(CalcOp.DIV, a, b) == c_div(a, b)
    if b:
        assert calculate(CalcOp.MOD, a, b) == wrap32(a - b * c_div(a, b))
        assert abs(calculate(CalcOp.MOD, a, b)) < abs(b) or (a, b) == (-(2**31), -1)
    assert calculate(CalcOp.AND, a, b) == a & b
    assert calculate(CalcOp.OR, a, b) == a | b
    assert calculate(CalcOp.XOR, a, b) == a ^ b
    assert calculate(CalcOp.NOT, a, b) == ~a
    assert calculate(CalcOp.LOAD, a, b) == b


def test_division_and_modulo_by_zero_do_not_crash() -> None:
    interp, _ = machine("""
        CALC LOAD, 1234
        CALC DIV, 0
        AGP 0, 2
        CALC LOAD, -77
        CALC MOD, 0
        AGP 1, 2
        CALCX LOAD
        CALC LOAD, 5
        CALCX SWAP
        CALC LOAD, 9
        CALCX LOAD
        CALC LOAD, 0
        CALCX SWAP
        CALCX DIV
        STOP
    """)
    start(interp, 10 * MS)
    port = interp.port
    assert isinstance(port, FakePort)
    agp = [c for c in port.commands if c[1] == Opcode.SGP]
    assert [c[4] for c in agp] == [0, -77]  # x/0 -> 0, x%0 -> x (ARM SDIV without the trap)
    assert interp.accumulator == 0
    assert interp.status is ApplicationStatus.STOP


def test_calc_wraps_and_int_min_divided_by_minus_one() -> None:
    interp, _ = machine(f"""
        CALC LOAD, {2**31 - 1}
        CALC ADD, 1
        CALCX LOAD
        CALC DIV, -1
        STOP
    """)
    start(interp, MS)
    assert interp.x == -(2**31)
    assert interp.accumulator == -(2**31)


def test_calcx_operates_with_the_x_register() -> None:
    interp, _ = machine("""
        CALC LOAD, 6
        CALCX LOAD       // X = 6
        CALC LOAD, 7
        CALCX MUL        // A = 42
        CALCX NOT        // X = ~6 (the manual: NOT inverts X)
        CALCX SWAP       // A = -7, X = 42
        STOP
    """)
    start(interp, MS)
    assert (interp.accumulator, interp.x) == (-7, 42)


@pytest.mark.parametrize(("value", "operand", "taken"), [
    (5, 5, {Condition.EQ, Condition.GE, Condition.LE, Condition.ZE}),
    (6, 5, {Condition.NE, Condition.GT, Condition.GE, Condition.NZ}),
    (4, 5, {Condition.NE, Condition.LT, Condition.LE, Condition.NZ}),
    (-(2**31), 2**31 - 1, {Condition.NE, Condition.LT, Condition.LE, Condition.NZ}),
])
def test_comp_flags(value: int, operand: int, taken: set[Condition]) -> None:
    interp, _ = machine(f"CALC LOAD, {value}\nCOMP {operand}\nSTOP")
    start(interp, MS)
    compare = [c for c in Condition if c <= Condition.LE]
    assert {c for c in compare if interp.flag(c)} == taken


def test_reading_commands_load_the_accumulator_and_zero_flag() -> None:
    interp, port = machine("""
        GIO 0, 2
        JC NZ, High
        CALC LOAD, 100
        STOP
    High:
        CALC LOAD, 200
        STOP
    """)
    port.replies[Opcode.GIO] = 1
    start(interp, MS)
    assert interp.accumulator == 200
    port.replies[Opcode.GIO] = 0
    interp.start(interp.time_ns, 0)
    run(interp, 2 * MS)
    assert interp.accumulator == 100


def test_module_commands_carry_their_instruction_time() -> None:
    interp, port = machine("SAP 4, 0, 1000\nCALC LOAD, 3\nAAP 5, 1\nACO 2, 0\nAGP 7, 2\nSTOP")
    start(interp, MS)
    assert port.commands == [
        (0, Opcode.SAP, 4, 0, 1000),
        (2 * INSTRUCTION_NS, Opcode.SAP, 5, 1, 3),
        (3 * INSTRUCTION_NS, Opcode.SCO, 2, 0, 3),
        (4 * INSTRUCTION_NS, Opcode.SGP, 7, 2, 3),
    ]
    assert interp.time_ns == 6 * INSTRUCTION_NS


# -- flow ---------------------------------------------------------------------------------------

def test_subroutine_stack_overflow_is_ignored() -> None:
    depth = CALL_STACK_DEPTH + 2
    calls = "\n".join(f"L{n}: CALC ADD, 1\n CSUB L{n + 1}" for n in range(depth))
    interp, _ = machine(f"CALC LOAD, 0\n{calls}\nL{depth}: STOP")
    start(interp, MS)
    assert interp.accumulator == depth  # every level ran: ignored calls fall through
    assert len(interp.stack) == CALL_STACK_DEPTH


def test_rsub_on_empty_stack_is_ignored() -> None:
    interp, _ = machine("CALC LOAD, 1\nRSUB\nCALC ADD, 1\nSTOP")
    start(interp, MS)
    assert interp.accumulator == 2
    assert interp.status is ApplicationStatus.STOP


def test_subroutines_return_to_the_caller() -> None:
    interp, _ = machine("""
        CALC LOAD, 0
        CSUB Add3
        CSUB Add3
        STOP
    Add3:
        CALC ADD, 1
        CSUB Add2
        RSUB
    Add2:
        CALC ADD, 2
        RSUB
    """)
    start(interp, MS)
    assert interp.accumulator == 6
    assert interp.stack == []


def test_running_off_the_end_or_jumping_outside_memory_stops() -> None:
    interp, _ = machine("CALC LOAD, 1")
    start(interp, MS)
    assert interp.status is ApplicationStatus.STOP
    interp.code[0] = Instruction(Opcode.JA, 0, 0, PROGRAM_MEMORY_SIZE + 5)
    interp.start(interp.time_ns, 0)
    run(interp, 2 * MS)
    assert interp.status is ApplicationStatus.STOP


# -- WAIT ---------------------------------------------------------------------------------------

def test_wait_ticks_takes_ten_ms_per_tick() -> None:
    interp, port = machine("WAIT TICKS, 0, 50\nSIO 0, 2, 1\nSTOP")
    start(interp, 499 * MS)
    assert port.commands == []
    assert interp.wait is not None
    assert interp.next_event_ns(interp.time_ns) == 50 * WAIT_TICK_NS
    run(interp, 501 * MS, now_ns=499 * MS)
    assert port.commands == [(500 * MS, Opcode.SIO, 0, 2, 1)]


def test_wait_timeout_sets_eto_and_cle_clears_it() -> None:
    interp, port = machine("""
        WAIT POS, 0, 10      // the axis never arrives: 100 ms timeout
        JC ETO, TimedOut
        STOP
    TimedOut:
        SGP 0, 2, 1
        CLE ETO
        JC ETO, Still
        SGP 1, 2, 1
        STOP
    Still:
        STOP
    """)
    start(interp, 99 * MS)
    assert not interp.error_flag(ErrorFlag.ETO)
    run(interp, 200 * MS, now_ns=99 * MS)
    # WAIT gives up at 100 ms; JC ETO runs then, SGP one instruction later.
    assert [(c[0], c[2]) for c in port.commands] == [(100 * MS + INSTRUCTION_NS, 0),
                                                     (100 * MS + 4 * INSTRUCTION_NS, 1)]
    assert not interp.error_flag(ErrorFlag.ETO)


def test_wait_pos_ends_when_the_axis_reports_position_reached() -> None:
    interp, port = machine("WAIT POS, 2, 0\nSIO 1, 2, 1\nSTOP")
    start(interp, 50 * MS)
    assert interp.wait is not None and interp.next_event_ns(50 * MS) is None
    port.axis[(2, 8)] = 1
    run(interp, 80 * MS, now_ns=70 * MS)
    assert port.commands == [(70 * MS, Opcode.SIO, 1, 2, 1)]
    assert not interp.error_flag(ErrorFlag.ETO)


@pytest.mark.parametrize(("condition", "parameter"), [("REFSW", 9), ("LIMSW", 11), ("LIMSW", 10)])
def test_wait_for_switches(condition: str, parameter: int) -> None:
    interp, port = machine(f"WAIT {condition}, 1, 0\nSTOP")
    start(interp, 10 * MS)
    assert interp.wait is not None
    port.axis[(1, parameter)] = 1
    run(interp, 20 * MS, now_ns=10 * MS)
    assert interp.wait is None and interp.status is ApplicationStatus.STOP


def test_wait_rfs_waits_for_the_reference_search() -> None:
    interp, port = machine("RFS START, 0\nWAIT RFS, 0, 0\nSTOP")
    port.searching.add(0)
    start(interp, 10 * MS)
    assert interp.wait is not None
    port.searching.clear()
    run(interp, 20 * MS, now_ns=10 * MS)
    assert interp.status is ApplicationStatus.STOP


# -- interrupts ---------------------------------------------------------------------------------

HANDLERS = """
    VECT 3, Target0
    VECT 4, Target1
    EI 3
    EI 4
    EI 255
    CALC LOAD, 7
Idle:
    JA Idle
Target0:
    CALC LOAD, 30
    AGP 0, 2
    RETI
Target1:
    CALC LOAD, 40
    AGP 1, 2
    COMP 40
    RETI
"""


def agp_log(port: FakePort) -> list[tuple[int, int]]:
    return [(c[2], c[4]) for c in port.commands if c[1] == Opcode.SGP and c[3] == 2]


def test_interrupt_priority_and_no_nesting() -> None:
    interp, port = machine(HANDLERS)
    start(interp, MS)
    interp.raise_interrupt(interrupts.target_reached(1))
    interp.raise_interrupt(interrupts.target_reached(0))
    run(interp, 2 * MS, now_ns=MS)
    assert agp_log(port) == [(0, 30), (1, 40)]  # vector 3 first (lower number), then 4


def test_no_nesting_an_interrupt_during_a_handler_waits_for_reti() -> None:
    interp, port = machine(HANDLERS)
    start(interp, MS)
    interp.raise_interrupt(interrupts.target_reached(1))
    interp.run_until(MS, MS + 1)  # enter the handler of vector 4 and run its first command
    assert interp.in_interrupt
    interp.raise_interrupt(interrupts.target_reached(0))
    run(interp, 2 * MS, now_ns=MS)
    assert agp_log(port) == [(1, 40), (0, 30)]


def test_context_is_restored_by_reti() -> None:
    interp, _ = machine(HANDLERS)
    start(interp, MS)
    before = (interp.accumulator, interp.x, interp.flag(Condition.EQ), interp.pc)
    interp.raise_interrupt(interrupts.target_reached(1))
    run(interp, 2 * MS, now_ns=MS)
    assert not interp.in_interrupt
    after = (interp.accumulator, interp.x, interp.flag(Condition.EQ))
    assert after == before[:3]
    assert interp.code[interp.pc].opcode == Opcode.JA


def test_disabled_or_unvectored_interrupts_are_not_taken() -> None:
    interp, port = machine(HANDLERS.replace("    EI 4\n", ""))
    start(interp, MS)
    interp.raise_interrupt(interrupts.target_reached(1))  # not enabled
    interp.raise_interrupt(interrupts.stall(0))  # no vector
    run(interp, 2 * MS, now_ns=MS)
    assert agp_log(port) == []
    interp.disable_interrupt(interrupts.GLOBAL)
    interp.raise_interrupt(interrupts.target_reached(0))
    run(interp, 3 * MS, now_ns=2 * MS)
    assert agp_log(port) == []  # latched while globally off ...
    interp.enable_interrupt(interrupts.GLOBAL)
    run(interp, 4 * MS, now_ns=3 * MS)
    assert agp_log(port) == [(0, 30)]  # ... and taken once interrupts are on again


def test_revectoring_inside_a_handler() -> None:
    interp, port = machine("""
        VECT 0, First
        SGP 0, 3, 10  // the module would start timer 0; the test does it below
        EI 0
        EI 255
    Idle: JA Idle
    First:
        SGP 0, 2, 1
        VECT 0, Second
        RETI
    Second:
        SGP 0, 2, 2
        VECT 0, First
        RETI
    """)
    interp.set_timer(0, 10, 0)
    start(interp, 45 * MS)
    assert [v for n, v in agp_log(port) if n == 0] == [1, 2, 1, 2]


def test_timer_interrupt_period_and_wait_survives_an_interrupt() -> None:
    interp, port = machine("""
        VECT 1, Tick
        EI 1
        EI 255
        WAIT TICKS, 0, 100   // one second, interrupted by the timer five times
        SIO 0, 2, 1
        STOP
    Tick:
        CALC ADD, 1
        RETI
    """)
    interp.set_timer(1, 200, 0)
    start(interp, 2000 * MS)
    sio = [c for c in port.commands if c[1] == Opcode.SIO]
    assert sio == [(1000 * MS + 3 * INSTRUCTION_NS, Opcode.SIO, 0, 2, 1)]
    assert interp.accumulator == 0  # the handler's CALC was undone by RETI
    assert interp.executed == 6 + 5 * 2  # main program + handler runs at 200, 400, ..., 1000 ms


def test_switch_trigger_transitions() -> None:
    interp, _ = machine("VECT 28, H\nEI 28\nEI 255\nIdle: JA Idle\nH: RETI")
    vector = interrupts.right_switch(0)
    start(interp, MS)
    interp.trigger_transition(vector, True)
    assert not interp.pending  # trigger "off" by default
    interp.triggers[vector] = Trigger.HIGH_LOW
    interp.trigger_transition(vector, True)
    assert not interp.pending
    interp.trigger_transition(vector, False)
    assert interp.pending == 1 << vector


def test_reset_clears_registers_stack_and_interrupts() -> None:
    interp, _ = machine(HANDLERS)
    start(interp, MS)
    interp.reset()
    assert (interp.pc, interp.accumulator, interp.x, interp.stack, interp.errors) == (0, 0, 0, [], 0)
    assert interp.status is ApplicationStatus.RESET
    assert not interp.globally_enabled and not interp.enabled and not interp.vectors


def test_step_executes_one_instruction() -> None:
    interp, _ = machine("CALC LOAD, 1\nCALC ADD, 1\nWAIT TICKS, 0, 1\nCALC ADD, 1\nSTOP")
    interp.step(0)
    assert (interp.pc, interp.accumulator) == (1, 1)
    interp.step(0)
    assert (interp.pc, interp.accumulator, interp.status) == (2, 2, ApplicationStatus.STEP)
    interp.step(0)  # starts the WAIT
    assert interp.wait is not None and interp.pc == 2
    interp.step(5 * MS)  # too early: still waiting
    assert interp.wait is not None and interp.pc == 2
    interp.step(20 * MS)
    assert interp.wait is None and interp.pc == 3



COUNTING_LOOP = """
    CALC LOAD, 0
Loop:
    CALC ADD, 1
    COMP 1000
    JC LT, Loop
    STOP
"""


def test_a_breakpoint_stops_the_program_in_step_mode_before_the_instruction() -> None:
    interp, port = machine(COUNTING_LOOP)
    interp.breakpoints.add(2)  # COMP: the first time after one CALC ADD
    start(interp, 10 * MS)
    assert (interp.status, interp.pc, interp.accumulator) == (ApplicationStatus.STEP, 2, 1)
    assert interp.executed == 2 and interp.time_ns == 2 * INSTRUCTION_NS
    assert port.events[-1] == (2 * INSTRUCTION_NS, "breakpoint", {"pc": 2})
    assert interp.next_event_ns(interp.time_ns) is None and not interp.busy  # nothing runs


def test_step_from_a_breakpoint_runs_one_instruction_and_continue_stops_there_again() -> None:
    interp, _ = machine(COUNTING_LOOP)
    interp.breakpoints.add(2)
    start(interp, 10 * MS)
    interp.step(interp.time_ns)  # the COMP at the breakpoint itself
    assert (interp.status, interp.pc, interp.accumulator, interp.executed) == (
        ApplicationStatus.STEP, 3, 1, 3)
    interp.start(interp.time_ns)  # continue: JC, CALC ADD, then the breakpoint again
    run(interp, 10 * MS)
    assert (interp.status, interp.pc, interp.accumulator, interp.executed) == (
        ApplicationStatus.STEP, 2, 2, 5)
    interp.start(interp.time_ns)  # continuing from the breakpoint itself does not stop at once
    run(interp, 10 * MS)
    assert (interp.pc, interp.accumulator, interp.executed) == (2, 3, 8)
    interp.breakpoints.clear()
    interp.start(interp.time_ns)
    run(interp, 100 * MS)
    assert (interp.status, interp.accumulator) == (ApplicationStatus.STOP, 1000)


def test_running_from_an_address_with_a_breakpoint_stops_there_first() -> None:
    interp, port = machine(COUNTING_LOOP)
    interp.breakpoints.add(0)
    interp.start(0, 0)
    run(interp, MS)
    assert (interp.status, interp.pc, interp.executed) == (ApplicationStatus.STEP, 0, 0)
    assert [kind for _, kind, _ in port.events] == ["program_started", "breakpoint"]


def test_a_breakpoint_in_an_interrupt_handler_stops_on_entry() -> None:
    interp, port = machine("""
        VECT 0, Handler
        EI 0
        EI 255
    Idle:
        JA Idle
    Handler:
        CALC ADD, 1
        RETI
    """)
    interp.breakpoints.add(4)  # Handler
    interp.start(0)
    interp.set_timer(0, 5, 0)
    run(interp, 20 * MS)
    assert (interp.status, interp.pc, interp.in_interrupt) == (ApplicationStatus.STEP, 4, True)
    assert [kind for _, kind, _ in port.events][-2:] == ["interrupt_taken", "breakpoint"]
    assert port.events[-1][0] == 5 * MS

def test_program_memory_bounds() -> None:
    interp = Interpreter(FakePort())
    with pytest.raises(IndexError):
        interp.store(PROGRAM_MEMORY_SIZE, Instruction(Opcode.STOP))
    interp.store(PROGRAM_MEMORY_SIZE - 1, Instruction(Opcode.STOP))
    assert len(interp.program()) == PROGRAM_MEMORY_SIZE
    interp.erase()
    assert interp.program() == []


def test_skipped_time_runs_no_instructions_and_fires_a_timer_once() -> None:
    interp, port = machine("""
        VECT 0, Tick
        EI 0
        EI 255
    Loop: JA Loop
    Tick: GGP 0, 2
        RETI
    """)
    interp.set_timer(0, 1, 0)  # every millisecond
    start(interp, MS)  # set up, looping just before the first tick
    interp.skip_to(100 * MS)  # the CPU fell behind: 99 ms pass without instructions
    executed = interp.executed
    run(interp, 100 * MS + 50_000, now_ns=100 * MS)
    assert interp.executed == executed + 50_000 // INSTRUCTION_NS
    # the 99 missed ticks raise the interrupt once, when the program resumes
    assert [c for c in port.commands if c[1] == Opcode.GGP] == [(100 * MS, Opcode.GGP, 0, 2, 0)]


@given(st.lists(st.tuples(st.sampled_from([op for op in CalcOp if op <= CalcOp.LOAD]), INT32),
                min_size=1, max_size=30), INT32)
def test_inlined_dispatch_agrees_with_the_reference_arithmetic(steps: list[tuple[int, int]],
                                                              operand: int) -> None:
    """The dispatch loop inlines ADD/SUB/LOAD and the JC tests; check it against calculate()."""
    source = "\n".join(f"CALC {CalcOp(op).name}, {value}" for op, value in steps)
    conditions = [c for c in Condition if c <= Condition.LE]
    jumps = "\n".join(f"JC {c.name}, T{c.name}\nJA N{c.name}\nT{c.name}: SGP {int(c)}, 2, 1\n"
                      f"N{c.name}:" for c in conditions)
    interp, port = machine(f"{source}\nCOMP {operand}\n{jumps}\nSTOP")
    start(interp, 100 * MS)
    expected = 0
    for op, value in steps:
        expected = calculate(op, expected, value)
    assert interp.accumulator == expected
    taken = {c for c in conditions if (c, 1) in agp_log(port)}
    difference = expected - operand
    assert taken == {c for c, holds in (
        (Condition.ZE, difference == 0), (Condition.NZ, difference != 0),
        (Condition.EQ, difference == 0), (Condition.NE, difference != 0),
        (Condition.GT, difference > 0), (Condition.GE, difference >= 0),
        (Condition.LT, difference < 0), (Condition.LE, difference <= 0)) if holds}


def test_program_events_start_interrupt_and_stop():
    vm, port = machine("""
        VECT 0, Tick
        SGP 0, 3, 5
        EI 0
        EI 255
        WAIT TICKS, 0, 1
        STOP
    Tick:
        RETI
    """)
    vm.set_timer(0, 5, 0)
    vm.start(0, 0)
    while vm.run_until(vm.time_ns, 50 * MS):  # True: it yielded after a module command
        pass
    kinds = [(kind, data) for _, kind, data in port.events]
    assert kinds[0] == ("program_started", {"pc": 0})
    assert ("interrupt_taken", {"vector": 0, "address": 6}) in kinds
    assert kinds[-1] == ("program_stopped", {"pc": 5})
    times = [t for t, _, _ in port.events]
    assert times == sorted(times)


def test_the_opcodes_the_interpreter_keeps_to_itself_are_isa_s_list() -> None:
    """interpreter.isa.INTERNAL_OPCODES (what the pass analysis treats as not a module
    command) is exactly what the dispatch loop executes itself."""
    from interpreter import machine
    from interpreter.isa import INTERNAL_OPCODES, OP_STOP, OP_WAIT

    assert {0, OP_STOP, OP_WAIT, *machine._INTERNAL} == INTERNAL_OPCODES
