"""The TMC4361A's remembered runs: a run from a state seen before replays what it did.

Back-and-forth moves and periodic rotations start the same runs again and again.  What a
run does is a function of the chip state relative to the motor (ramp state, the fine
fraction of the step, the positions the law and the flags depend on relative to
XACTUAL, flags and events) and of the ramp parameters; in a chip without position marks
from the board, virtual stops, home checks or an encoder tolerance nothing else enters
it (NFREEZE counts: a frozen chip locks both directions), and the engine's answers do
not depend on ``until`` (HORIZON_TICKS).  So the state
after each clock the engine did by itself is kept (a trace, by start state), and a run
from a state seen before replays the trace up to ``until`` (or its budget, or a stop)
and goes on from there: the same clocks, states, flags and events, worked out once.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from axes.chips.tmc4361a.law import MOTION_SLOTS
from axes.chips.tmc4361a.params import Params, Stage
from axes.chips.tmc4361a.registers import Reg, signed32
from axes.core import Board, Stop

if TYPE_CHECKING:
    from axes.chips.tmc4361a.ramp import Ramp

#: Remembered runs: at most this many states in all (then everything is forgotten and
#: remembered afresh), and at most TRACE_POINTS per run.
RECALLED_STATES = 4096
TRACE_POINTS = 64
#: The motion state a remembered run restores (the position moves by its recorded distance).
_MOTION_SLOTS = tuple(name for name in MOTION_SLOTS if name != "p")


class RememberedRuns:
    """The memory of runs of a TMC4361A (a base of the chip's class, shared with its clones)."""

    #: Replay runs from a state seen before (:meth:`TMC4361A.run`); False: work every run
    #: out (the tests compare the two).
    recall = True
    t: int
    board: Board | None
    regs: dict[int, int]
    events: int
    _ramp: Ramp
    _setup: tuple | None
    _flags: int
    _frozen: bool
    _wake: int
    _mark: int | None

    if TYPE_CHECKING:
        @property
        def motor_position(self) -> int: ...

        @property
        def xactual(self) -> int: ...

        def _status_setup(self) -> tuple: ...

        def _run(self, until: int, budget: int | None, used: int = 0,
                 trace: list | None = None, t0: int = 0, p0: int = 0) -> Stop | None: ...

    def _forget_runs(self) -> None:
        """An empty memory (a new chip; its clones share it)."""
        #: Remembered runs by ramp parameters, shared with clones (:meth:`_recall_key`).
        self._recalled: dict[Params, dict[tuple, list]] = {}
        self._recall_for: tuple[Params | None, dict[tuple, list]] = (None, {})
        #: States remembered in all (one item, shared with clones, as the memo is)
        self._recall_count = [0]

    def _run_remembered(self, key: tuple, until: int, budget: int | None) -> Stop | None:
        """run() from a recallable state (``key``): the remembered trace replayed up to
        ``until``, its budget or a stop, then worked out from there (and remembered)."""
        runs = self._recall_runs()
        trace = runs.get(key)
        ramp = self._ramp
        t0, p0 = self.t, ramp.p
        used = 0
        if trace is None:
            if not self._remember(1):
                return self._run(until, budget)
            trace = runs[key] = []
        elif trace:
            last = _last_point(trace, until - t0, budget)
            if last is not None:
                self._replay(last, t0, p0)
                if last[7] is not None:
                    return last[7]
                used = last[1]
            if last is not trace[-1]:
                trace = None  # left inside the trace (until or budget): nothing to add
        return self._run(until, budget, used, trace, t0, p0)

    def _record(self, trace: list, t0: int, p0: int, used: int, stop: Stop | None
                ) -> list | None:
        """Append the state after a clock the engine did by itself to ``trace`` (None: the
        trace is full, or the memory: nothing more is added)."""
        if len(trace) >= TRACE_POINTS or not self._remember(1):
            return None
        ramp = self._ramp
        trace.append((self.t - t0, used, ramp.p - p0,
                      tuple([getattr(ramp, name) for name in _MOTION_SLOTS]), self._flags,
                      self.events, self._wake, stop))
        return trace


    def _recall_key(self) -> tuple | None:
        """The whole input of a run from here, relative to the motor; None: not recallable."""
        board = self.board
        m = self.motor_position
        if board is not None and (board.next_mark(m, 1) is not None
                                  or board.next_mark(m, -1) is not None):
            return None
        xtarget, compare, fixed, checks = self._setup or self._status_setup()
        if checks is not None:
            return None
        ramp = self._ramp
        g = self.regs.get
        x = self.xactual
        # at rest the stage counter is left over from the last stage: a start sets it to 0
        # (without a ramp nothing starts: the counter runs on)
        q = (None if ramp.stage == Stage.IDLE and not ramp.stopping and ramp.P.profile
             else ramp.q)
        return (signed32(xtarget - x), signed32(compare - x), ramp.p - m * ramp.P.S, fixed,
                g(Reg.REFERENCE_CONF, 0), g(Reg.INTR_CONF, 0), self._frozen, self._flags,
                self.events,
                ramp.w, ramp.s, ramp.a, ramp.slope, ramp.stage, q, ramp.goal,
                ramp.braking, ramp.wait, ramp.no_vstart, ramp.stopping)

    def _recall_runs(self) -> dict[tuple, list]:
        P = self._ramp.P
        params, runs = self._recall_for
        if params is not P:
            runs = self._recalled.setdefault(P, {})
            self._recall_for = (P, runs)
        return runs

    def _remember(self, states: int) -> bool:
        """Count ``states`` more remembered states; False (and everything forgotten) when the
        memory is full: the run at hand is then worked out without being remembered."""
        count = self._recall_count
        count[0] += states
        if count[0] <= RECALLED_STATES:
            return True
        self._recalled.clear()
        self._recall_for = (None, {})
        count[0] = 0
        return False

    def _replay(self, point: tuple, t0: int, p0: int) -> None:
        """Take the state of a trace point (recorded from a run that started at t0, p0)."""
        ticks, _, moved, motion, flags, events, wake, _ = point
        ramp = self._ramp
        self.t = t0 + ticks
        ramp.p = p0 + moved
        for name, value in zip(_MOTION_SLOTS, motion, strict=True):
            setattr(ramp, name, value)
        self._flags = flags
        self.events = events
        self._wake = wake
        self._mark = None


def _last_point(trace: list, ticks: int, budget: int | None) -> tuple | None:
    """The last point of ``trace`` within ``ticks`` clocks and ``budget`` (up to the first
    stop); None if there is none."""
    last = None
    for point in trace:
        if point[0] > ticks or (budget is not None and point[1] > budget):
            break
        last = point
        if point[7] is not None:
            break
    return last
