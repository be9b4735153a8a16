"""WAIT: a program waiting for a condition of the module, a timeout or a number of ticks.

When a WAIT ends depends on when its condition is evaluated, which the exactness of loop
skipping rests on (I1, I3, I8 in interpreter/skipping.py); the rules are kept here, in one
place, apart from the dispatch loop (``machine.py``), which only starts and resumes WAITs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

from interpreter.isa import CONTINUE, OP_GAP, OP_RFS, OP_WAIT, WAIT_TICK_NS, WAITING
from interpreter.port import ModulePort
from interpreter.skipping import FOREVER, Call
from tmcl_spec.commands import STATUS_OK, ErrorFlag, RfsType, WaitCondition
from tmcl_spec.parameters import AP

_RFS_STATUS = RfsType.STATUS.value
#: The WAIT conditions that read the module (the others: TICKS, or skipped).
_WAIT_CONDITIONS = frozenset(int(c) for c in WaitCondition) - {int(WaitCondition.TICKS)}


@dataclass(slots=True)
class Wait:
    """A WAIT in progress (the PC stays on the WAIT instruction meanwhile)."""

    condition: int
    motor: int
    deadline_ns: int | None
    #: The condition, false when last evaluated, stays false before this instant (its
    #: reads' ``ModulePort.steady_until``): it is evaluated again then.
    recheck_ns: int = FOREVER


class WaitHandling:
    """Starting, resuming and evaluating a WAIT (a base of :class:`Interpreter`)."""

    port: ModulePort
    number_of_axes: int
    instruction_ns: int
    time_ns: int
    pc: int
    wait: Wait | None
    recording: list[Call] | None

    if TYPE_CHECKING:
        def set_error_flag(self, flag: ErrorFlag) -> None: ...

    def _start_wait(self, condition: int, motor: int, ticks: int, t: int) -> int:
        evaluated = condition in _WAIT_CONDITIONS and 0 <= motor < self.number_of_axes
        if not evaluated and self.recording is not None:
            # the pass analysis takes one call per WAIT: this one reads nothing (a WAIT
            # TICKS lasts the same in every pass, I8)
            self.recording.append(Call(t, STATUS_OK, 0, False, FOREVER,
                                       (OP_WAIT, condition, motor, 0)))
        if not evaluated and condition != WaitCondition.TICKS:
            self.pc += 1  # a WAIT the firmware cannot evaluate is skipped
            return CONTINUE
        deadline = t + ticks * WAIT_TICK_NS if ticks > 0 else None
        wait = Wait(condition, motor, deadline)
        if condition == WaitCondition.TICKS:
            if deadline is None:
                self.pc += 1
                return CONTINUE
        elif self._wait_satisfied(wait, t):
            self.pc += 1
            return CONTINUE
        self.wait = wait
        return WAITING

    def _resume_wait(self, end_ns: int) -> bool:
        """Check the WAIT in progress at ``self.time_ns``; True once it is over.

        The condition is evaluated when the WAIT starts, at the start of every batch (so
        after every module event and host request, I1 in interpreter/skipping.py) and when
        its reads may first answer otherwise (``Wait.recheck_ns``, their steady_until, I3):
        a condition false now stays false before then, nothing intervening, so the WAIT
        ends at the same instant however time is cut into batches.  A timeout ends it only
        before that instant (at it, the condition is evaluated first, as a batch starting
        there would).
        """
        wait = self.wait
        assert wait is not None
        ticks = wait.condition == WaitCondition.TICKS
        if not ticks and self._wait_satisfied(wait, self.time_ns):
            pass
        elif (wait.deadline_ns is not None and wait.deadline_ns < end_ns
              and (ticks or wait.deadline_ns < wait.recheck_ns)):
            if not ticks:
                self.set_error_flag(ErrorFlag.ETO)
            self.time_ns = max(self.time_ns, wait.deadline_ns)
        else:
            return False
        self.wait = None
        self.pc += 1
        return True

    def _wait_satisfied(self, wait: Wait, t: int) -> bool:
        """Evaluate the WAIT's condition at ``t``.  When it is false, ``wait.recheck_ns``
        says until when it stays so (a read the module cannot forecast is evaluated again an
        instruction later, as a poll would); while a pass is analysed, the WAIT is recorded
        as one call whose answer holds as long as its reads do (skipping.py I3)."""
        port, motor, condition = self.port, wait.motor, wait.condition
        if condition == WaitCondition.RFS:
            reads: tuple[tuple[int, int], ...] = ((OP_RFS, _RFS_STATUS),)
            satisfied = not port.reference_search_active(t, motor)
        elif condition == WaitCondition.LIMSW:
            satisfied = port.axis_parameter(t, motor, AP.LEFT_SWITCH) == 1
            reads = ((OP_GAP, AP.LEFT_SWITCH),)
            if not satisfied:
                satisfied = port.axis_parameter(t, motor, AP.RIGHT_SWITCH) == 1
                reads += ((OP_GAP, AP.RIGHT_SWITCH),)
        else:
            number = AP.POSITION_REACHED if condition == WaitCondition.POS else AP.HOME_SWITCH
            satisfied = port.axis_parameter(t, motor, number) == 1
            reads = ((OP_GAP, number),)
        calls = self.recording
        if satisfied and calls is None:
            return True
        steady = min(port.steady_until(t, opcode, read, motor) for opcode, read in reads)
        if calls is not None:
            calls.append(Call(t, STATUS_OK, int(satisfied), False, steady,
                              (OP_WAIT, condition, motor, 0)))
        if not satisfied:
            wait.recheck_ns = steady if steady > t else t + self.instruction_ns
        return satisfied
