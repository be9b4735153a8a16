"""The TMCL bytecode interpreter: registers, flags, call stack, WAIT, interrupts, timers.

The interpreter owns program memory and the program's state, never the module: commands
that touch motors, parameters or I/O go through :class:`ModulePort`, which the module
implements.  Time is simulated integer nanoseconds passed in by the caller.  Every
instruction takes :data:`INSTRUCTION_NS`; the caller runs the program in batches with
:meth:`Interpreter.run_until` and learns from :meth:`Interpreter.next_event_ns` when it next
has to (docs/interpreter.md has the timing model and every choice the manual leaves open).
Its parts apart: WAIT in ``waits.py``, timer-cycle skipping in ``timer_cycles.py``, the CALC
arithmetic in ``arithmetic.py``, the :class:`ModulePort` hook in ``port.py``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import NamedTuple, cast

from interpreter import interrupts
from interpreter.arithmetic import calculate
from interpreter.interrupts import Trigger
from interpreter.isa import (
    CALL_STACK_DEPTH,
    CONTINUE,
    EMPTY,
    INTERNAL_OPCODES,
    INTERRUPTS,
    LOOP,
    OP_AAP,
    OP_ACO,
    OP_AGP,
    OP_CALC,
    OP_COMP,
    OP_GCO,
    OP_JA,
    OP_JC,
    OP_RFS,
    OP_SAP,
    OP_SCO,
    OP_SGP,
    OP_STOP,
    OP_WAIT,
    PROGRAM_MEMORY_SIZE,
    STOPPED,
    YIELD,
    Instruction,
)
from interpreter.port import ModulePort
from interpreter.skipping import (
    FOREVER,
    LOADS_ACCUMULATOR,
    Call,
    LoopSkipper,
)
from interpreter.timer_cycles import Timer, TimerCycles
from interpreter.waits import Wait, WaitHandling
from tmcl_spec.commands import (
    MOTOR_ALL,
    STATUS_OK,
    ApplicationStatus,
    CalcOp,
    Condition,
    ErrorFlag,
    Opcode,
    RfsType,
    WaitCondition,
)
from tmcl_spec.numbers import to_int32 as wrap32

#: Simulated time one TMCL instruction takes (a command of the main loop of the firmware).
INSTRUCTION_NS = 10_000
#: A running program asks to be run at least this often (how far it may lag a real clock).
SLICE_NS = 10_000_000

_MASK = 0xFFFF_FFFF
_SIGN = 0x8000_0000
_RFS_STATUS = RfsType.STATUS.value

_ERROR_BITS: dict[int, int] = {ErrorFlag.ETO: 1, ErrorFlag.EAL: 2, ErrorFlag.EDV: 4, ErrorFlag.EPO: 8,
               ErrorFlag.ESD: 16}
_ALL_ERRORS = sum(_ERROR_BITS.values())
#: JC condition -> error flag bit it tests.
_JC_ERROR_BIT: dict[int, int] = {Condition.ETO: 1, Condition.EAL: 2, Condition.EDV: 4, Condition.EPO: 8,
                 Condition.ESD: 16}


#: The first seven of :meth:`Interpreter.registers`: PC, accumulator, X, the two flag
#: sources, error flags, call stack.
_Registers = tuple[int, int, int, int, int, int, tuple[int, ...]]


class Context(NamedTuple):
    """What an interrupt saves and RETI restores."""

    pc: int
    accumulator: int
    x: int
    zero_source: int
    compare_source: int
    wait: Wait | None


class Interpreter(WaitHandling, TimerCycles):
    """One TMCL program and the state of its execution (not thread-safe)."""

    def __init__(self, port: ModulePort, instruction_ns: int = INSTRUCTION_NS,
                 number_of_axes: int = interrupts.NUMBER_OF_AXES,
                 memory_size: int = PROGRAM_MEMORY_SIZE) -> None:
        self.port = port
        self.instruction_ns = instruction_ns
        self.number_of_axes = number_of_axes
        #: Commands program memory holds; the address after the last is the sentinel "end".
        self.memory_size = memory_size
        #: Program memory plus one empty sentinel cell, so running off the end reads "end".
        self.code: list[Instruction] = [EMPTY] * (memory_size + 1)
        #: Counts changes to program memory (a viewer redraws its listing when it moves).
        self.memory_revision = 0
        #: Instructions executed since creation (benchmarks, tests).
        self.executed = 0
        #: The instruction in progress ends no earlier than this (0: no such hold), set by
        #: :meth:`busy_until` while the module executes it (an EEPROM write cycle).
        self._hold_ns = 0
        self.triggers: dict[int, Trigger] = {}
        self._timers: dict[int, Timer] = {}
        #: Addresses a running program stops at, before executing the instruction there (a
        #: debugger's, e.g. the dashboard's: not firmware state, so reset and power-up keep
        #: them).  While the set is empty the dispatch loop runs unchecked, at full speed.
        self.breakpoints: set[int] = set()
        #: (PC, executed) when the program was last continued: the breakpoint it continued
        #: from is not stopped at again before an instruction has run.
        self._resumed_at: tuple[int, int] | None = None
        #: Skip the passes of loops that change nothing (docs/scheduling.md); False: step every
        #: instruction (the reference the skipping is checked against).
        self.skip_loops = True
        #: How often a running program asks to be run (SLICE_NS; a virtual clock asks less).
        self.slice_ns = SLICE_NS
        #: Whether the caller must run the program at each timer's instant.  A real clock's
        #: server must (the handler runs on time); on a virtual clock the timers fire inside
        #: :meth:`run_until` at their instants anyway, so the caller need not stop there.
        self.wake_for_timers = True
        #: Passes of loops skipped so far (tests, benchmarks).
        self.loops_skipped = 0
        #: While a pass is analysed, the module commands it sends (interpreter.skipping).
        self.recording: list[Call] | None = None
        #: A kept plan's reads by PC, and the module epoch they hold under (skipping.py I13).
        self.replay: dict[int, tuple[int, int, int]] | None = None
        self.replay_epoch = 0
        self.skipper = LoopSkipper(self)
        #: The timer cycle being recorded (I12), and how many dispatches to let pass before
        #: recording one again (doubling while they cannot be skipped, as loops back off).
        self._cycle = None
        self._cycle_wait = 0
        self._cycle_backoff = 1
        #: Timer cycles skipped so far (tests, benchmarks).
        self.ticks_skipped = 0
        #: The end of the batch being run (skipping.py I15: loops skipped across the ticks of
        #: a timer that only counts go on up to it, not only to the next tick).
        self.batch_end_ns = 0
        self.power_up(0)

    def power_up(self, now_ns: int) -> None:
        """Forget what RAM holds: registers, interrupt set-up, timers; memory is kept."""
        self.reset()
        self.status = ApplicationStatus.STOP
        self.time_ns = now_ns
        self.triggers.clear()
        self._timers.clear()

    # == state =================================================================================

    def reset(self) -> None:
        """Command 131: stop; PC, stack, registers, flags and interrupt state back to zero."""
        self.status = ApplicationStatus.RESET
        self.pc = 0
        self.accumulator = 0
        self.x = 0
        # Flags are kept as the value they were computed from: ZE/NZ test the last result,
        # EQ..LE the last difference accumulator - operand of COMP.
        self.zero_source = 1
        self.compare_source = 1
        self.errors = 0
        self.stack: list[int] = []
        self.wait: Wait | None = None
        self.vectors: dict[int, int] = {}
        self.enabled = 0  # bit n: interrupt n enabled by EI n
        self.globally_enabled = False
        self.pending = 0
        self.saved: Context | None = None

    @property
    def in_interrupt(self) -> bool:
        return self.saved is not None

    def error_flag(self, flag: ErrorFlag) -> bool:
        return bool(self.errors & _ERROR_BITS[flag])

    def set_error_flag(self, flag: ErrorFlag) -> None:
        """The module reports an error condition (deviation, shutdown, ...)."""
        self.errors |= _ERROR_BITS[flag]

    # == program memory ========================================================================

    def load(self, instructions: Iterable[Instruction], start: int = 0) -> None:
        for address, ins in enumerate(instructions, start):
            self.store(address, ins)

    def store(self, address: int, ins: Instruction) -> None:
        if not 0 <= address < self.memory_size:
            raise IndexError(f"program address {address} outside 0..{self.memory_size - 1}")
        opcode, type_, motor, value = ins
        self.code[address] = Instruction(int(opcode), int(type_), int(motor), int(value))
        self.memory_revision += 1

    def erase(self) -> None:
        self.code[:self.memory_size] = [EMPTY] * self.memory_size
        self.memory_revision += 1

    def program(self) -> list[Instruction]:
        """Memory up to the last non-empty cell."""
        end = self.memory_size
        while end and self.code[end - 1].opcode == 0:
            end -= 1
        return self.code[:end]

    # == control commands ======================================================================

    def start(self, now_ns: int, address: int | None = None) -> None:
        """Command 129: run from the current PC, or from ``address``."""
        if address is not None:
            self.pc = address
            self.wait = None
            self.stack.clear()
            self.saved = None
        self.time_ns = max(self.time_ns, now_ns)
        self.status = ApplicationStatus.RUN
        self._resumed_at = (self.pc, self.executed) if address is None else None
        self._fire_timers(now_ns, fire=False)
        self.port.program_event(self.time_ns, "program_started", pc=self.pc)

    def stop(self) -> None:
        """Command 128 (the STOP instruction ends the same way)."""
        running = self.status is ApplicationStatus.RUN
        self.status = ApplicationStatus.STOP
        self.wait = None
        if running:
            self.port.program_event(self.time_ns, "program_stopped", pc=self.pc)

    def step(self, now_ns: int) -> None:
        """Command 130: execute the next instruction, then stay in step mode."""
        if self.status is not ApplicationStatus.STEP:
            self._fire_timers(now_ns, fire=False)
        self.status = ApplicationStatus.STEP
        self.time_ns = max(self.time_ns, now_ns)
        self._fire_timers(self.time_ns)
        if self.pending and self._dispatchable():
            self._dispatch()
        if self.wait is not None:
            self._resume_wait(self.time_ns + 1)  # evaluating the WAIT again is the step
        else:
            self._execute(self.time_ns + 1)

    # == interrupts ============================================================================

    def raise_interrupt(self, vector: int) -> None:
        """An interrupt source fired: latch it if the program enabled that interrupt."""
        if self.enabled >> vector & 1:
            self.pending |= 1 << vector

    def trigger_transition(self, vector: int, level: bool) -> None:
        """A switch or input changed to ``level``: raise its interrupt if bank 3 says so."""
        if self.triggers.get(vector, Trigger.OFF).fires(level):
            self.raise_interrupt(vector)

    def set_timer(self, number: int, period_ms: int, now_ns: int) -> None:
        """Bank 3 parameter 0..2 written: the timer restarts with the new period."""
        if period_ms <= 0:
            self._timers.pop(number, None)
            return
        period = period_ms * 1_000_000
        self._timers[number] = Timer(period, now_ns + period)

    def _fire_timers(self, now_ns: int, fire: bool = True) -> None:
        """Move elapsed timers past ``now_ns``, raising each one's interrupt once if ``fire``
        (when nothing ran meanwhile, the periods are skipped: no burst of stale interrupts)."""
        for number, timer in self._timers.items():
            if timer.next_ns <= now_ns:
                if fire:
                    self.raise_interrupt(interrupts.timer(number))
                missed = (now_ns - timer.next_ns) // timer.period_ns + 1
                timer.next_ns += missed * timer.period_ns

    def _next_timer_ns(self) -> int | None:
        enabled = self.enabled
        due = None
        for number, timer in self._timers.items():
            if enabled >> (interrupts.TIMER_BASE + number) & 1 and (due is None or timer.next_ns < due):
                due = timer.next_ns
        return due

    def _dispatchable(self) -> int:
        """Pending interrupts that may be taken now (bit mask)."""
        if not self.globally_enabled or self.saved is not None:
            return 0
        return self.pending & self.enabled

    def _dispatch(self) -> None:
        """Enter the handler of the highest-priority (lowest-numbered) pending interrupt."""
        while True:
            candidates = self._dispatchable()
            if not candidates:
                return
            vector = (candidates & -candidates).bit_length() - 1
            self.pending &= ~(1 << vector)
            address = self.vectors.get(vector)
            if address is None:
                continue  # no handler defined: the interrupt is dropped
            self.saved = Context(self.pc, self.accumulator, self.x, self.zero_source,
                                 self.compare_source, self.wait)
            self.wait = None
            self.pc = address
            self.port.program_event(self.time_ns, "interrupt_taken", vector=vector,
                                    address=address)
            return

    # == time ==================================================================================

    def next_event_ns(self, now_ns: int) -> int | None:
        """The next time (> ``now_ns``) the program has to run, or None while it can sleep."""
        if self.status is not ApplicationStatus.RUN:
            return None
        candidates: list[int] = []
        wait = self.wait
        if wait is None or self._dispatchable():
            slice_ns = self.slice_ns
            candidates.append((max(self.time_ns, now_ns) // slice_ns + 1) * slice_ns)
        else:
            if wait.deadline_ns is not None:
                candidates.append(wait.deadline_ns)
            if wait.recheck_ns < FOREVER:  # its condition may hold then (_resume_wait)
                candidates.append(wait.recheck_ns)
        if self.globally_enabled and self.wake_for_timers:
            timer = self._next_timer_ns()
            if timer is not None:
                candidates.append(timer)
        if not candidates:
            return None
        return max(min(candidates), now_ns + 1)

    @property
    def busy(self) -> bool:
        """Running with instructions to execute now: not stopped and not idle in a WAIT."""
        return self.status is ApplicationStatus.RUN and (
            self.wait is None or bool(self._dispatchable()))

    def busy_until(self, t_ns: int) -> None:
        """Called by the module during a command: the instruction ends no earlier than
        ``t_ns`` (the module was busy, e.g. writing its EEPROM), so the program's next
        instruction starts then."""
        self._hold_ns = max(self._hold_ns, t_ns)

    def skip_to(self, t_ns: int) -> None:
        """Let time pass to ``t_ns`` without executing (a CPU too slow for its program); when
        it resumes, elapsed timers fire once and a WAIT past its deadline ends."""
        if self.time_ns < t_ns:
            self.time_ns = t_ns

    def run_until(self, now_ns: int, end_ns: int) -> bool:
        """Run the instructions that start before ``end_ns``; the module is at ``now_ns``.

        Returns True when it stopped early, right after a command that went to the module
        (which may have scheduled an earlier event): the caller re-plans and calls again.
        """
        if self.status is not ApplicationStatus.RUN:
            return False
        if self.time_ns < now_ns:
            self.time_ns = now_ns
        return self._advance(end_ns)

    # == execution =============================================================================

    def _advance(self, end_ns: int) -> bool:
        """Execute until ``end_ns``; True if a module command ended the batch early."""
        try:
            return self._run_batch(end_ns)
        finally:
            if self._cycle is not None:  # a cycle is recorded within one batch only (I12)
                self._cycle = None
                self.recording = None
                self._give_up_cycles()  # (batches shorter than a cycle: record less often)

    def _run_batch(self, end_ns: int) -> bool:
        self.batch_end_ns = end_ns  # (loops skipped across a timer's ticks go up to it, I15)
        while self.time_ns < end_ns:
            if self._timers:
                self._fire_timers(self.time_ns)
            if self.pending and self._dispatchable():
                if (self.skip_loops and not self.breakpoints and self._timers
                        and not self.wake_for_timers):  # (a real clock stops at every tick)
                    self._timer_cycle(end_ns)
                self._dispatch()
            limit = end_ns
            if self._timers:
                timer = self._next_timer_ns()
                if timer is not None and timer < limit:
                    limit = timer
            if self.wait is not None and not self._resume_wait(limit):
                # still waiting when the next timer fires, or when the condition may change
                wake = min(limit, self.wait.recheck_ns)
                if wake >= end_ns:
                    return False
                self.time_ns = wake
                continue
            if self.skipper.inside is not None and self.recording is None:
                self.skipper.resume(limit)  # skipping.py I16: where a skip stopped inside a pass
                if self.time_ns >= limit:
                    continue
            outcome = self._execute_checked(limit) if self.breakpoints else self._execute(limit)
            if outcome == LOOP:
                outcome = self.skipper.at_loop_head(limit)
            if outcome == YIELD:
                return True
            if outcome == STOPPED:
                return False
        return False

    def flag(self, condition: int) -> bool:
        """Whether JC ``condition`` would jump now (the dispatch loop inlines this)."""
        if condition == Condition.ZE:
            return self.zero_source == 0
        if condition == Condition.NZ:
            return self.zero_source != 0
        c = self.compare_source
        if condition == Condition.EQ:
            return c == 0
        if condition == Condition.NE:
            return c != 0
        if condition == Condition.GT:
            return c > 0
        if condition == Condition.GE:
            return c >= 0
        if condition == Condition.LT:
            return c < 0
        if condition == Condition.LE:
            return c <= 0
        return bool(self.errors & _JC_ERROR_BIT.get(condition, 0))

    def _execute(self, limit_ns: int) -> int:
        """The dispatch loop: instructions starting before ``limit_ns`` (hot ones inlined)."""
        code = self.code
        pc = self.pc
        acc = self.accumulator
        zero = self.zero_source
        cmp_ = self.compare_source
        cost = self.instruction_ns
        end = self.memory_size
        count = (limit_ns - self.time_ns + cost - 1) // cost
        not_module = INTERNAL_OPCODES
        n = 0
        outcome = CONTINUE
        # Backward jumps count down to a loop analysis (never while one runs, or breakpoints).
        watch = self.skip_loops and self.recording is None and not self.breakpoints
        skipper = self.skipper
        loops = skipper.countdown
        while n < count:
            op, ty, motor, va = code[pc]
            if op == OP_CALC:
                if ty == 0:
                    acc = ((acc + va + _SIGN) & _MASK) - _SIGN
                elif ty == 1:
                    acc = ((acc - va + _SIGN) & _MASK) - _SIGN
                elif ty == 9:
                    acc = va
                else:
                    acc = calculate(ty, acc, va)
                zero = acc
                pc += 1
            elif op == OP_COMP:
                cmp_ = zero = acc - va
                pc += 1
            elif op in (OP_JC, OP_JA):
                if op == OP_JA:
                    taken = True
                elif ty == 0:
                    taken = zero == 0
                elif ty == 1:
                    taken = zero != 0
                elif ty == 2:
                    taken = cmp_ == 0
                elif ty == 3:
                    taken = cmp_ != 0
                elif ty == 4:
                    taken = cmp_ > 0
                elif ty == 5:
                    taken = cmp_ >= 0
                elif ty == 6:
                    taken = cmp_ < 0
                elif ty == 7:
                    taken = cmp_ <= 0
                else:
                    taken = bool(self.errors & _JC_ERROR_BIT.get(ty, 0))
                if not taken:
                    pc += 1
                elif va <= pc and watch and va >= 0:  # a loop: counts down to its analysis
                    pc = va
                    loops -= 1
                    if loops <= 0:
                        n += 1
                        outcome = LOOP
                        break
                else:
                    pc = va if 0 <= va < end else end
            else:
                self.pc, self.accumulator = pc, acc
                self.zero_source, self.compare_source = zero, cmp_
                if op in not_module:
                    outcome = self._execute_other(code[pc], self.time_ns + n * cost)
                else:
                    outcome = self._module_command(op, ty, motor, va, self.time_ns + n * cost)
                pc, acc = self.pc, self.accumulator
                zero, cmp_ = self.zero_source, self.compare_source
                if outcome != CONTINUE:
                    n += 1
                    break
            n += 1
        self.pc, self.accumulator = pc, acc
        self.zero_source, self.compare_source = zero, cmp_
        skipper.countdown = loops
        self.executed += n
        self.time_ns += n * cost
        if self._hold_ns:
            if self._hold_ns > self.time_ns:
                self.time_ns = self._hold_ns
            self._hold_ns = 0
        return outcome

    def _execute_checked(self, limit_ns: int) -> int:
        """The dispatch loop while breakpoints are set: one instruction at a time, stopping in
        step mode before an instruction at a breakpoint (slower, so only used then)."""
        breakpoints = self.breakpoints
        while self.time_ns < limit_ns:
            pc = self.pc
            if pc in breakpoints and (pc, self.executed) != self._resumed_at:
                self.status = ApplicationStatus.STEP
                self.port.program_event(self.time_ns, "breakpoint", pc=pc)
                return STOPPED
            outcome = self._execute(self.time_ns + 1)
            if outcome != CONTINUE:
                return outcome
        return CONTINUE

    def _execute_other(self, ins: Instruction, t: int) -> int:
        """The interpreter's own instructions the dispatch loop does not inline (the opcodes
        of ``INTERNAL_OPCODES``; the module's go to :meth:`_module_command`); ``t`` is the
        instruction's time."""
        op, ty, motor, va = ins
        if op == 0 or op == OP_STOP:  # empty memory ends a program too
            self.status = ApplicationStatus.STOP
            self.port.program_event(t, "program_stopped", pc=self.pc)
            return STOPPED
        if op == OP_WAIT:
            return self._start_wait(ty, motor, va, t)
        return _INTERNAL[op](self, ty, motor, va)

    # -- commands the interpreter handles itself ---------------------------------------------

    def calc(self, operation: int, operand: int) -> None:
        """CALC: the accumulator op= operand (also sent in direct mode, §3.5.5)."""
        self.accumulator = self.zero_source = calculate(operation, self.accumulator, operand)

    def calcx(self, operation: int) -> None:
        """CALCX: the accumulator with the X register (also sent in direct mode)."""
        if operation == CalcOp.LOAD:
            self.x = self.accumulator
        elif operation == CalcOp.SWAP:
            self.x, self.accumulator = self.accumulator, self.x
            self.zero_source = self.accumulator
        elif operation == CalcOp.NOT:
            self.x = wrap32(~self.x)  # the manual: "NOT - logical invert X register"
        else:
            self.accumulator = calculate(operation, self.accumulator, self.x)
            self.zero_source = self.accumulator

    def clear_error_flags(self, flag: int) -> None:
        """CLE: clear one error flag, or all of them (also sent in direct mode)."""
        self.errors &= ~(_ALL_ERRORS if flag == ErrorFlag.ALL else _ERROR_BITS.get(flag, 0))

    def _calcx(self, ty: int, motor: int, va: int) -> int:
        self.calcx(ty)
        self.pc += 1
        return CONTINUE

    def _address(self, value: int) -> int:
        """A jump target: outside program memory it is the empty sentinel cell (the end)."""
        return value if 0 <= value < self.memory_size else self.memory_size

    def _csub(self, ty: int, motor: int, va: int) -> int:
        if len(self.stack) < CALL_STACK_DEPTH:
            self.stack.append(self.pc + 1)
            self.pc = self._address(va)
        else:
            self.pc += 1  # stack full: the call is ignored (§3.6.18)
        return CONTINUE

    def _rsub(self, ty: int, motor: int, va: int) -> int:
        self.pc = self.stack.pop() if self.stack else self.pc + 1  # empty stack: ignored
        return CONTINUE

    def _ei(self, ty: int, motor: int, va: int) -> int:
        self.enable_interrupt(ty)
        self.pc += 1
        return INTERRUPTS

    def _di(self, ty: int, motor: int, va: int) -> int:
        self.disable_interrupt(ty)
        self.pc += 1
        return INTERRUPTS

    def _vect(self, ty: int, motor: int, va: int) -> int:
        self.vectors[ty] = self._address(va)
        self.pc += 1
        return INTERRUPTS

    def _reti(self, ty: int, motor: int, va: int) -> int:
        saved = self.saved
        if saved is None:
            self.pc += 1  # RETI outside a handler does nothing
            return CONTINUE
        self.saved = None
        (self.pc, self.accumulator, self.x, self.zero_source, self.compare_source,
         self.wait) = saved
        if self.wait is not None or (self.globally_enabled and self.pending & self.enabled):
            return INTERRUPTS  # a WAIT to resume, or the next interrupt to take
        return CONTINUE  # back where it was interrupted, nothing else to do: go on

    def _cle(self, ty: int, motor: int, va: int) -> int:
        self.clear_error_flags(ty)
        self.pc += 1
        return CONTINUE

    def enable_interrupt(self, number: int) -> None:
        if number == interrupts.GLOBAL:
            self.globally_enabled = True
        else:
            self.enabled |= 1 << number

    def disable_interrupt(self, number: int) -> None:
        if number == interrupts.GLOBAL:
            self.globally_enabled = False
        else:
            self.enabled &= ~(1 << number)
            self.pending &= ~(1 << number)

    # -- commands that go to the module --------------------------------------------------------

    def _module_command(self, op: int, ty: int, motor: int, va: int, t: int) -> int:
        """A command for the module; while a pass is analysed (interpreter.skipping) it is
        recorded with whether it changed the module and how long its answer stays the same."""
        if op == OP_AGP:  # the accumulator variants send the plain command with its value
            op, va = OP_SGP, self.accumulator
        elif op == OP_AAP:
            op, va = OP_SAP, self.accumulator
        elif op == OP_ACO:
            if motor == MOTOR_ALL:
                self.pc += 1
                return YIELD if self._hold_ns else CONTINUE
            op, va = OP_SCO, self.accumulator
        calls = self.recording
        replay = self.replay
        known = None if replay is None or calls is not None else replay.get(self.pc)
        if (known is not None and t < known[2]
                and self.port.epoch() == self.replay_epoch):  # skipping.py I13
            status, value, replan = known[0], known[1], False
        elif calls is None:
            status, value, replan = self.port.execute(t, op, ty, motor, va)
        else:
            status, value, changed, steady = self.port.probe(t, op, ty, motor, va)
            calls.append(Call(t, status, value, changed, steady, (op, ty, motor, va)))
            # a user variable's write moves no event (a timer cycle's counting, I12)
            replan = changed and not (op == OP_SGP and motor == 2)
        if status == STATUS_OK and (  # skipping.loads_accumulator, inlined: every command runs it
                (op in LOADS_ACCUMULATOR and not (op == OP_GCO and motor == MOTOR_ALL))
                or (op == OP_RFS and ty == _RFS_STATUS)):
            self.accumulator = self.zero_source = wrap32(value)
        self.pc += 1
        return YIELD if replan or self._hold_ns else CONTINUE

    # == the pass analysis' view (interpreter.skipping.Program) ================================

    def registers(self) -> tuple[object, ...]:
        """What a pass may read of the program's state (besides the module)."""
        return (self.pc, self.accumulator, self.x, self.zero_source, self.compare_source,
                self.errors, tuple(self.stack), self.saved, self.memory_revision)

    def restore(self, registers: tuple[object, ...]) -> None:
        pc, accumulator, x, zero, compare, errors, stack = cast(_Registers, registers[:7])
        self.pc, self.accumulator, self.x = pc, accumulator, x
        self.zero_source, self.compare_source, self.errors = zero, compare, errors
        self.stack = list(stack)

    def interrupt_due(self) -> bool:
        return bool(self.pending and self._dispatchable())

    def execute_one(self) -> int:
        return self._execute(self.time_ns + 1)

    def tick_wait_ends(self, limit_ns: int) -> bool:
        wait = self.wait
        assert wait is not None
        return wait.condition == WaitCondition.TICKS and self._resume_wait(limit_ns)

    def first_time_at(self, time_ns: int, opcode: int, type_: int, motor: int,
                      values: tuple[int, ...]) -> int:
        return self.port.first_time_at(time_ns, opcode, type_, motor, values)

    def epoch(self) -> int:
        return self.port.epoch()

    def user_variable(self, number: int) -> int | None:
        return self.port.user_variable(number)


_INTERNAL: dict[int, Callable[[Interpreter, int, int, int], int]] = {
    Opcode.CALCX: Interpreter._calcx,
    Opcode.CSUB: Interpreter._csub,
    Opcode.RSUB: Interpreter._rsub,
    Opcode.EI: Interpreter._ei,
    Opcode.DI: Interpreter._di,
    Opcode.VECT: Interpreter._vect,
    Opcode.RETI: Interpreter._reti,
    Opcode.CLE: Interpreter._cle,
}
