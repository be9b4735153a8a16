"""One TMC4361A motion controller: its register file behind 40-bit SPI datagrams, and its motion.

The register map and power-on values are in :mod:`axes.chips.tmc4361a.registers`; the ramp
generator (the motion law and the segment-jumping engine) in :mod:`axes.chips.tmc4361a.ramp`.
This module adds what a host sees around it: the one-frame read pipeline and the SPI status
byte, separate read and write views of shared addresses, write side effects, STATUS flags and
latched EVENTS (clear on read, EVENT_CLEAR_CONF, INTR), the stop switches and virtual stops,
the position latch and home tracking, position compare, and a basic incremental encoder.

Time is a count of chip clock ticks (``clock_hz``, the real oscillator; the CLK_FREQ register
is what the chip *believes* it to be, and all real units are converted with it, as on the
real part).  The switch inputs are driven by a :class:`~axes.core.Board`; a board that also
has ``encoder_counts(motor_position)`` drives the encoder inputs (:class:`EncoderBoard`).
Every modelling choice is written down in ``docs/tmc4361a.md``.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from typing import Protocol, runtime_checkable

from axes.chips.tmc4361a.ramp import (
    A_FALL,
    A_IDLE,
    A_SPEED,
    A_START,
    A_WAIT,
    BOW_QUANTUM,
    MOTION_SLOTS,
    Context,
    Params,
    Ramp,
    RampRegisters,
    Stage,
)
from axes.chips.tmc4361a.registers import (
    FLAG_EVENTS,
    MASK32,
    POWER_ON,
    RAMP_REGISTERS,
    READ_COMPUTED,
    READ_ONLY,
    RESET_KEY,
    VERSION,
    WAKE_ALWAYS,
    WRITE_MASKS,
    Event,
    GeneralConf,
    RefConf,
    Reg,
    Status,
    datagram,
    signed32,
)
from axes.core import Board, ChipModel, Stop

DEFAULT_CLOCK_HZ = 16_000_000
#: Remembered runs: at most this many states in all (then everything is forgotten and
#: remembered afresh), and at most TRACE_POINTS per run.
RECALLED_STATES = 4096
TRACE_POINTS = 64
#: How far ahead (clock ticks) the engine looks for the next clock the law must do by itself,
#: whatever ``until`` a caller gives: the answer, and so the motion, cannot depend on how a
#: caller cuts time into runs.  2^42 ticks: 76 h at 16 MHz.
HORIZON_TICKS = 1 << 42
#: Hidden STATUS bit (above the 32 real ones) that tracks the MAX_PHASE_TRAP condition.
_MAX_PHASE = 1 << 40
_VEL_STATE = Status.VEL_STATE_POS | Status.VEL_STATE_NEG
#: The motion state a remembered run restores (the position moves by its recorded distance).
_MOTION_SLOTS = tuple(name for name in MOTION_SLOTS if name != "p")
_TARGET_REACHED_F = Status.TARGET_REACHED_F
_POS_COMP_REACHED_F = Status.POS_COMP_REACHED_F
_VEL_REACHED_F = Status.VEL_REACHED_F
_VEL_STATE_POS = Status.VEL_STATE_POS
_VEL_STATE_NEG = Status.VEL_STATE_NEG
_RAMP_STATE_ACC = Status.RAMP_STATE_ACC
_RAMP_STATE_DEC = Status.RAMP_STATE_DEC
_RAMP_STATE = Status.RAMP_STATE_ACC | Status.RAMP_STATE_DEC
#: home_event values (REFERENCE_CONF 19..16), digest §9.3
HOME_SIDE_TYPES = {3: False, 12: True}  # value: the level on the negative side
HOME_HIGH_ACTIVE = {2: "left", 4: "right", 6: "centre"}
HOME_LOW_ACTIVE = {13: "left", 11: "right", 9: "centre"}
ENC_SEL_DECIMAL = 1 << 0
INVERT_ENC_DIR = 1 << 29
MANUAL_ENC_CONST = 1 << 31
#: The registers read most (plain ints for the hot path of SPI reads).
_STATUS = int(Reg.STATUS)
_XACTUAL = int(Reg.XACTUAL)
#: RAMPMODE(1:0) of an S-shaped ramp (Params.profile).
S_SHAPED_PROFILE = 2

#: CURRENTA (8..0) = 0, CURRENTB (24..16) = 247: the sine table's start values.
CURRENT_AB_POWER_ON = 0x00F7_0000


@lru_cache(maxsize=16)
def _status_bits(selection: int) -> tuple[int, ...]:
    """The event bits an SPI_STATUS_SELECTION puts into the status byte (at most 8)."""
    return tuple(bit for bit in range(32) if selection >> bit & 1)[:8]


@lru_cache(maxsize=64)
def _params_for(registers: RampRegisters, quantum: int) -> Params:
    """The ramp parameters of a register set (the same object for the same registers, which
    keeps the engine's memos: a rotation that reverses alternates between two sets)."""
    return Params.from_registers(registers, quantum)


@lru_cache(maxsize=256)
def _spi_status(events: int, selection: int) -> int:
    status = 0
    for out_bit, bit in enumerate(_status_bits(selection)):
        status |= (events >> bit & 1) << out_bit
    return status


@runtime_checkable
class EncoderBoard(Board, Protocol):
    """A board that also drives the encoder inputs (A/B transitions)."""

    def encoder_counts(self, motor_position: int) -> int:
        """Signed count of AB transitions the encoder has made with the motor at this position."""
        ...


def _turned_at_once(twin: TMC4361A) -> bool:
    """TMC4361A.speed_turns' test where no promise is made."""
    return True


class TMC4361A(ChipModel):
    """The chip.  Host access is :meth:`spi`; the world drives pins through the board."""

    frame_bits = 40
    #: Replay runs from a state seen before (:meth:`run`); False: work every run out (the
    #: tests compare the two).
    recall = True

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, board: Board | None = None,
                 bow_quantum: int = BOW_QUANTUM, recall: bool | None = None) -> None:
        if clock_hz <= 0:
            raise ValueError("clock frequency must be positive")
        self.clock_hz = clock_hz
        self.board = board
        self.bow_quantum = bow_quantum
        if recall is not None:
            self.recall = recall
        #: Remembered runs by ramp parameters, shared with clones (:meth:`_recall_key`).
        self._recalled: dict[Params, dict[tuple, list]] = {}
        self._recall_for: tuple[Params | None, dict[tuple, list]] = (None, {})
        #: States remembered in all (one item, shared with clones, as the memo is)
        self._recall_count = [0]
        self.t = 0  # chip clock ticks fully processed
        self._ramp = Ramp(Params.from_registers(RampRegisters(), bow_quantum))
        self.pin_left = self.pin_right = self.pin_home = False  # electrical levels
        self.pin_freeze = True  # NFREEZE: its internal pull-up keeps it high when unconnected
        self.power_on()
        if board is not None:
            self.pin_left, self.pin_right, self.pin_home = board.pins(self.motor_position)
            self._flags = self._status()

    # == power-on and reset ====================================================================

    def power_on(self) -> None:
        """Every register at its power-on value; the motor stays where it is (RST_EV set)."""
        m = self._ramp.x
        self._setup: tuple | None = None
        self.regs: dict[int, int] = dict(POWER_ON)
        self._ramp = Ramp(Params.from_registers(RampRegisters(), self.bow_quantum))
        self._ramp.p = m * self._ramp.P.S
        self._x_offset = -m  # XACTUAL = motor position + offset (32-bit)
        self.events = int(Event.RST_EV)
        self._spi_out = 0
        self._wake = 0
        self.x_latch = 0
        self._home_latched = False
        self._home_entry: tuple[int, int] | None = None  # (XACTUAL, direction) entering
        self._freeze_written = False
        self._frozen = False  # NFREEZE fell: no motion until a reset (datasheet §12)
        self._mark: int | None = None
        self._mark_dir = 0
        self._enc_const = (0, 65536, 0)  # (numerator, denominator, ENC_CONST register)
        self._enc_base = 0  # ENC_POS * denominator at the rebase point
        self._enc_counts_base = 0
        self._mscnt_base = 0
        self._mscnt_m = m
        self._enc_rebase(0)
        self._flags = self._status()

    # == the contract: time, motion, pins ======================================================

    @property
    def ramp(self) -> Ramp:
        """The ramp generator's exact state (diagnostics and tests; write through SPI only)."""
        return self._ramp

    @property
    def motor_position(self) -> int:
        """Microsteps that reached the STEP output, unwrapped (what the mechanics follow)."""
        return self._ramp.x

    def ticks_at(self, t_ns: int) -> int:
        """Chip clock ticks that have happened by simulated time ``t_ns``."""
        return t_ns * self.clock_hz // 1_000_000_000

    def ns_at(self, ticks: int) -> int:
        """The simulated time (ns, rounded up) of clock tick ``ticks``."""
        return -(-ticks * 1_000_000_000 // self.clock_hz)

    def clone(self) -> TMC4361A:
        """An independent copy (for looking ahead without disturbing this chip)."""
        twin = TMC4361A.__new__(TMC4361A)
        twin.__dict__.update(self.__dict__)
        twin.regs = dict(self.regs)
        twin._ramp = self._ramp.copy()
        return twin

    def speed_turns(self) -> Callable[[TMC4361A], bool] | None:
        """How far a rotation's VACTUAL moves one way from here, if nothing intervenes: a
        test of a later copy of this chip, true once the speed may have turned by its tick
        (false before, true from then on); None: it never turns.  Positioning ramps rise and
        fall: turned at once.  A rotation heads for the speed asked for, except:

        * a start from rest jumps to VSTART, which may lie beyond that speed (it comes
          back): turned at once, until the ramp has started (after TZEROWAIT's standstill);
        * an S-shaped slope first takes back the acceleration of the other slope (REC: a
          rotation asked for more speed while braking brakes on for a while, one asked for
          less while accelerating overshoots): turned where that acceleration reaches 0;
        * an S-shaped reversal with BOW2 = BOW4 passes through 0 without stopping and may
          then take back its acceleration again (the new direction's speed overshoots):
          turned at the zero crossing (or a standstill).

        Otherwise each slope lands on its goal (``Ramp._s_tick`` clamps there)."""
        ramp = self._ramp
        if ramp.P.positioning:
            return _turned_at_once
        if ramp.wait:  # TZEROWAIT: standing still until the start
            started = self.t + ramp.wait
            return lambda twin: twin.t > started
        if ramp.decide(self._context())[0] == A_START:
            return _turned_at_once
        if ramp.P.profile != S_SHAPED_PROFILE:
            return None
        direction, turning = ramp.s, self._takes_back_acceleration()

        def turned(twin: TMC4361A) -> bool:
            later = twin._ramp
            return (later.s != direction or later.w == 0
                    or (turning and not twin._takes_back_acceleration()))

        return turned

    def _takes_back_acceleration(self) -> bool:
        """Whether the next tick of an S-shaped rotation moves the speed against where its
        slope heads (the REC stage: the acceleration points the other way)."""
        ramp = self._ramp
        action = ramp.decide(self._context())
        if action[0] == A_SPEED:
            slope = (ramp.w < action[1]) - (ramp.w > action[1])
        elif action[0] == A_FALL:
            slope = -1
        else:  # at rest, waiting, a soft stop: no acceleration to take back
            return False
        return ramp.a * slope < 0

    def at_rest(self) -> bool:
        """Stopped, and nothing will start the motor without a datagram or a pin change."""
        r = self._ramp
        if r.w or r.wait or r.stopping:
            return False
        ctx = self._context()
        kind = r.decide(ctx)[0]
        return kind == A_IDLE or (kind == A_START and r.start_is_void(ctx))

    def set_pins(self, left: bool, right: bool, home: bool) -> None:
        """Drive STOPL, STOPR and HOME_REF (electrical levels); edges act at once."""
        old_l, old_r = self._stop_active_raw()
        old_home = self.pin_home
        self.pin_left, self.pin_right, self.pin_home = left, right, home
        self._setup = None
        new_l, new_r = self._stop_active_raw()
        conf = self.regs.get(Reg.REFERENCE_CONF, 0)
        if ((old_l and not new_l and conf & RefConf.LATCH_X_ON_INACTIVE_L)
                or (not old_l and new_l and conf & RefConf.LATCH_X_ON_ACTIVE_L)
                or (old_r and not new_r and conf & RefConf.LATCH_X_ON_INACTIVE_R)
                or (not old_r and new_r and conf & RefConf.LATCH_X_ON_ACTIVE_R)):
            self.x_latch = self.xactual
            self._setup = None
            self._raise(Event.XLATCH_DONE)
        if home != old_home:
            self._home_edge(old_home, home)
        self._update_flags()
        self._check_stops()

    def set_freeze(self, level: bool) -> None:
        """Drive NFREEZE (electrical level, low active).  A falling edge freezes the chip
        (datasheet §12): the FROZEN event, the ramp stopped — at once, as DFREEZE = 0 says;
        a linear stop with DFREEZE > 0 is not modelled (docs/tmc4361a.md) — and no motion
        until a reset.  Rising again releases nothing."""
        falling = self.pin_freeze and not level
        self.pin_freeze = level
        if falling and not self._frozen:
            self._frozen = True
            self._ramp.hard_stop()
            self._raise(Event.FROZEN)
            self._update_flags()

    @property
    def frozen(self) -> bool:
        return self._frozen

    def adopt(self, twin: TMC4361A) -> TMC4361A:
        """Continue with the state a :meth:`clone` reached (one chip, one motor: the clone)."""
        return twin

    def run(self, until: int, budget: int | None = None) -> Stop | None:
        """Advance to clock tick ``until``; return early (``t < until``) at a notable instant.

        Returns ARRIVED when a positioning move ends at XTARGET, STOPPED when the velocity
        became 0 otherwise (ramp, switch or virtual stop), MARK when the motor reached a
        position the board asked about (the pins are updated first), and EVENT when an event
        selected in INTR_CONF, or one of :data:`WAKE_ALWAYS`, newly latched.  At one instant
        the first of ARRIVED, STOPPED, MARK, EVENT in that order is returned.

        ``budget`` bounds the work of this call: every clock the law must do by itself (a
        segment boundary, one horizon search and one literal tick) costs one unit; when the
        budget is spent the call returns None with ``t < until``.  None: no bound.
        """
        self._wake = 0
        key = self._recall_key() if self.recall else None
        if key is None:
            return self._run(until, budget)
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
            last = None
            for point in trace:
                if point[0] > until - t0 or (budget is not None and point[1] > budget):
                    break
                last = point
                if point[7] is not None:
                    break
            if last is not None:
                self._replay(last, t0, p0)
                if last[7] is not None:
                    return last[7]
                used = last[1]
            if last is not trace[-1]:
                trace = None  # left inside the trace (until or budget): nothing to add
        return self._run(until, budget, used, trace, t0, p0)

    # == remembered runs =======================================================================
    #
    # Back-and-forth moves and periodic rotations start the same runs again and again.  What a
    # run does is a function of the chip state relative to the motor (ramp state, the fine
    # fraction of the step, the positions the law and the flags depend on relative to
    # XACTUAL, flags and events) and of the ramp parameters; in a chip without position marks
    # from the board, virtual stops, home checks or an encoder tolerance nothing else enters
    # it (NFREEZE counts: a frozen chip locks both directions), and the engine's answers do
    # not depend on ``until`` (HORIZON_TICKS).  So the state
    # after each clock the engine did by itself is kept (a trace, by start state), and a run
    # from a state seen before replays the trace up to ``until`` (or its budget, or a stop)
    # and goes on from there: the same clocks, states, flags and events, worked out once.

    def _recall_key(self) -> tuple | None:
        """The whole input of a run from here, relative to the motor; None: not recallable."""
        board = self.board
        m = self.motor_position
        if board is not None and (board.next_mark(m, 1) is not None
                                  or board.next_mark(m, -1) is not None):
            return None
        xtarget, compare, fixed, virtual_left, virtual_right, home, tolerance = (
            self._setup or self._status_setup())
        if not (virtual_left is None and virtual_right is None and home is None
                and tolerance is None):
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

    def _run(self, until: int, budget: int | None, used: int = 0, trace: list | None = None,
             t0: int = 0, p0: int = 0) -> Stop | None:
        """The engine's run (see :meth:`run`), ``used`` budget units spent already; with a
        ``trace``, each clock it does by itself is appended to it (relative to t0, p0)."""
        ramp = self._ramp
        while self.t < until:
            if budget is not None and used >= budget:
                return None  # out of budget, short of until
            used += 1
            ctx = self._context()
            limit = until - self.t
            plan = ramp.segment_for(ctx)
            action = plan[0]
            if ramp.w or action[0] not in (A_IDLE, A_WAIT):
                positions = self._positions(ctx, action[1] if action[0] == A_START else ramp.s)
            else:
                positions = ()
                self._mark = None
            e = ramp.horizon(ctx, HORIZON_TICKS, positions, plan)
            if e > limit:
                ramp.advance(ctx, limit, plan)
                self.t = until
                self._update_flags()  # nothing rises inside a jump; live flags move on
                return None
            if e > 1:
                ramp.advance(ctx, e - 1, plan)
                self.t += e - 1
                self._update_flags()
            stop = self._tick(ctx)
            if trace is not None:
                if len(trace) < TRACE_POINTS and self._remember(1):
                    trace.append((self.t - t0, used, ramp.p - p0, tuple(
                        [getattr(ramp, name) for name in _MOTION_SLOTS]), self._flags,
                        self.events, self._wake, stop))
                else:
                    trace = None
            if stop is not None:
                return stop
        return None

    def _tick(self, ctx: Context) -> Stop | None:
        """One clock by the letter of the law, then everything that reacts to it."""
        ramp = self._ramp
        moving = ramp.w > 0
        arrived, stopped = ramp.tick(ctx)
        self.t += 1
        at_mark = False
        if self._mark is not None and (self.motor_position - self._mark) * self._mark_dir >= 0:
            self._mark = None
            at_mark = True
            if self.board is not None:
                self.set_pins(*self.board.pins(self.motor_position))
        else:
            self._update_flags()
            self._check_stops()
        if moving and ramp.w == 0 and ramp.stage == Stage.IDLE and not arrived:
            stopped = True
        if arrived:
            return Stop.ARRIVED
        if stopped:
            return Stop.STOPPED
        if at_mark:
            return Stop.MARK
        if self._wake:
            return Stop.EVENT
        return None

    # == what the ramp needs ===================================================================

    def _params(self) -> Params:
        g = self.regs.get
        return _params_for(RampRegisters(
            rampmode=g(Reg.RAMPMODE, 0), vmax=g(Reg.VMAX, 0), vstart=g(Reg.VSTART, 0),
            vstop=g(Reg.VSTOP, 0), vbreak=g(Reg.VBREAK, 0), amax=g(Reg.AMAX, 0),
            dmax=g(Reg.DMAX, 0), astart=g(Reg.ASTART, 0) & 0xFF_FFFF, dfinal=g(Reg.DFINAL, 0),
            dstop=g(Reg.DSTOP, 0), bow1=g(Reg.BOW1, 0), bow2=g(Reg.BOW2, 0),
            bow3=g(Reg.BOW3, 0), bow4=g(Reg.BOW4, 0), clk_freq=g(Reg.CLK_FREQ, 0),
            tzerowait=g(Reg.TZEROWAIT, 0), general_conf=g(Reg.GENERAL_CONF, 0)),
            self.bow_quantum)

    def _unwrap(self, register_value: int) -> int:
        """The motor position at which XACTUAL would read ``register_value`` (nearest way)."""
        return self.motor_position + signed32(register_value - self.xactual)

    def _context(self) -> Context:
        flags = self._flags
        events = self.events
        frozen = self._frozen  # both directions locked until a reset
        return Context(
            target=self._unwrap(self.regs.get(Reg.XTARGET, 0)),
            blocked_neg=frozen or bool(flags & (Status.STOPL_ACTIVE_F | Status.VSTOPL_ACTIVE_F)
                                       or events & (Event.STOPL | Event.VSTOPL_ACTIVE)),
            blocked_pos=frozen or bool(flags & (Status.STOPR_ACTIVE_F | Status.VSTOPR_ACTIVE_F)
                                       or events & (Event.STOPR | Event.VSTOPR_ACTIVE)))

    def _positions(self, ctx: Context, direction: int) -> tuple[int, ...]:
        """Motor positions at which something observable changes (the engine stops there)."""
        g = self.regs.get
        out: list[int] = []
        events = self.events
        conf = g(Reg.REFERENCE_CONF, 0)
        ramp = self._ramp
        if not ramp.P.positioning and not events & Event.TARGET_REACHED:
            out.append(ctx.target)
        if not events & Event.POS_COMP_REACHED:
            out.append(self._unwrap(self._compare_value()))
        if conf & RefConf.VIRTUAL_LEFT_LIMIT_EN:
            left = self._unwrap(g(Reg.VIRT_STOP_LEFT, 0))
            out += (left, left + 1)
        if conf & RefConf.VIRTUAL_RIGHT_LIMIT_EN:
            right = self._unwrap(g(Reg.VIRT_STOP_RIGHT, 0))
            out += (right, right - 1)
        if self._home_expectation() is not None:
            home = self._unwrap(g(Reg.X_HOME, 0))
            margin = g(Reg.HOME_SAFETY_MARGIN, 0)
            out += (home - margin - 1, home - margin, home + margin, home + margin + 1)
        self._mark = None
        if self.board is not None:
            mark = self.board.next_mark(self.motor_position, direction)
            if mark is not None and (mark - self.motor_position) * direction > 0:
                self._mark = mark
                self._mark_dir = direction
                out.append(mark)
        fail = self._encoder_fail_position()
        if fail is not None:
            out.append(fail)
        return tuple(out)

    # == stop switches, virtual stops, home ====================================================

    def _stop_active_raw(self) -> tuple[bool, bool]:
        """(left, right) stop inputs at their active level (after invert_stop_direction)."""
        conf = self.regs.get(Reg.REFERENCE_CONF, 0)
        left, right = self.pin_left, self.pin_right
        if conf & RefConf.INVERT_STOP_DIRECTION:
            left, right = right, left
        return (left == bool(conf & RefConf.POL_STOP_LEFT),
                right == bool(conf & RefConf.POL_STOP_RIGHT))

    def _check_stops(self) -> None:
        """Stop a motion that runs into an active (virtual) stop switch (digest §9.1, §9.2)."""
        ramp = self._ramp
        if ramp.w == 0:
            return
        flags = self._flags
        conf = self.regs.get(Reg.REFERENCE_CONF, 0)
        if ramp.s < 0:
            switch, virtual = Status.STOPL_ACTIVE_F, Status.VSTOPL_ACTIVE_F
        else:
            switch, virtual = Status.STOPR_ACTIVE_F, Status.VSTOPR_ACTIVE_F
        active_switch = flags & switch
        active_virtual = flags & virtual
        if not (active_switch or active_virtual):
            return
        # a hard stop from either source acts at once, even while a soft stop runs
        hard = ((active_switch and not conf & RefConf.SOFT_STOP_EN)
                or (active_virtual and (conf & RefConf.VIRT_STOP_MODE) >> 8 != 2))
        if hard:
            ramp.hard_stop()
            self._update_flags()
        elif not ramp.stopping:
            ramp.stopping = True
            ramp.braking = False

    def _home_kind(self) -> int:
        return (self.regs.get(Reg.REFERENCE_CONF, 0) & RefConf.HOME_EVENT) >> 16

    def _home_expectation(self) -> tuple[bool, bool] | None:
        """Expected HOME_REF level (below, above) the X_HOME window; None: not checked."""
        kind = self._home_kind()
        if kind in HOME_SIDE_TYPES:
            below = HOME_SIDE_TYPES[kind]
            return below, not below
        if kind in HOME_HIGH_ACTIVE:
            return False, False
        if kind in HOME_LOW_ACTIVE:
            return True, True
        return None

    def _home_edge(self, old: bool, new: bool) -> None:
        """A HOME_REF edge: the home event of the selected type, with the present direction."""
        kind = self._home_kind()
        direction = self._ramp.s
        position: int | None = None
        if kind in HOME_SIDE_TYPES:
            position = self.xactual
        elif kind in HOME_HIGH_ACTIVE or kind in HOME_LOW_ACTIVE:
            side = HOME_HIGH_ACTIVE.get(kind) or HOME_LOW_ACTIVE[kind]
            active_level = kind in HOME_HIGH_ACTIVE
            entering = new == active_level
            if side == "centre":
                if entering:
                    self._home_entry = (self.xactual, direction)
                elif self._home_entry is not None:
                    entry, entry_direction = self._home_entry
                    self._home_entry = None
                    if entry_direction == direction:  # passed through, not turned back
                        last_active = self.xactual - direction
                        position = (signed32(entry) + signed32(last_active)) // 2
            elif (side == "left") == (entering == (direction > 0)):
                position = self.xactual
        conf = self.regs.get(Reg.REFERENCE_CONF, 0)
        if position is not None and conf & RefConf.START_HOME_TRACKING and not self._home_latched:
            self.regs[Reg.X_HOME] = position & MASK32
            self._setup = None
            self._home_latched = True
            self._raise(Event.XLATCH_DONE)

    # == flags and events ======================================================================

    @property
    def xactual(self) -> int:
        return (self.motor_position + self._x_offset) & MASK32

    def _compare_value(self) -> int:
        mode = (self.regs.get(Reg.REFERENCE_CONF, 0) & RefConf.MODIFIED_POS_COMPARE) >> 28
        if mode == 1:
            return self.regs.get(Reg.X_HOME, 0)
        if mode == 2:
            return self.x_latch
        return self.regs.get(Reg.POS_COMP, 0)

    def _status_setup(self) -> tuple:
        """What the STATUS flags depend on besides the motion: registers and pin levels, worked
        out once and kept until a register, a pin or a latch changes (``_setup = None``)."""
        setup = self._setup
        if setup is not None:
            return setup
        g = self.regs.get
        conf = g(Reg.REFERENCE_CONF, 0)
        fixed = 0
        left, right = self._stop_active_raw()
        if left and conf & RefConf.STOP_LEFT_EN:
            fixed |= Status.STOPL_ACTIVE_F
        if right and conf & RefConf.STOP_RIGHT_EN:
            fixed |= Status.STOPR_ACTIVE_F
        virtual_left = (signed32(g(Reg.VIRT_STOP_LEFT, 0))
                        if conf & RefConf.VIRTUAL_LEFT_LIMIT_EN else None)
        virtual_right = (signed32(g(Reg.VIRT_STOP_RIGHT, 0))
                         if conf & RefConf.VIRTUAL_RIGHT_LIMIT_EN else None)
        expected = self._home_expectation()
        home = None if expected is None else (
            expected, g(Reg.X_HOME, 0), g(Reg.HOME_SAFETY_MARGIN, 0))
        tolerance = g(Reg.ENC_POS_DEV_TOL, 0)
        setup = self._setup = (g(Reg.XTARGET, 0), self._compare_value(), fixed, virtual_left,
                               virtual_right, home,
                               tolerance if tolerance < 0x8000_0000 else None)
        return setup

    def _status(self) -> int:
        """The live STATUS flags (plus the hidden MAX_PHASE bit)."""
        xtarget, compare, flags, virtual_left, virtual_right, home, tolerance = (
            self._setup or self._status_setup())
        ramp = self._ramp
        P = ramp.P
        x = (ramp.p // P.S + self._x_offset) & MASK32
        if x == xtarget:
            flags |= _TARGET_REACHED_F
        if x == compare:
            flags |= _POS_COMP_REACHED_F
        w = ramp.w
        if w:
            if w == P.V:
                flags |= _VEL_REACHED_F
            flags |= _VEL_STATE_POS if ramp.s > 0 else _VEL_STATE_NEG
            if P.profile == 1 and 0 < P.VBREAK <= w:
                flags |= _MAX_PHASE
        elif not P.V:
            flags |= _VEL_REACHED_F
        a = ramp.a
        if a > 0:
            flags |= _RAMP_STATE_ACC
        elif a < 0:
            flags |= _RAMP_STATE_DEC
        if virtual_left is not None and signed32(x) <= virtual_left:
            flags |= Status.VSTOPL_ACTIVE_F
        if virtual_right is not None and signed32(x) >= virtual_right:
            flags |= Status.VSTOPR_ACTIVE_F
        if home is not None:
            expected, x_home, margin = home
            offset = signed32(x - x_home)
            if (offset < -margin and self.pin_home != expected[0]) or (
                    offset > margin and self.pin_home != expected[1]):
                flags |= Status.HOME_ERROR_F
        if tolerance is not None and abs(self._enc_dev(self.motor_position)) > tolerance:
            flags |= Status.ENC_FAIL_F
        return flags

    def _update_flags(self) -> None:
        """Recompute the flags and latch the events of their transitions."""
        new = self._status()
        old = self._flags
        self._flags = new
        if new == old:
            return
        rising = new & ~old
        events = 0
        for flag, event in FLAG_EVENTS:
            if rising & flag:
                events |= event
        if (new ^ old) & _VEL_STATE:
            events |= (Event.VEL_STATE_POS if new & Status.VEL_STATE_POS else
                       Event.VEL_STATE_NEG if new & Status.VEL_STATE_NEG else Event.VEL_STATE_ZERO)
        if (new ^ old) & _RAMP_STATE:
            events |= (Event.RAMP_STATE_ACC if new & Status.RAMP_STATE_ACC else
                       Event.RAMP_STATE_DEC if new & Status.RAMP_STATE_DEC
                       else Event.RAMP_STATE_CONST)
        if rising & _MAX_PHASE:
            events |= Event.MAX_PHASE_TRAP
        if events:
            self._raise(events)

    def _raise(self, events: int) -> None:
        new = events & ~self.events
        self.events |= events
        self._wake |= new & (self.regs.get(Reg.INTR_CONF, 0) | WAKE_ALWAYS)

    @property
    def interrupt(self) -> bool:
        """INTR output is active (its electrical level follows GENERAL_CONF.intr_pol)."""
        return bool(self.events & self.regs.get(Reg.INTR_CONF, 0))

    def spi_status(self) -> int:
        """The 8 status bits of every reply: the first 8 events selected (ascending bit order)."""
        events = self.events
        if not events:
            return 0
        return _spi_status(events, self.regs.get(Reg.SPI_STATUS_SELECTION, 0))

    # == encoder ===============================================================================

    def _encoder_counts(self, motor_position: int) -> int:
        g = self.regs.get
        if isinstance(self.board, EncoderBoard):
            counts = self.board.encoder_counts(motor_position)
        else:
            resolution = g(Reg.ENC_IN_RES, 0)
            if resolution & MANUAL_ENC_CONST or not resolution:
                return 0
            counts = motor_position * resolution // self._usteps_per_rev()
        return -counts if g(Reg.ENC_IN_CONF, 0) & INVERT_ENC_DIR else counts

    def _usteps_per_rev(self) -> int:
        step_conf = self.regs.get(Reg.STEP_CONF, 0)
        fs_per_rev = (step_conf >> 4) & 0xFFF
        return max(fs_per_rev * (256 >> min(step_conf & 0xF, 8)), 1)

    def _enc_const_now(self) -> tuple[int, int, int]:
        """(numerator, denominator, register) of ENC_CONST from ENC_IN_RES and STEP_CONF."""
        g = self.regs.get
        written = g(Reg.ENC_IN_RES, 0)
        decimal = bool(g(Reg.ENC_IN_CONF, 0) & ENC_SEL_DECIMAL)
        if written & MANUAL_ENC_CONST:
            raw = written & 0x7FFF_FFFF
            if decimal:
                return (raw >> 16) * 10000 + min(raw & 0xFFFF, 9999), 10000, raw
            return raw, 65536, raw
        resolution = written & 0x7FFF_FFFF
        if not resolution:
            return 0, 65536, 0
        whole, rest = divmod(self._usteps_per_rev(), resolution)
        if whole > 0x7FFF:
            whole = 0x7FFF
        if rest * 65536 % resolution == 0 or (rest * 10000 % resolution and not decimal):
            fraction = rest * 65536 // resolution
            return whole * 65536 + fraction, 65536, whole << 16 | fraction
        fraction = rest * 10000 // resolution
        return whole * 10000 + fraction, 10000, whole << 16 | fraction

    def _enc_fine(self, motor_position: int) -> int:
        """ENC_POS times the constant's denominator."""
        numerator, _, _ = self._enc_const
        return self._enc_base + (self._encoder_counts(motor_position)
                                 - self._enc_counts_base) * numerator

    def enc_pos(self, motor_position: int | None = None) -> int:
        m = self.motor_position if motor_position is None else motor_position
        return signed32(self._enc_fine(m) // self._enc_const[1])

    def _enc_rebase(self, value: int | None = None) -> None:
        """Freeze ENC_POS here (or set it to ``value``) before the constant or counting changes."""
        m = self.motor_position
        if value is None:
            value = self.enc_pos(m) if hasattr(self, "_enc_const") else 0
        self._enc_const = self._enc_const_now()
        self._enc_base = value * self._enc_const[1]
        self._enc_counts_base = self._encoder_counts(m)

    def _enc_dev(self, motor_position: int) -> int:
        x = signed32(self.xactual + motor_position - self.motor_position)
        return signed32(self.enc_pos(motor_position) - x)

    def _encoder_fail_position(self) -> int | None:
        """First motor position ahead where |ENC_POS_DEV| exceeds ENC_POS_DEV_TOL.

        Assumes the deviation grows steadily with the distance travelled (a slipping or lagging
        encoder); the search is exponential and then bisects, O(log distance) board queries.
        """
        tolerance = self.regs.get(Reg.ENC_POS_DEV_TOL, 0)
        if tolerance >= 0x8000_0000 or self.events & Event.ENC_FAIL or not self._ramp.w:
            return None
        m = self.motor_position
        s = self._ramp.s
        if abs(self._enc_dev(m)) > tolerance:
            return None
        low, step = 0, 1
        high = None
        while step < 1 << 34:
            if abs(self._enc_dev(m + s * (low + step))) > tolerance:
                high = low + step
                break
            low += step
            step *= 2
        if high is None:
            return None
        while high - low > 1:
            mid = (low + high) // 2
            if abs(self._enc_dev(m + s * mid)) > tolerance:
                high = mid
            else:
                low = mid
        return m + s * high

    def _v_enc(self) -> int:
        """Encoder velocity [pps]: the encoder's rate against the motor at the present speed."""
        ramp = self._ramp
        if not ramp.w:
            return 0
        m = self.motor_position
        span = 1024 * ramp.s
        ratio_num = self.enc_pos(m + span) - self.enc_pos(m)
        v = self._vactual_exact()
        return int(v * ratio_num / span)

    # == register reads and writes =============================================================

    def _vactual_exact(self) -> float:
        r = self._ramp
        return r.s * r.w * r.P.f / r.P.S

    def _read(self, address: int) -> int:
        g = self.regs.get
        if address not in READ_COMPUTED:
            return g(address, 0)  # the read view is what was written
        if address == _STATUS:
            return self._flags & MASK32
        if address == _XACTUAL:
            return self.xactual
        ramp = self._ramp
        match address:
            case Reg.EVENTS:
                value = self.events
                kept = g(Reg.EVENT_CLEAR_CONF, 0) | (Event.FROZEN if self._frozen else 0)
                self.events &= kept  # FROZEN "remains active until the reset"
                self._events_cleared(value & ~kept)
                return value
            case Reg.STATUS:
                return self._flags & MASK32
            case Reg.XACTUAL:
                return self.xactual
            case Reg.VACTUAL:
                magnitude = ramp.w * ramp.P.f // ramp.P.S
                return (ramp.s * magnitude) & MASK32
            case Reg.AACTUAL:
                magnitude = abs(ramp.a) * ramp.P.f * ramp.P.f // ramp.P.S
                sign = 1 if ramp.a >= 0 else -1
                return (ramp.s * sign * magnitude) & MASK32
            case Reg.X_LATCH:
                if g(Reg.GENERAL_CONF, 0) & GeneralConf.CIRCULAR_CNT_AS_XLATCH:
                    return 0  # REV_CNT: circular motion is not emulated
                return self.x_latch
            case Reg.ENC_POS:
                return self.enc_pos() & MASK32
            case Reg.ENC_LATCH:
                return 0  # N channel not emulated
            case Reg.ENC_POS_DEV:
                return self._enc_dev(self.motor_position) & MASK32
            case Reg.ENC_CONST:
                return self._enc_const[2]
            case Reg.V_ENC | Reg.V_ENC_MEAN:
                return self._v_enc() & MASK32
            case Reg.MSCNT:
                return self._mscnt()
            case Reg.CURRENTA_B | Reg.TZEROWAIT:
                return CURRENT_AB_POWER_ON
            case Reg.CIRCULAR_DEC:
                return 0  # SCALE_PARAM
            case Reg.VERSION_NO:
                return VERSION
            case Reg.RESET_CLK_GATING:
                return g(address, 0) & 0x7
            case Reg.COVER_DRV_LOW | Reg.COVER_DRV_HIGH:
                return 0  # no driver answers behind the SPI output
        if address in (Reg.ENC_POS_DEV_TOL, 0x55, 0x56, 0x57, 0x58, 0x5A, 0x5B, 0x5C, 0x5D,
                       0x5E, 0x5F, 0x60, 0x61, 0x62, 0x63, 0x64, 0x68, 0x69, 0x6A, 0x6B,
                       Reg.MSLUTSEL, Reg.ENC_COMP) or 0x70 <= address <= 0x77:
            return 0  # write-only views (or closed-loop / serial-encoder results)
        return g(address, 0)

    def _events_cleared(self, cleared: int) -> None:
        if cleared & Event.XLATCH_DONE and self._home_latched:
            self.regs[Reg.REFERENCE_CONF] = (self.regs.get(Reg.REFERENCE_CONF, 0)
                                             & ~RefConf.START_HOME_TRACKING)
            self._setup = None
            self._home_latched = False

    def _write(self, address: int, data: int) -> None:
        if address in READ_ONLY:
            return
        data &= WRITE_MASKS.get(address, MASK32)
        ramp = self._ramp
        old = self.regs.get(address, 0)
        self._setup = None
        match address:
            case Reg.XACTUAL:
                self._x_offset = data - self.motor_position
                self._update_flags()
                self._check_stops()
                return
            case Reg.EVENTS:
                if self._frozen:
                    data &= ~Event.FROZEN
                cleared = self.events & data
                self.events &= ~data
                self._events_cleared(cleared)
                return
            case Reg.RESET_CLK_GATING:
                if data >> 8 == RESET_KEY:
                    self.power_on()
                    return
                data &= 0x7
            case Reg.FREEZE:
                if self._freeze_written:
                    return
                self._freeze_written = True
            case Reg.ENC_POS:
                self.regs[address] = data
                self._enc_rebase(signed32(data))
                self._update_flags()
                return
            case Reg.ENC_IN_RES | Reg.ENC_IN_CONF | Reg.STEP_CONF:
                self.regs[address] = data
                self._enc_rebase()
                if address == Reg.STEP_CONF:
                    self._mscnt_rebase(old)
                self._update_flags()
                return
            case Reg.COVER_HIGH:
                self.regs[address] = data
                self._raise(Event.COVER_DONE)  # the datagram goes out at once
                return
            case Reg.REFERENCE_CONF:
                if not data & RefConf.START_HOME_TRACKING or not old & RefConf.START_HOME_TRACKING:
                    self._home_latched = False  # armed again by a 0 -> 1 write
        self.regs[address] = data
        if address in RAMP_REGISTERS:
            if data != old:  # the same value leaves the parameters (and their caches) as they are
                ramp.set_params(self._params())
            if address == Reg.RAMPMODE and data != old:
                ramp.mode_changed()
            elif (address == Reg.VMAX and data != old) or address == Reg.BOW3:
                ramp.replan()
        elif address == Reg.XTARGET and data != old:
            ramp.replan()
        self._update_flags()
        self._check_stops()

    def _mscnt(self) -> int:
        step_conf = self.regs.get(Reg.STEP_CONF, 0)
        increment = 1 << min(step_conf & 0xF, 8)
        if self.regs.get(Reg.GENERAL_CONF, 0) & GeneralConf.REVERSE_MOTOR_DIR:
            increment = -increment
        return (self._mscnt_base + (self.motor_position - self._mscnt_m) * increment) & 0x3FF

    def _mscnt_rebase(self, old_step_conf: int) -> None:
        new = self.regs.get(Reg.STEP_CONF, 0)
        self.regs[Reg.STEP_CONF] = old_step_conf
        value = self._mscnt()
        self.regs[Reg.STEP_CONF] = new
        self._mscnt_base = value
        self._mscnt_m = self.motor_position

    # == SPI ===================================================================================

    def spi(self, frame: int) -> int:
        """Exchange one 40-bit datagram; returns the chip's 40-bit answer.

        The answer carries the SPI status (sampled before this frame acts) and the data
        latched at the end of the previous frame: the register it read, or the data it wrote.
        """
        answer = self.spi_status() << 32 | self._spi_out
        address = frame >> 32 & 0x7F
        data = frame & MASK32
        if frame >> 39 & 1:
            self._write(address, data)
            self._spi_out = data
        else:
            self._spi_out = self._read(address) & MASK32
        return answer

    def read(self, reg: int) -> int:
        """Convenience: the 32 data bits of a register (two frames, as the pipeline needs)."""
        self.spi(datagram(reg))
        return self.spi(datagram(reg)) & MASK32

    def write(self, reg: int, data: int) -> None:
        self.spi(datagram(reg, data, write=True))
