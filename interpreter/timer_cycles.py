"""Timer cycles skipped (invariant I12 of interpreter/skipping.py): a timer's interrupt
whose handler only counts, cycle after cycle, is left out as arithmetic.

One cycle, from a dispatch of the timer's interrupt to the next, is recorded like a pass
of a loop; the cycles after it that will do exactly the same are skipped up to the
batch's end.  Apart from the dispatch loop (``machine.py``), which only calls in here
when a timer's interrupt is about to be taken.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from interpreter import interrupts
from interpreter.isa import OP_SGP, Instruction
from interpreter.port import ModulePort
from interpreter.skipping import Call, LoopSkipper, TickSchedule, counting_handler, ticks_to_skip
from interpreter.waits import Wait
from tmcl_spec.numbers import to_int32 as wrap32


@dataclass(slots=True)
class Timer:
    """A timer's period and its next expiry (bank 3 parameters 0..2)."""

    period_ns: int
    next_ns: int


@dataclass(slots=True)
class _Cycle:
    """A timer cycle being recorded, from one dispatch of its interrupt to the next, to skip
    the cycles after it that do exactly the same (interpreter/skipping.py I12)."""

    vector: int
    counters: dict[int, int]
    start: int
    registers: tuple[object, ...]
    epoch: int
    executed: int
    calls: list[Call]


class TimerCycles:
    """Recording and skipping timer cycles (a base of :class:`Interpreter`)."""

    port: ModulePort
    code: list[Instruction]
    time_ns: int
    executed: int
    vectors: dict[int, int]
    enabled: int
    globally_enabled: bool
    saved: object  # the interrupt's saved Context (machine.py), or None
    wait: Wait | None
    recording: list[Call] | None
    ticks_skipped: int
    instruction_ns: int
    pending: int
    wake_for_timers: bool
    skipper: LoopSkipper
    batch_end_ns: int
    _timers: dict[int, Timer]
    _cycle: _Cycle | None
    _cycle_wait: int
    _cycle_backoff: int

    if TYPE_CHECKING:
        def _dispatchable(self) -> int: ...

        def registers(self) -> tuple[object, ...]: ...

    def _timer_cycle(self, end_ns: int) -> None:
        """A timer's interrupt is about to be taken: skip the cycles that will do exactly
        what the one recorded since its last dispatch did, and record this one (I12)."""
        cycle = self._cycle
        pending = self._dispatchable()
        vector = (pending & -pending).bit_length() - 1
        if cycle is not None:
            self._cycle = None
            self.recording = None
            self._skip_cycles(cycle, vector, end_ns)
        if self._cycle_wait > 0:
            self._cycle_wait -= 1
            return
        if self.skipper.crosses_ticks:
            return  # the loop is skipped across the ticks (I15): recording would step it
        address = self.vectors.get(vector)
        timer = self._timers.get(vector - interrupts.TIMER_BASE)
        counters = None if address is None else counting_handler(self.code, address)
        if (counters is None or timer is None or len(self._timers) != 1
                or pending != 1 << vector or self.wait is not None or self.saved is not None
                or any(self.port.user_variable(number) is None for number in counters)):
            self._give_up_cycles()
            return
        self._cycle = _Cycle(vector, counters, self.time_ns, self._cycle_state(),
                             self.port.epoch(), self.executed, [])
        self.recording = self._cycle.calls

    def _cycle_state(self) -> tuple[object, ...]:
        """What a timer cycle starts from besides the module (I12): the registers and the
        interrupt set-up (a VECT, EI or DI in the cycle changes none of the module)."""
        return (*self.registers(), self.enabled, self.globally_enabled,
                tuple(sorted(self.vectors.items())))

    def _give_up_cycles(self) -> None:
        self._cycle_wait = self._cycle_backoff
        self._cycle_backoff = min(self._cycle_backoff * 2, 1024)

    def _skip_cycles(self, cycle: _Cycle, vector: int, end_ns: int) -> None:
        """I12: the recorded cycle ended at this dispatch; skip the ones after it that do
        exactly the same, up to the batch's end."""
        timer = self._timers.get(vector - interrupts.TIMER_BASE)
        if (timer is None or vector != cycle.vector or len(self._timers) != 1
                or self.time_ns - cycle.start != timer.period_ns
                or self._dispatchable() != 1 << vector or self.wait is not None
                or self._cycle_state() != cycle.registers or self.port.epoch() != cycle.epoch):
            self._give_up_cycles()
            return
        period = timer.period_ns
        skipped = ticks_to_skip(cycle.calls, cycle.counters, cycle.start, period, end_ns)
        if skipped <= 0:
            if (end_ns - 1 - cycle.start) // period - 1 > 0:  # not the batch's end: backoff
                self._give_up_cycles()
            return
        self._cycle_backoff = 1
        now = self.time_ns
        self.time_ns = now + skipped * period
        self.executed += skipped * (self.executed - cycle.executed)
        self._dispatches_left_out(timer, vector, self.vectors[vector], now, skipped,
                                  cycle.counters)

    def tick_schedule(self, limit: int, period: int, length: int,
                      touched: frozenset[int]) -> TickSchedule | None:
        """I15: the schedule of the ticks a loop at its head (passes of ``period`` ns and
        ``length`` instructions, addressing the user variables ``touched``) may be skipped
        across, when ``limit`` is the next tick of the only timer, before the batch's end,
        and its handler only counts, in variables the loop leaves alone; else None."""
        timers = self._timers
        if len(timers) != 1 or limit >= self.batch_end_ns or self.wake_for_timers:
            return None
        ((number, timer),) = timers.items()
        vector = interrupts.timer(number)
        cost = self.instruction_ns
        if (timer.next_ns != limit or period != length * cost or timer.period_ns % cost
                or self.pending or self.saved is not None or self.wait is not None
                or not self.globally_enabled or not self.enabled >> vector & 1):
            return None  # a WAIT in the pass, an interrupt pending or in progress, ...
        address = self.vectors.get(vector)
        counters = {} if address is None else counting_handler(self.code, address)
        if counters is None or any(number in touched or self.port.user_variable(number) is None
                                   for number in counters):
            return None  # a handler that does more than count, or counts what the loop reads
        handler = 0 if address is None else 3 * len(counters) + 1  # (RETI included)
        between = timer.period_ns // cost - handler
        if between < 1:
            return None
        return TickSchedule(self.time_ns, cost, -(-(limit - self.time_ns) // cost), between,
                            handler, timer.period_ns, self.batch_end_ns, vector, address,
                            counters)

    def take_ticks(self, schedule: TickSchedule, instructions: int) -> None:
        """I15: the loop's next ``instructions`` and the dispatches among them, left out."""
        taken = schedule.dispatches_before(instructions)
        self.time_ns = schedule.start + (instructions + taken * schedule.handler) * schedule.cost
        self.executed += instructions + taken * schedule.handler
        if taken:
            self._dispatches_left_out(
                self._timers[schedule.vector - interrupts.TIMER_BASE], schedule.vector,
                schedule.address, schedule.start + schedule.first * schedule.cost, taken,
                schedule.counters)

    def _dispatches_left_out(self, timer: Timer, vector: int, address: int | None,
                             first_ns: int, count: int, counters: dict[int, int]) -> None:
        """``count`` dispatches of ``timer``'s interrupt from ``first_ns`` on, each a period
        apart, whose handler (at ``address``; None: none, the interrupt dropped) only counts,
        left out (I12, I15): the timer's next tick, each dispatch's event at its instant (as
        one run to the observers that take runs) and the counters ``count`` steps on, written
        at the program's instant (which the caller has moved past them)."""
        timer.next_ns += count * timer.period_ns
        self.ticks_skipped += count
        port = self.port
        if address is not None:
            port.program_events(first_ns, timer.period_ns, count, "interrupt_taken",
                                vector=vector, address=address)
        for number, step in counters.items():
            value = port.user_variable(number)
            assert value is not None
            port.execute(self.time_ns, OP_SGP, number, 2, wrap32(value + count * step))
