"""Loop skipping: the passes of a loop that are certain to repeat are left out, exactly.

Most TMCL programs poll (``GAP 8`` / ``COMP 1`` / ``JC NE`` until a move ends).  Each
instruction costs 10 µs of simulated time and microseconds of Python, so stepping them cannot
be much faster than real time.  Like an emulator's idle-loop detection (mGBA, Dolphin), the
interpreter analyses one pass of a loop, instruction by instruction, while the module says of
every command the pass sends whether it changed anything and until when its answer holds
(:meth:`interpreter.machine.ModulePort.probe`), and then leaves out the passes certain to do
the same: time and the instruction count advance as if they had run.  docs/scheduling.md
("Loops that change nothing") tells the story; the proof that the result is exactly what
stepping every instruction gives is these invariants, each cited where the code relies on it:

I1. Nothing intervenes within a batch.  A batch (one ``Interpreter._advance`` up to its
    ``limit``) ends no later than the module's next hardware event (the caller's ``end_ns``),
    the next timer interrupt, and the clock; host requests, world changes and faults are
    applied between batches, never inside one, and a program command that may move an event
    ends the batch (``YIELD``).  Inside a batch the module changes only through the program.
I2. A repeat is a repeat.  The interpreter is deterministic in its registers
    (:meth:`Program.registers`: PC, accumulator, X, flags, error flags, stack, interrupt
    context, program memory) and the answers it gets.  A pass that changed nothing (no call
    ``changed``) and left the registers as it found them, run again from them while every
    command answers the same, does exactly the same again.
I3. Steady answers.  A call's ``steady_until``: executed again at any time before it, with
    nothing intervening (I1), the command answers the same and changes nothing.  A WAIT
    whose condition holds falls through, so its reads are answers the pass depends on like
    any command's: each WAIT a pass executes is one call (its condition, steady as long as
    all its reads are, ``ModulePort.steady_until``); one whose condition does not hold
    waits, and the pass is not analysed.
I4. The ceiling.  Pass k >= 1 after the analysed pass (which began at ``start``) sends the
    command at offset o at ``start + k * period + o``; its answer is certain (I3) while that
    is < ``steady_until``, i.e. for k <= ceil((steady_until - start - o) / period) - 1.  The
    pass must also end by the batch's ``limit``: k <= (limit - start) // period - 1.
I5. Flips are found on time.  A pass that reads moving values (a position, a speed) and
    uses them only through COMP and JC (:func:`boundaries`), directly or through CALC/CALCX
    that keep them exactly invertible (I14), takes a path that is a function of how each
    value compares with each boundary (<, =, >).  The axis answers when
    it first compares otherwise with one of them (``first_time_at``, axes/forecast.py F3-F8):
    where the value meets a boundary, or, for AP 1, where it wraps (2**31 - 1 -> -2**31: the
    comparison flips there without meeting its boundary, F3), counted from the read's own
    instant (a later command of the pass to the same axis has brought the axis further,
    F7), over a stretch where a speed is monotonic (F4).  Every pass whose read comes
    strictly before that instant compares as the analysed one did and takes its path, so
    stopping there is never late.
I6. What the next pass reads first it finds as this one did.  A register the pass reads
    before writing must be left as it was found and must not hold a moving read's value
    (equal now by chance, it would differ in the passes left out).
I7. One real pass is kept.  The passes left out before a flip do not compute their moving
    reads, so the registers hold the analysed pass's values, not the last left-out pass's;
    the last whole pass before ``limit`` is therefore stepped, and whenever the batch ends
    (and a host, an interrupt or the next analysis can look) the registers are stepping's.
I8. A WAIT TICKS inside a pass lasts the same in every pass (its deadline is a fixed offset
    from the WAIT's instant), so it is part of the pass's period (its call reads nothing and
    holds forever, I3).
I9. A loop that touches nothing but registers (no command, no WAIT) is, by I2 with no
    answers to hold, skipped again without an analysis whenever its registers are the same.
I10. A plan survives a batch boundary.  The module counts everything that may change a
    pass's answers from outside the loop (``ModulePort.epoch``): every host request, every
    command that changed something (the program's own included), every module event
    handled, every world change, power-up.  A pass found skippable is kept (:class:`_Plan`)
    with the epoch after it, the registers it left as it found them and the user variables
    it read (a program's write of a plain user variable, a timer handler counting, is not
    counted: ``ModulePort.user_variable`` is compared instead).  At a later loop head at the
    same address, with the same epoch, registers and variables and no interrupt due, every
    call answers as it did in the analysis: its ``steady_until`` and its flip (I3, I5) are
    absolute instants promised "nothing intervening", which the unchanged epoch witnesses,
    and the path is the analysed one (I2, I6).  So the passes from there are skipped by I4
    as if the analysed pass had begun one period earlier, the last whole one still stepped
    where I7 asks.  A batch end at which nothing intervenes (an ``advance`` returning, a
    timer tick whose handler only counts, the end of a recorder's span of samples, which
    reads and changes nothing) costs no analysis.
I11. The millisecond tick (GGP 132) is arithmetic on the instant: it answers the same until
    the next millisecond (I3), and it is also a moving read whose flip the module forecasts
    exactly (``ModulePort.first_time_at``: it meets every value above the one read, one a
    millisecond, and wraps to 0 past 2**31 - 1; only SGP 132 and a power-up move its origin,
    and both count in the epoch).  A pass that reads it is skipped to its flip (I5) when it
    only compares it, else to its next millisecond (I4).
I12. A timer whose handler only counts is applied for k ticks at once.  A handler that is
    nothing but ``GGP n, 2; CALC ADD|SUB, c; AGP n, 2`` groups (one per plain user variable)
    and RETI leaves the registers as it found them (RETI restores PC, accumulator, X and
    flags) and adds c to each variable n, whatever they hold.  One whole cycle, from one
    dispatch of the timer to the next, is recorded like a pass (every command with its
    answer, I3).  If the next dispatch finds the registers, the epoch (I10) and the period
    as the recorded one began, no WAIT in progress and nothing else pending, every command of
    the cycle but the handler's counting changed nothing, no other command read or wrote a
    counted variable, and each answer is steady over the cycles to skip (I4 with the timer's
    period for the pass's), then each of those cycles does exactly what the recorded one
    did: the same instructions at the same offsets, the same answers, and the variables one
    c further.  They are skipped at once (time, instruction count, the timer's next tick,
    each dispatch's ``interrupt_taken`` event at its instant, the variables k c further),
    ending no later than the batch (I1); the dispatch after them is executed.  The events
    go out as one run (``ModulePort.program_events``): a module's listeners get each one at
    its instant, its run listeners the run as one event, so skipped ticks cost those nothing
    a tick.
I13. A kept plan answers its reads.  While the epoch is the plan's (I10), a GAP or GIO the
    analysed pass sent from a PC, answered OK and changing nothing, answers the same at any
    instant before its ``steady_until`` (I3) wherever the program executes that PC: a read
    changes nothing in the module (F6, T3), so the passes that are still stepped (the one
    I7 keeps, the part of a pass before a batch's end) take those answers from the plan
    instead of the module.
I14. A moving read through CALC/CALCX compares as the read does with its own boundaries.
    A register follows the read r as ``int32(s * r + o)`` (s = +-1, o known exactly: CALC
    ADD/SUB/NOT/MUL by +-1 and CALCX ADD/SUB with a register whose value is known in every
    pass: the pass's start value, which I6 keeps, or one it loaded from a steady read or a
    constant; CALCX LOAD/SWAP/NOT move it).  Modulo 2**32 each value c has exactly one
    r with ``s * r + o = c``, so between the r at which it meets the COMP's value and the
    two on either side of its own wrap (2**31 - 1 -> -2**31: ``GAP 1; CALC ADD 1000;
    COMP 0`` turns from greater to less there) it compares alike, and those r are the
    read's boundaries (``Affine.flips``).  Anything else a moving read goes through
    (MUL, DIV, MOD, AND, OR, XOR, a second moving read, a value not known) is stepped.
I15. A loop is skipped across the ticks of a timer whose handler only counts.  When the
    batch's ``limit`` is the next tick of the only timer, its handler is I12's (or there is
    none: the interrupt is dropped), it counts in plain variables the pass neither reads
    nor writes, the pass lasts its instructions (no WAIT that waits: ``period == length *
    cost``), nothing is pending, no handler or WAIT is in progress and interrupts are on,
    then a dispatch interrupts the loop between two of its instructions and RETI resumes it
    with the registers it saved (PC, accumulator, X, flags; the handler touches no other),
    having changed only the counters, which the loop does not see.  So the loop's
    instructions run as without the timer, each later by the handlers taken before it:
    main instruction n starts at ``start + n * cost`` plus ``handler * cost`` for each
    dispatch before it, and the dispatches come at the first instruction boundary at or
    after each tick (``TickSchedule``: a period that is a whole number of instructions
    keeps the boundaries on one grid, so the dispatches are exactly ``period`` apart and
    ``between`` loop instructions separate them).  I4 then holds with those instants: a
    command of pass k is sent before its horizon iff its main instruction starts before
    it (``TickSchedule.last_before``), and the passes, with the ones I7 keeps, end by the
    batch's end, the next hardware event or the clock (I1), not the tick.  The ticks taken
    among the passes left out are applied as I12 applies its cycles (time, instruction
    count, the timer's next tick, the counters, the events as one run); a tick due at the
    landing is taken by the dispatch loop, as stepping takes it.  While a loop is skipped
    across the ticks, I12's cycles are not recorded (recording one steps the loop for a
    whole period).
I16. A skip stops where stepping would, inside a pass.  A pass that repeats whole (every
    answer steady, I2: no flip, so no pass I7 must keep; every register as it found it; no
    WAIT that waits, so instruction i of a pass starts ``i * cost`` after its head; no
    handler in progress) takes the same states in every pass: before its instruction i, the
    registers the analysed pass had there (``_Plan.states``, recorded by the analysis).
    Instruction n counted from a head at ``began`` starts at ``began + n * cost``; stepping
    runs those that start before the batch's ``limit``, and the command at offset o of pass
    k answers as analysed while it starts before its horizon (I3, I4).  So the program is
    put straight into the state before the first instruction that either starts at or after
    ``limit`` or is a command at or past its horizon (``LoopSkipper._glide``; that one is
    then executed by the dispatch loop, against the module), instead of stepping the last
    part of a pass to ``limit``: no module command is left out that stepping would have
    answered otherwise, and a read changes nothing in the module (F6, T3).  The next batch
    goes on from there without stepping to the head (``LoopSkipper.resume``) if nothing
    intervened: the same instant, epoch (I10; a pass without commands needs none, I9),
    registers as the recorded state there, and no interrupt due.  A timer's tick ending the
    batch is taken at the instruction boundary stepping takes it at.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Protocol

from interpreter.isa import (
    CONTINUE,
    INTERNAL_OPCODES,
    OP_AAP,
    OP_ACO,
    OP_AGP,
    OP_CALC,
    OP_CALCX,
    OP_COMP,
    OP_GAP,
    OP_GCO,
    OP_JA,
    OP_JC,
    OP_RFS,
    OP_WAIT,
    WAITING,
    Instruction,
)
from tmcl_spec.commands import MOTOR_ALL, STATUS_OK, CalcOp, Opcode, RfsType
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import GP

#: A loop is analysed after this many backward jumps; while it cannot be skipped, the wait
#: doubles up to LOOP_BACKOFF_MAX (docs/scheduling.md, "Loops that change nothing").
LOOP_PROBE_AFTER = 2
LOOP_BACKOFF_MAX = 1024
#: A pass longer than this many instructions is not analysed.
MAX_PASS = 256
#: "Steady until something intervenes" (axes.interface.FOREVER's value).
FOREVER = 1 << 62

#: Commands that, in a program, load the value they read into the accumulator.
LOADS_ACCUMULATOR = frozenset({Opcode.GAP.value, Opcode.GGP.value, Opcode.GIO.value, OP_GCO})
_RFS_STATUS = RfsType.STATUS.value
OP_GGP = Opcode.GGP.value
OP_SGP = Opcode.SGP.value
OP_RETI = Opcode.RETI.value
_TICK_READ = (OP_GGP, int(GP.TICK_TIMER), 0)


def loads_accumulator(op: int, ty: int, motor: int) -> bool:
    """Whether a command's answer goes to the accumulator (when it succeeds): the reads, but
    not GCO of all coordinates, and RFS STATUS."""
    return ((op in LOADS_ACCUMULATOR and not (op == OP_GCO and motor == MOTOR_ALL))
            or (op == OP_RFS and ty == _RFS_STATUS))


@dataclass(slots=True)
class Call:
    """One module command of a pass being analysed."""

    time_ns: int
    status: int
    value: int
    changed: bool
    steady_until: int
    request: tuple[int, int, int, int]  # opcode, type, motor, value sent


class Program(Protocol):
    """What the analysis needs of the interpreter it serves (``interpreter.machine``)."""

    code: list[Instruction]
    pc: int
    time_ns: int
    executed: int
    loops_skipped: int
    #: While a pass is analysed, every module command is appended here (None otherwise).
    recording: list[Call] | None
    #: Simulated time one instruction takes.
    instruction_ns: int
    #: The end of the batch being run (I15).
    batch_end_ns: int
    #: A kept plan's reads by PC, (status, value, steady until), with the epoch they hold
    #: under (I13); None: every command goes to the module.
    replay: dict[int, tuple[int, int, int]] | None
    replay_epoch: int

    def registers(self) -> tuple[object, ...]:
        """What a pass may read of the program's state besides the module (I2)."""
        ...

    def restore(self, registers: tuple[object, ...]) -> None:
        """Set the registers to what :meth:`registers` returned (I16: a state of the pass)."""
        ...

    def interrupt_due(self) -> bool:
        """An interrupt is pending and may be taken now."""
        ...

    def execute_one(self) -> int:
        """Execute the instruction at the PC; the outcome (``interpreter.isa``)."""
        ...

    def tick_wait_ends(self, limit_ns: int) -> bool:
        """A WAIT has begun: True (and the program past it) if it is a WAIT TICKS that ends
        before ``limit_ns``."""
        ...

    def first_time_at(self, time_ns: int, opcode: int, type_: int, motor: int,
                      values: tuple[int, ...]) -> int:
        """The module's forecast for a moving read (``ModulePort.first_time_at``)."""
        ...

    def epoch(self) -> int:
        """What may have intervened from outside the loop, counted (``ModulePort.epoch``)."""
        ...

    def user_variable(self, number: int) -> int | None:
        """A plain user variable's value (``ModulePort.user_variable``), or None."""
        ...

    def tick_schedule(self, limit: int, period: int, length: int,
                      touched: frozenset[int]) -> TickSchedule | None:
        """I15: when ``limit`` is the next tick of a timer whose handler only counts, before
        the batch's end, and the loop at the PC (passes of ``period`` ns, ``length``
        instructions, addressing the user variables ``touched``) may be skipped across its
        ticks, their schedule; else None (at the batch's end too)."""
        ...

    def take_ticks(self, schedule: TickSchedule, instructions: int) -> None:
        """I15: leave out ``instructions`` of the loop from the schedule's start and the
        timer's dispatches among them (time, instruction count, counters, events)."""
        ...


@dataclass(frozen=True, slots=True)
class TickSchedule:
    """I15: a loop's instructions interleaved with the dispatches of a timer whose handler
    only counts, from the loop head at ``start`` to the batch's ``end``.  Main instruction n
    (counted from the head) starts at ``start + n * cost`` plus the handlers run before it:
    ``first`` main instructions run before the first dispatch, ``between`` between two
    (``between * cost + handler * cost == period``), each handler ``handler`` instructions
    (0: no handler, the interrupt is dropped).  ``vector``, ``address`` and ``counters``
    (variable -> step a tick) say what each dispatch does."""

    start: int
    cost: int
    first: int
    between: int
    handler: int
    period: int
    end: int
    vector: int
    address: int | None
    counters: dict[int, int]

    def dispatches_before(self, n: int) -> int:
        """How many dispatches come before main instruction ``n`` (one due just before it
        is not yet taken: the dispatch loop takes it, as stepping would)."""
        return 0 if n <= self.first else (n - self.first - 1) // self.between + 1

    def last_before(self, instant: int) -> int:
        """The last main instruction that starts before ``instant`` (-1: none)."""
        cost, start = self.cost, self.start
        first_dispatch = start + self.first * cost
        if instant <= first_dispatch:
            return (instant - start - 1) // cost if instant > start else -1
        cycle, into = divmod(instant - 1 - first_dispatch, self.period)
        handler = self.handler * cost
        before = self.first + cycle * self.between
        return before - 1 if into < handler else before + (into - handler) // cost

    def passes(self, length: int, horizons: tuple[tuple[int, int], ...],
               real_passes: int) -> int:
        """I4 across the ticks: how many whole passes of ``length`` instructions from the
        head may be left out, each command (offset in its pass, steady until) sent before
        its horizon, with ``real_passes`` more whole passes ending by the batch's end."""
        cost = self.cost
        # pass k (from 0 at the head) ends when its last instruction ends: by the batch's end
        passes = (self.last_before(self.end - cost + 1) + 1) // length - real_passes
        for offset, horizon in horizons:
            # the command at `offset` of pass k is main instruction k * length + offset // cost
            passes = min(passes, (self.last_before(horizon) - offset // cost) // length + 1)
        return max(passes, 0)


class LoopSkipper:
    """Decides, at a loop head, how many passes of the loop can be left out, and leaves them
    out (one per interpreter)."""

    def __init__(self, program: Program) -> None:
        self.program = program
        #: Backward jumps until the next analysis (the dispatch loop counts it down).
        self.countdown = LOOP_PROBE_AFTER
        self._backoff = 1
        #: Loop head -> (registers, pass ns, pass instructions) of loops that touch nothing
        #: but registers: skipped again without an analysis (I9).
        self._idle_loops: dict[int, tuple[tuple[object, ...], int, int]] = {}
        #: The last pass analysed that could be skipped, kept for the next batch (I10).
        self._plan: _Plan | None = None
        #: Passes analysed, and passes skipped again from a kept plan (tests, benchmarks).
        self.analyses = 0
        self.reuses = 0
        #: The last skip went across a counting timer's ticks (I15): the timer's own cycle
        #: skipping (I12), which steps the loop for a whole cycle to record it, stands aside.
        self.crosses_ticks = False
        #: Where the program stands in the kept plan's pass, left there by a skip that ended
        #: inside one (I16): (the instant that pass began, instructions into it).
        self.inside: tuple[int, int] | None = None

    def at_loop_head(self, limit: int) -> int:
        """A backward jump brought the program to a loop head: skip the passes that would do
        exactly what the last one did (or analyse one pass to learn whether they would)."""
        program = self.program
        idle = self._idle_loops.get(program.pc)
        plan = self._plan
        if idle is not None:
            registers = program.registers()
            if idle[0] == registers:
                if (plan is not None and plan.states is not None and not plan.horizons
                        and plan.states[0] == registers and limit >= program.batch_end_ns
                        and not program.interrupt_due()):
                    self._glide(plan, program.time_ns, 0, limit)  # I9 and I16
                else:
                    self._skip(idle[1], idle[2], limit, (), program.time_ns - idle[1],
                               touched=frozenset())  # I9
                return CONTINUE
        if plan is not None and plan.head == program.pc and self._reuse(plan, limit):
            return CONTINUE
        return self._analyse(limit)

    def _reuse(self, plan: _Plan, limit: int) -> bool:
        """I10: nothing intervened since ``plan`` was analysed and the program is where it
        began, so its passes are skipped as the analysis would (False: analyse again)."""
        program = self.program
        if program.epoch() != plan.epoch or program.interrupt_due():  # I10: something intervened
            return False
        registers = program.registers()
        if plan.everything is not None:  # the usual case, a pass that keeps every register
            if registers != plan.everything:  # I2
                return False
        elif any(registers[index] != value for index, value in plan.registers):  # I2, I6
            return False
        if plan.variables and any(program.user_variable(number) != value
                                  for number, value in plan.variables):
            return False  # I10: a user variable it reads was written since
        self.countdown = 1
        program.replay, program.replay_epoch = plan.answers, plan.epoch  # I13
        ticks = self._across_ticks(plan, limit)
        if ticks is None and plan.states is not None:  # I16: to the limit's instruction
            if self._glide(plan, program.time_ns, 0, limit):
                self.reuses += 1
                return True
            self._plan = program.replay = None  # a horizon is here: its answers may change
            return False
        if program.time_ns + (1 + plan.real_passes) * plan.period > (
                limit if ticks is None else ticks.end):
            return True  # no whole pass to leave out before the batch ends: step on to it
        # I4 counts from a pass that began a period ago, as the analysed one did; I7
        if self._skip(plan.period, plan.length, limit, plan.horizons,
                      program.time_ns - plan.period, plan.real_passes, ticks=ticks):
            self.reuses += 1
            return True
        self._plan = program.replay = None  # its answers no longer hold
        return False

    def _give_up(self) -> None:
        """This loop cannot be skipped now: analyse again later, less often each time."""
        self.crosses_ticks = False
        self.countdown = self._backoff
        self._backoff = min(self._backoff * 2, LOOP_BACKOFF_MAX)

    def _run_pass(self, limit: int, calls: list[Call], path: list[int],
                  states: list[tuple[object, ...]]) -> tuple[int, bool] | None:
        """Execute one pass from the loop head, recording its commands and path: (outcome,
        whether it waited), or None when it cannot be analysed (too long, past ``limit``, a
        WAIT that goes on)."""
        program = self.program
        head = program.pc
        waited = False
        program.recording = calls
        try:
            while True:
                if program.time_ns >= limit or len(path) >= MAX_PASS:
                    return None
                path.append(program.pc)
                states.append(program.registers())
                outcome = program.execute_one()
                if outcome == WAITING:
                    if not program.tick_wait_ends(limit):
                        return None  # the wait goes on: the caller waits
                    waited = True  # I8
                elif outcome != CONTINUE:
                    return outcome, waited
                if program.pc == head:
                    return CONTINUE, waited
        finally:
            program.recording = None

    def _analyse(self, limit: int) -> int:
        """Run one pass instruction by instruction, recording what it asks the module, then
        skip the passes after it that are certain to do the same (exactly as stepping)."""
        program = self.program
        if program.interrupt_due():
            self._give_up()
            return CONTINUE
        self._plan = program.replay = None
        self.analyses += 1
        head, start, executed = program.pc, program.time_ns, program.executed
        before = program.registers()
        calls: list[Call] = []
        path: list[int] = []
        states: list[tuple[object, ...]] = []
        ran = self._run_pass(limit, calls, path, states)
        if ran is None or ran[0] != CONTINUE or any(call.changed for call in calls):
            self._give_up()
            return CONTINUE if ran is None else ran[0]
        analysed = _Pass(head, start, program.time_ns - start, program.executed - executed,
                         before, program.registers(), calls, path, ran[1], states)
        repeats = analysed.repeats()
        if analysed.reads_clock():  # I11: to the tick's flip, else to its next millisecond
            skipped = self._skip_to_flip(analysed, limit)
            if skipped is None and repeats:
                skipped = self._skip_repeats(analysed, limit)
        else:
            skipped = (self._skip_repeats(analysed, limit) if repeats
                       else self._skip_to_flip(analysed, limit))
        plan = self._plan
        if skipped or (plan is not None and plan.start == start and  # kept for the next batch
                       program.time_ns + (1 + plan.real_passes) * plan.period > limit):
            self._backoff = 1
            self.countdown = 1 if repeats else 2
        else:
            self._give_up()
        return CONTINUE

    def _keep(self, analysed: _Pass, horizons: tuple[tuple[int, int], ...],
              real_passes: int) -> None:
        """Keep a pass that could be skipped for the next batch (I10): the registers it must
        find (those the pass left as it found them: I2, I6), the user variables it read."""
        before, after = analysed.before, analysed.after
        registers = tuple((index, value) for index, value in enumerate(before)
                          if after[index] == value)
        # the user variables it reads, and those it writes with the value they had (a
        # timer's handler may have counted one since: the write would change it again)
        variables = tuple((call.request[1], call.value if call.request[0] == OP_GGP
                           else call.request[3]) for call in analysed.calls
                          if call.request[2] == 2 and (call.request[0] == OP_GGP or (
                              call.request[0] == OP_SGP and call.status == STATUS_OK)))
        everything = before if len(registers) == len(before) else None
        # I16: a pass that repeats whole, its instructions alone in its time, and touches
        # nothing a batch boundary could (no handler in progress): its states, one an
        # instruction, to stop inside it where stepping would
        states = (tuple(analysed.states) if real_passes == 0 and everything is not None
                  and analysed.period == analysed.length * self.program.instruction_ns
                  and len(analysed.states) == analysed.length and before[_SAVED] is None
                  else None)
        self.inside = None
        self._plan = _Plan(analysed.head, analysed.start, self.program.epoch(), registers,
                           everything, variables, analysed.period, analysed.length, horizons,
                           real_passes, _answers(self.program.code, analysed.path,
                                                 analysed.calls), analysed.touched(), states)

    def _skip_repeats(self, analysed: _Pass, limit: int) -> int:
        """I2: the next passes do exactly the same while every answer holds (I3, I4)."""
        if not analysed.calls and not analysed.waited:  # I9
            self._idle_loops[analysed.head] = (analysed.before, analysed.period, analysed.length)
        horizons = tuple((call.time_ns - analysed.start, call.steady_until)
                         for call in analysed.calls)
        self._keep(analysed, horizons, 0)
        plan, program = self._plan, self.program
        assert plan is not None
        ticks = self._across_ticks(plan, limit)
        if ticks is None and plan.states is not None:  # I16: to the limit's instruction
            return self._glide(plan, program.time_ns, 0, limit)
        return self._skip(analysed.period, analysed.length, limit, horizons, analysed.start,
                          ticks=ticks)

    def _across_ticks(self, plan: _Plan, limit: int) -> TickSchedule | None:
        """I15 for the kept plan's loop: the ticks it is skipped across when ``limit`` is a
        counting timer's tick (the port says; None at the batch's end and otherwise)."""
        return self.program.tick_schedule(limit, plan.period, plan.length, plan.touched)

    def _glide(self, plan: _Plan, began: int, index: int, limit: int) -> int:
        """I16: from instruction ``index`` of a pass of ``plan`` that began at ``began`` (the
        program there, in the state the analysed pass had there), leave out the
        instructions that start before ``limit``, as long as every command among them is
        sent before its horizon; the program is left in the state the analysed pass had
        at the instruction it stops before.  Returns how many were left out."""
        program = self.program
        states = plan.states
        assert states is not None
        cost, length = program.instruction_ns, plan.length
        stop = index + max(0, -(-(limit - program.time_ns) // cost))
        for offset, horizon in plan.horizons:
            # the first time the command at `offset` is sent at or after its horizon
            first = max(index, -(-(horizon - began) // cost))
            at = offset // cost
            stop = min(stop, first + (at - first) % length)
        if stop <= index:
            return 0
        whole, inside = divmod(stop, length)
        program.restore(states[inside])
        program.time_ns = began + stop * cost
        program.executed += stop - index
        program.loops_skipped += whole
        self.inside = (began + whole * length * cost, inside)
        return stop - index

    def resume(self, limit: int) -> None:
        """I16 at a batch's start: the program still stands where a skip left it inside the
        kept plan's pass, nothing intervened (the epoch, the registers), so it goes on
        gliding to ``limit``."""
        inside, plan, program = self.inside, self._plan, self.program
        if program.time_ns >= limit:
            return  # nothing to run in this batch: it stays where it is
        self.inside = None
        if inside is None or plan is None or plan.states is None:
            return
        began, index = inside
        if (program.time_ns != began + index * program.instruction_ns
                or (plan.horizons and program.epoch() != plan.epoch)  # (I9: no command)
                or program.interrupt_due() or program.registers() != plan.states[index]
                or any(program.user_variable(number) != value
                       for number, value in plan.variables)):
            return  # something intervened: the dispatch loop steps on from here
        if self._glide(plan, began, index, limit):
            self.reuses += 1

    def _skip(self, period: int, length: int, limit: int,
              horizons: tuple[tuple[int, int], ...], start: int, real_passes: int = 0,
              touched: frozenset[int] | None = None, ticks: TickSchedule | None = None) -> int:
        """Skip the whole passes after the one that began at ``start`` whose every module
        command (offset in the pass, steady until) still answers the same, keeping
        ``real_passes`` whole passes before ``limit`` to be stepped; returns how many.  Where
        ``limit`` is the tick of a timer whose handler only counts, the passes go on across
        its ticks to the batch's end (``ticks``, or found for a loop addressing the user
        variables ``touched``: I15)."""
        program = self.program
        if ticks is None and touched is not None:
            ticks = program.tick_schedule(limit, period, length, touched)
        if ticks is not None:  # I15: across the timer's ticks, each handler's time counted
            passes = ticks.passes(length, horizons, real_passes)
            if passes <= 0:
                return 0
            program.take_ticks(ticks, passes * length)
            program.loops_skipped += passes
            self.crosses_ticks = True
            return passes
        passes = (limit - start) // period - 1 - real_passes  # I4: the pass ends by the limit
        for offset, steady_until in horizons:
            # I4: pass k sends at start + k * period + offset, certain while < steady_until
            passes = min(passes, -(-(steady_until - start - offset) // period) - 1)
        if passes <= 0:
            return 0
        program.time_ns = start + (passes + 1) * period
        program.executed += passes * length
        program.loops_skipped += passes
        return passes

    def _skip_to_flip(self, analysed: _Pass, limit: int) -> int | None:
        """A pass that reads moving values (positions, the tick) and only compares them: skip
        to the pass where a comparison could flip, the first time a value reaches one of its
        boundaries (None: the pass is not of that shape)."""
        calls, start = analysed.calls, analysed.start
        moving = analysed.moving_reads()
        if moving is None:
            return None
        found = boundaries(self.program.code, analysed.path, calls, moving, analysed.before,
                           analysed.after)
        if found is None:
            return None
        horizons = []
        for index, call in enumerate(calls):
            horizon = call.steady_until
            if index in found:
                values = found[index]
                if call.value in values:
                    return None  # on a boundary now: the next pass may compare otherwise
                opcode, type_, motor, _ = call.request
                horizon = self.program.first_time_at(call.time_ns, opcode, type_, motor,
                                                     values) if values else FOREVER  # I5
            horizons.append((call.time_ns - start, horizon))
        self._keep(analysed, tuple(horizons), 1)
        return self._skip(analysed.period, analysed.length, limit, tuple(horizons), start,
                          real_passes=1, touched=analysed.touched())  # I7


@dataclass(slots=True)
class _Plan:
    """A pass analysed and found skippable, kept for the batches after its own (I10): where
    and when it began, the module's epoch then, the registers (index, value; or all of them
    as a tuple) and user variables (number, value) it needs, its period and length, each
    call's (offset, horizon), and how many whole passes before a batch's end are stepped
    (I7)."""

    head: int
    start: int
    epoch: int
    registers: tuple[tuple[int, object], ...]
    everything: tuple[object, ...] | None  # all the registers, when it needs all of them
    variables: tuple[tuple[int, int], ...]
    period: int
    length: int
    horizons: tuple[tuple[int, int], ...]
    real_passes: int
    answers: dict[int, tuple[int, int, int]] | None  # its reads by PC (I13)
    touched: frozenset[int]  # the user variables its commands address (I15)
    #: the registers before each of its instructions (I16), where it may be stopped inside
    states: tuple[tuple[object, ...], ...] | None


def _answers(code: list[Instruction], path: list[int],
             calls: list[Call]) -> dict[int, tuple[int, int, int]] | None:
    """I13: the pass's GAP and GIO reads that succeeded and changed nothing, by the PC that
    sent them: (status, value, steady until); None if a PC sent two calls (an inner loop)
    or the path and the calls do not pair up."""
    answers: dict[int, tuple[int, int, int]] = {}
    pending = iter(calls)
    for pc in path:
        op, _, motor, _ = code[pc]
        if op in _NO_CALL or (op in INTERNAL_OPCODES and op != OP_WAIT) or (
                op == OP_ACO and motor == MOTOR_ALL):
            continue  # the interpreter's own: no module command
        call = next(pending, None)
        if call is None or pc in answers:
            return None
        if op in _REPLAYED and call.status == STATUS_OK and not call.changed:
            answers[pc] = (call.status, call.value, call.steady_until)
    return answers if next(pending, None) is None else None


#: The commands of global parameters, which address a user variable in bank 2 (I15).
_USER_VARIABLE_OPCODES = frozenset({OP_GGP, OP_SGP, Opcode.STGP.value, Opcode.RSGP.value})
#: What the dispatch loop keeps to itself (no call), and the reads a plan answers (I13).
_NO_CALL = frozenset({OP_CALC, OP_COMP, OP_JC, OP_JA})
_REPLAYED = frozenset({OP_GAP, Opcode.GIO.value})


@dataclass(slots=True)
class _Pass:
    """One pass of a loop, analysed: where and when it began, how long it took (ns and
    instructions), the registers before and after, its module commands and its path."""

    head: int
    start: int
    period: int
    length: int
    before: tuple[object, ...]
    after: tuple[object, ...]
    calls: list[Call]
    path: list[int]
    waited: bool
    states: list[tuple[object, ...]]

    def touched(self) -> frozenset[int]:
        """I15: the user variables (bank 2) the pass's commands read or write."""
        return frozenset(call.request[1] for call in self.calls
                         if call.request[2] == 2 and call.request[0] in _USER_VARIABLE_OPCODES)

    def moving_reads(self) -> set[int] | None:
        """The indices of the calls whose answers are not steady, and of the tick's reads
        (I11), if all of them are GAPs or GGPs answered (the moving values a flip is
        forecast for); None otherwise."""
        moving = {index for index, call in enumerate(self.calls)
                  if call.steady_until <= call.time_ns or _reads_clock(call)}
        if any(self.calls[i].status != STATUS_OK or self.calls[i].request[0] not in _FORECAST
               for i in moving):
            return None
        return moving

    def reads_clock(self) -> bool:
        """I11: the pass reads the millisecond tick (GP 132)."""
        return any(_reads_clock(call) for call in self.calls)

    def repeats(self) -> bool:
        """I2: every answer steady and the registers as found: the next passes do the same."""
        return self.after == self.before and all(call.steady_until > call.time_ns
                                                 for call in self.calls)


def counting_handler(code: list[Instruction], address: int) -> dict[int, int] | None:
    """I12: the variables a timer handler at ``address`` counts and by how much a tick, if
    it is nothing but ``GGP n, 2; CALC ADD|SUB, c; AGP n, 2`` groups (each variable once)
    and RETI; None otherwise."""
    counters: dict[int, int] = {}
    pc = address
    while pc < len(code):
        op, ty, motor, _ = code[pc]
        if op == OP_RETI:
            return counters
        if pc + 2 >= len(code):
            return None
        calc, store = code[pc + 1], code[pc + 2]
        if (op != OP_GGP or motor != 2 or ty in counters or calc.opcode != OP_CALC
                or calc.type not in (CalcOp.ADD, CalcOp.SUB)
                or store[:3] != (OP_AGP, ty, 2)):
            return None
        counters[ty] = calc.value if calc.type == CalcOp.ADD else -calc.value
        pc += 3
    return None


def ticks_to_skip(calls: list[Call], counters: dict[int, int], start: int, period: int,
                  limit: int) -> int:
    """I12: how many timer cycles after the recorded one (``calls``, begun at ``start``) do
    exactly what it did, ending by ``limit`` (0: none, or the cycle is not of that shape)."""
    reads = dict.fromkeys(counters, 0)
    writes = dict.fromkeys(counters, 0)
    cycles = (limit - 1 - start) // period - 1  # the dispatch after them within the batch
    for call in calls:
        opcode, type_, motor, _ = call.request
        if motor == 2 and type_ in counters and opcode in (OP_GGP, OP_SGP):
            (reads if opcode == OP_GGP else writes)[type_] += 1
            continue
        if call.changed or call.steady_until <= call.time_ns:
            return 0  # changed something, or no promise about the next answer
        # I4: cycle i sends at start + i * period + offset, certain while < steady_until
        cycles = min(cycles, -(-(call.steady_until - call.time_ns) // period) - 1)
    if any(count != 1 for count in (*reads.values(), *writes.values())):
        return 0  # the handler's counting, once each, and nothing else touches the counters
    return max(cycles, 0)


#: The reads whose flips the module forecasts: GAP (axes/forecast.py), GGP (the tick, I11).
_FORECAST = frozenset({OP_GAP, OP_GGP})


def _reads_clock(call: Call) -> bool:
    """GGP 132 of bank 0 answered: the millisecond tick, which moves with time alone."""
    return call.request[:3] == _TICK_READ and call.status == STATUS_OK


#: Registers of the pass analysis (the indices in Program.registers()).
_ACC, _X, _ZERO, _CMP, _ERRORS, _STACK, _SAVED = 1, 2, 3, 4, 5, 6, 7
_HALF = 1 << 31
#: CALCX operations of plain arithmetic that keep a moving read's function invertible.
_PLAIN = (CalcOp.ADD, CalcOp.SUB)


class Affine(NamedTuple):
    """A register that holds ``to_int32(sign * r + offset) - compared``, r the value of moving
    read ``read`` (an index of the pass's calls; ``sign`` +1 or -1, ``offset`` a 32-bit value,
    ``compared`` a COMP's value, 0 for the accumulator and X): a function of the read that
    CALC ADD/SUB/NOT/MUL by +-1 and CALCX ADD/SUB/LOAD/SWAP/NOT keep exactly invertible
    (I14)."""

    read: int
    sign: int
    offset: int
    compared: int = 0

    def flips(self) -> tuple[int, ...]:
        """I14: the read values at which ``to_int32(sign * read + offset)`` meets ``compared``
        or jumps across its wrap (2**31 - 1 -> -2**31, on both sides), each solved exactly
        modulo 2**32; the identity cannot jump (the read's own wrap is the forecast's, F3)."""
        sign, offset = self.sign, self.offset
        if sign == 1 and offset == 0:
            return (self.compared,)
        return tuple(to_int32(sign * (value - offset))
                     for value in (self.compared, _HALF - 1, -_HALF))


class _PassShape:
    """Follows a pass's path symbolically: which registers hold an affine function of a moving
    read's value (:class:`Affine`), which registers' values are known (the pass's start and
    what it loads), which the pass reads before writing, and the values each moving read is
    compared with (the boundaries of I5, I14)."""

    def __init__(self, calls: list[Call], moving: set[int], before: tuple[object, ...]) -> None:
        self.moving = moving
        self.pending = iter(enumerate(calls))  # the pass's module commands, in order
        #: register -> the function of a moving read it holds
        self.symbolic: dict[int, Affine] = {}
        #: ACC and X -> their value where it is known for certain (None: not known)
        self.known: dict[int, int | None] = {_ACC: _int(before[_ACC]), _X: _int(before[_X])}
        self.written: set[int] = set()
        self.first_read: set[int] = set()
        self.boundaries: dict[int, set[int]] = {index: set() for index in moving}

    def follow(self, instruction: Instruction) -> bool:
        """One instruction of the path; False if the pass is not of the analysable shape."""
        op, ty, motor, va = instruction
        handler = _FOLLOW.get(op)
        if handler is not None:
            return handler(self, ty, motor, va)
        if op in INTERNAL_OPCODES:
            return False  # subroutines, interrupts, error flags: not analysed
        index, call = next(self.pending)
        if call.status == STATUS_OK and loads_accumulator(op, ty, motor):
            source = Affine(index, 1, 0) if index in self.moving else None
            self.writes(_ACC, source, to_int32(call.value))
            self.writes(_ZERO, source)
        return True

    def reads(self, register: int) -> None:
        if register not in self.written:
            self.first_read.add(register)

    def writes(self, register: int, source: Affine | None = None,
               value: int | None = None) -> None:
        """``register`` now holds ``source`` (a moving read's function) or ``value`` (known;
        None: neither)."""
        self.written.add(register)
        if source is None:
            self.symbolic.pop(register, None)
        else:
            self.symbolic[register] = source
        if register in self.known:
            self.known[register] = None if source is not None else value

    def calc(self, ty: int, motor: int, va: int) -> bool:
        """CALC: a moving value goes on only through what keeps it invertible (I14)."""
        if ty == CalcOp.LOAD:
            self.writes(_ACC, None, to_int32(va))
            self.writes(_ZERO)
            return True
        self.reads(_ACC)
        source = self.symbolic.get(_ACC)
        if source is None:
            known = self.known[_ACC]
            value = None if known is None else _exactly(ty, known, va)
            self.writes(_ACC, None, value)
            self.writes(_ZERO)
            return True
        if ty == CalcOp.MUL and va == 0:
            self.writes(_ACC, None, 0)  # the same 0 in every pass
            self.writes(_ZERO)
            return True
        moved = _affine_calc(ty, source, va)
        if moved is None:
            return False
        self.writes(_ACC, moved)
        self.writes(_ZERO, moved)
        return True

    def calcx(self, ty: int, motor: int, va: int) -> bool:
        """CALCX: the accumulator with X, where a moving value stays invertible (I14)."""
        symbolic, known = self.symbolic, self.known
        if ty == CalcOp.LOAD:
            self.reads(_ACC)
            self.writes(_X, symbolic.get(_ACC), known[_ACC])
            return True
        if ty == CalcOp.NOT:
            self.reads(_X)
            source, value = symbolic.get(_X), known[_X]
            self.writes(_X, None if source is None else _affine_calc(ty, source, 0),
                        None if value is None else to_int32(~value))
            return True
        self.reads(_ACC)
        self.reads(_X)
        acc, x = symbolic.get(_ACC), symbolic.get(_X)
        if ty == CalcOp.SWAP:
            acc_value, x_value = known[_ACC], known[_X]
            self.writes(_ACC, x, x_value)
            self.writes(_X, acc, acc_value)
            self.writes(_ZERO, x)
            return True
        if acc is None and x is None:
            acc_value, x_value, value = known[_ACC], known[_X], None
            if acc_value is not None and x_value is not None and ty in _PLAIN:
                value = _exactly(ty, acc_value, x_value)
            self.writes(_ACC, None, value)
            self.writes(_ZERO)
            return True
        if ty not in _PLAIN:
            return False
        sign = 1 if ty == CalcOp.ADD else -1
        if acc is not None and x is not None:
            if acc.read != x.read or acc.sign + sign * x.sign != 0:
                return False  # two reads, or twice one: not one read's +-1 function
            self.writes(_ACC, None, to_int32(acc.offset + sign * x.offset))  # the read cancels
        elif acc is not None:
            other = known[_X]
            if other is None:
                return False
            self.writes(_ACC, Affine(acc.read, acc.sign, to_int32(acc.offset + sign * other)))
        else:
            assert x is not None
            other = known[_ACC]
            if other is None:
                return False
            self.writes(_ACC, Affine(x.read, sign * x.sign, to_int32(other + sign * x.offset)))
        self.writes(_ZERO, symbolic.get(_ACC))
        return True

    def comp(self, ty: int, motor: int, va: int) -> bool:
        self.reads(_ACC)
        source = self.symbolic.get(_ACC)
        compared = None if source is None else source._replace(compared=va)
        self.writes(_CMP, compared)
        self.writes(_ZERO, compared)
        return True

    def jc(self, ty: int, motor: int, va: int) -> bool:
        register = _ZERO if ty <= 1 else _CMP if ty <= 7 else _ERRORS
        self.reads(register)
        source = self.symbolic.get(register)
        if source is not None:
            self.boundaries[source.read].update(source.flips())  # I5, I14
        return True

    def jump(self, ty: int, motor: int, va: int) -> bool:
        return True  # JA: no register, no answer

    def wait(self, ty: int, motor: int, va: int) -> bool:
        """A WAIT that fell through (its condition held) or a WAIT TICKS that ended (I8): its
        one call, whose answer holds as long as the reads of its condition do (I3); no
        register.  (A WAIT whose reads move has the analysis give up: moving_reads.)"""
        next(self.pending)
        return True

    def accumulator_write(self, ty: int, motor: int, va: int) -> bool:
        """AAP, AGP: a command sending the accumulator (not analysed if it is moving)."""
        self.reads(_ACC)
        if _ACC in self.symbolic:
            return False
        next(self.pending)
        return True

    def aco(self, ty: int, motor: int, va: int) -> bool:
        """ACO: as AAP, but ACO of all coordinates (motor 255) sends nothing to the module."""
        self.reads(_ACC)
        if _ACC in self.symbolic:
            return False
        if motor != MOTOR_ALL:
            next(self.pending)
        return True

    def keeps_what_the_next_pass_reads(self, before: tuple[object, ...],
                                       after: tuple[object, ...]) -> bool:
        """I6: what the next pass reads before writing is what this one found, and does not
        come from a moving read (equal now by chance, it would differ in the passes skipped)."""
        return not any(before[register] != after[register] or register in self.symbolic
                       for register in self.first_read)


def _int(value: object) -> int | None:
    return value if isinstance(value, int) else None


def _exactly(operation: int, value: int, operand: int) -> int | None:
    """CALC ``operation`` of a known accumulator, where it is plain 32-bit arithmetic (the
    interpreter's ``calculate``); None for the others (not needed: the value becomes unknown)."""
    if operation == CalcOp.ADD:
        return to_int32(value + operand)
    if operation == CalcOp.SUB:
        return to_int32(value - operand)
    if operation == CalcOp.NOT:
        return to_int32(~value)
    return None


def _affine_calc(operation: int, source: Affine, operand: int) -> Affine | None:
    """CALC ``operation`` (or CALCX NOT) of a moving read's function, if it is again one of
    them (I14): ADD, SUB, NOT (~v = -v - 1) and MUL by +-1; None for the rest (stepped)."""
    index, sign, offset, _ = source
    if operation == CalcOp.ADD:
        return Affine(index, sign, to_int32(offset + operand))
    if operation == CalcOp.SUB:
        return Affine(index, sign, to_int32(offset - operand))
    if operation == CalcOp.NOT:
        return Affine(index, -sign, to_int32(-offset - 1))
    if operation == CalcOp.MUL and operand in (1, -1):
        return Affine(index, sign * operand, to_int32(offset * operand))
    return None


_FOLLOW = {OP_CALC: _PassShape.calc, OP_CALCX: _PassShape.calcx, OP_COMP: _PassShape.comp,
           OP_JC: _PassShape.jc, OP_JA: _PassShape.jump, OP_WAIT: _PassShape.wait,
           OP_AAP: _PassShape.accumulator_write, OP_AGP: _PassShape.accumulator_write,
           OP_ACO: _PassShape.aco}


def boundaries(code: list[Instruction], path: list[int], calls: list[Call], moving: set[int],
               before: tuple[object, ...],
               after: tuple[object, ...]) -> dict[int, tuple[int, ...]] | None:
    """For each moving read (an index of ``calls``), the values at which the pass's branches
    could decide otherwise (I5), if the pass depends on the moving reads only through COMP
    and JC and leaves every register it reads before writing as it found it (I6); None if the
    pass is not of that shape."""
    shape = _PassShape(calls, moving, before)
    if not all(shape.follow(code[pc]) for pc in path):
        return None
    if not shape.keeps_what_the_next_pass_reads(before, after):
        return None
    return {index: tuple(sorted(values)) for index, values in shape.boundaries.items()}
