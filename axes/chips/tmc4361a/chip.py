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

from axes.chips.tmc4361a.encoder import EncoderInputs
from axes.chips.tmc4361a.home import HomeTracking
from axes.chips.tmc4361a.params import (
    A_IDLE,
    A_START,
    A_WAIT,
    BOW_QUANTUM,
    Context,
    Params,
    RampRegisters,
    Stage,
)
from axes.chips.tmc4361a.ramp import Ramp
from axes.chips.tmc4361a.recall import RememberedRuns
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
from axes.chips.tmc4361a.turns import TurnPromises
from axes.core import Board, ChipModel, Stop

DEFAULT_CLOCK_HZ = 16_000_000
#: How far ahead (clock ticks) the engine looks for the next clock the law must do by itself,
#: whatever ``until`` a caller gives: the answer, and so the motion, cannot depend on how a
#: caller cuts time into runs.  2^42 ticks: 76 h at 16 MHz.
HORIZON_TICKS = 1 << 42
#: Hidden STATUS bit (above the 32 real ones) that tracks the MAX_PHASE_TRAP condition.
_MAX_PHASE = 1 << 40
_VEL_STATE = Status.VEL_STATE_POS | Status.VEL_STATE_NEG
_TARGET_REACHED_F = Status.TARGET_REACHED_F
_POS_COMP_REACHED_F = Status.POS_COMP_REACHED_F
_VEL_REACHED_F = Status.VEL_REACHED_F
_VEL_STATE_POS = Status.VEL_STATE_POS
_VEL_STATE_NEG = Status.VEL_STATE_NEG
_RAMP_STATE_ACC = Status.RAMP_STATE_ACC
_RAMP_STATE_DEC = Status.RAMP_STATE_DEC
_RAMP_STATE = Status.RAMP_STATE_ACC | Status.RAMP_STATE_DEC
#: Events whose flags can change inside a segment (Ramp.motion_state_limit).
_MOTION_STATE_EVENTS = (Event.VEL_STATE_ZERO | Event.VEL_STATE_POS | Event.VEL_STATE_NEG
                        | Event.RAMP_STATE_CONST | Event.RAMP_STATE_ACC | Event.RAMP_STATE_DEC)
#: REFERENCE_CONF bits whose positions the engine stops at (_limit_positions).
_LIMIT_CHECKS = RefConf.VIRTUAL_LEFT_LIMIT_EN | RefConf.VIRTUAL_RIGHT_LIMIT_EN
#: The event a change of VEL_STATE_F / RAMP_STATE_F latches, by the new state.
_VEL_STATE_EVENTS = {0: Event.VEL_STATE_ZERO, Status.VEL_STATE_POS: Event.VEL_STATE_POS,
                     Status.VEL_STATE_NEG: Event.VEL_STATE_NEG}
_RAMP_STATE_EVENTS = {0: Event.RAMP_STATE_CONST, Status.RAMP_STATE_ACC: Event.RAMP_STATE_ACC,
                      Status.RAMP_STATE_DEC: Event.RAMP_STATE_DEC}
#: The registers read most (plain ints for the hot path of SPI reads).
_STATUS = int(Reg.STATUS)
_XACTUAL = int(Reg.XACTUAL)
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


class TMC4361A(RememberedRuns, HomeTracking, EncoderInputs, TurnPromises, ChipModel):
    """The chip.  Host access is :meth:`spi`; the world drives pins through the board."""

    frame_bits = 40

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, board: Board | None = None,
                 bow_quantum: int = BOW_QUANTUM, recall: bool | None = None) -> None:
        if clock_hz <= 0:
            raise ValueError("clock frequency must be positive")
        self.clock_hz = clock_hz
        self.board = board
        self.bow_quantum = bow_quantum
        if recall is not None:
            self.recall = recall
        self._forget_runs()
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
        self._encoder_reset(m)
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
        if any(before != after and conf & (on_active if after else on_inactive)
               for before, after, on_inactive, on_active in (
                   (old_l, new_l, RefConf.LATCH_X_ON_INACTIVE_L, RefConf.LATCH_X_ON_ACTIVE_L),
                   (old_r, new_r, RefConf.LATCH_X_ON_INACTIVE_R, RefConf.LATCH_X_ON_ACTIVE_R))):
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
        return self._run_remembered(key, until, budget)

    def step(self, until: int) -> Stop | None:
        """The law, one clock at a time, to clock tick ``until`` or the first notable
        instant: what :meth:`run` must equal (the same state at every tick it returns at, the
        same ``Stop``; ``tests/axes/test_tmc4361a_law.py``).  A clock per call: the yardstick
        of the tests, never the simulator's way."""
        self._wake = 0
        while self.t < until:
            ctx = self._context()
            self._watch(ctx, self._ramp.decide(ctx))
            stop = self._tick(ctx)
            if stop is not None:
                return stop
        return None

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
            watched = self._watch(ctx, plan[0])
            e = ramp.horizon(ctx, HORIZON_TICKS, watched, plan)
            if self.regs.get(Reg.INTR_CONF, 0) & _MOTION_STATE_EVENTS and e > 1:
                # events that change inside a segment, wanted at once (EVENT at their clock)
                e = min(e, ramp.motion_state_limit(plan[1], e - 1))
            if e > limit:
                ramp.advance(ctx, limit, plan)
                self.t = until
                self._update_flags()  # nothing rises inside a jump; live flags move on
                return None
            if e > 1:
                ramp.advance(ctx, e - 1, plan)
                self.t += e - 1
                self._update_flags()
                if not watched:  # at rest so far (TZEROWAIT): the clock due may start the
                    ctx = self._context()  # motor, towards marks the law watches from there
                    self._watch(ctx, ramp.decide(ctx))
            stop = self._tick(ctx)
            if trace is not None:
                trace = self._record(trace, t0, p0, used, stop)
            if stop is not None:
                return stop
        return None

    def _watch(self, ctx: Context, action: tuple) -> tuple[int, ...]:
        """The positions where something observable changes (_positions) ahead of a motor
        that moves or is about to (``action``: the law's next), and the board mark to stop
        at among them; none at rest."""
        ramp = self._ramp
        if ramp.w or action[0] not in (A_IDLE, A_WAIT):
            return self._positions(ctx, action[1] if action[0] == A_START else ramp.s)
        self._mark = None
        return ()

    def _tick(self, ctx: Context) -> Stop | None:
        """One clock by the letter of the law, then everything that reacts to it."""
        ramp = self._ramp
        moving = ramp.w > 0
        arrived, stopped = ramp.tick(ctx)
        self.t += 1
        at_mark = self._reached_mark()
        if not at_mark:
            self._update_flags()
            self._check_stops()
        if arrived:
            return Stop.ARRIVED
        if stopped or (moving and ramp.w == 0 and ramp.stage == Stage.IDLE):
            return Stop.STOPPED
        if at_mark:
            return Stop.MARK
        return Stop.EVENT if self._wake else None

    def _reached_mark(self) -> bool:
        """The motor reached the board mark ahead (_watch): the board drives the pins."""
        if self._mark is None or (self.motor_position - self._mark) * self._mark_dir < 0:
            return False
        self._mark = None
        if self.board is not None:
            self.set_pins(*self.board.pins(self.motor_position))
        return True

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
        if conf & _LIMIT_CHECKS or self._home_expectation() is not None:
            out += self._limit_positions(conf)
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

    def _limit_positions(self, conf: int) -> list[int]:
        """The edges of the virtual stops and of the home window (where the flags change)."""
        g = self.regs.get
        out: list[int] = []
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
        return out

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
        out once and kept until a register, a pin or a latch changes (``_setup = None``):
        (XTARGET, the compare value, the stop switch flags, the position checks or None)."""
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
        setup = self._setup = (g(Reg.XTARGET, 0), self._compare_value(), fixed,
                               self._position_checks())
        return setup

    def _position_checks(self) -> tuple | None:
        """(virtual left stop, virtual right stop, home window, encoder tolerance), each None
        where it is off; None if all are: what the flags check at each position."""
        g = self.regs.get
        conf = g(Reg.REFERENCE_CONF, 0)
        virtual_left = (signed32(g(Reg.VIRT_STOP_LEFT, 0))
                        if conf & RefConf.VIRTUAL_LEFT_LIMIT_EN else None)
        virtual_right = (signed32(g(Reg.VIRT_STOP_RIGHT, 0))
                         if conf & RefConf.VIRTUAL_RIGHT_LIMIT_EN else None)
        expected = self._home_expectation()
        home = None if expected is None else (
            expected, g(Reg.X_HOME, 0), g(Reg.HOME_SAFETY_MARGIN, 0))
        tolerance = g(Reg.ENC_POS_DEV_TOL, 0)
        checks = (virtual_left, virtual_right, home,
                  tolerance if tolerance < 0x8000_0000 else None)
        return None if checks == (None, None, None, None) else checks

    def _status(self) -> int:
        """The live STATUS flags (plus the hidden MAX_PHASE bit)."""
        xtarget, compare, flags, checks = self._setup or self._status_setup()
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
        if a:
            flags |= _RAMP_STATE_ACC if a > 0 else _RAMP_STATE_DEC
        return flags if checks is None else flags | self._checked_flags(x, checks)

    def _checked_flags(self, x: int, checks: tuple) -> int:
        """The flags of the position checks (_position_checks) with XACTUAL at ``x``."""
        virtual_left, virtual_right, home, tolerance = checks
        flags = 0
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
        changed = new ^ old
        if changed & _VEL_STATE:
            events |= _VEL_STATE_EVENTS[new & _VEL_STATE]
        if changed & _RAMP_STATE:
            events |= _RAMP_STATE_EVENTS[new & _RAMP_STATE]
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

    # == register reads and writes =============================================================

    def _read(self, address: int) -> int:
        # STATUS and XACTUAL first, in line: the firmware reads them at every look
        if address == _STATUS:
            return self._flags & MASK32
        if address == _XACTUAL:
            return self.xactual
        read = _COMPUTED_READS.get(address)
        return self.regs.get(address, 0) if read is None else read(self)  # else what was written

    def _read_events(self) -> int:
        """EVENTS: read and cleared, but for EVENT_CLEAR_CONF's bits and FROZEN ("remains
        active until the reset")."""
        value = self.events
        kept = self.regs.get(Reg.EVENT_CLEAR_CONF, 0) | (Event.FROZEN if self._frozen else 0)
        self.events &= kept
        self._events_cleared(value & ~kept)
        return value

    def _read_vactual(self) -> int:
        ramp = self._ramp
        return (ramp.s * (ramp.w * ramp.P.f // ramp.P.S)) & MASK32

    def _read_aactual(self) -> int:
        ramp = self._ramp
        magnitude = abs(ramp.a) * ramp.P.f * ramp.P.f // ramp.P.S
        return (ramp.s * (1 if ramp.a >= 0 else -1) * magnitude) & MASK32

    def _read_x_latch(self) -> int:
        if self.regs.get(Reg.GENERAL_CONF, 0) & GeneralConf.CIRCULAR_CNT_AS_XLATCH:
            return 0  # REV_CNT: circular motion is not emulated
        return self.x_latch

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
        old = self.regs.get(address, 0)
        self._setup = None
        special = _SPECIAL_WRITES.get(address)
        if special is not None:
            stored = special(self, data, old)
            if stored is None:
                return  # the write did all it does
            data = stored
        self.regs[address] = data
        ramp = self._ramp
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

    # Writes with side effects of their own: each returns the value to store (then the ramp
    # and the flags take it as any write), or None when it has done all the write does.

    def _write_xactual(self, data: int, old: int) -> int | None:
        self._x_offset = data - self.motor_position
        self._update_flags()
        self._check_stops()
        return None

    def _write_events(self, data: int, old: int) -> int | None:
        """Writing 1 clears an event (FROZEN stays until the reset)."""
        if self._frozen:
            data &= ~Event.FROZEN
        cleared = self.events & data
        self.events &= ~data
        self._events_cleared(cleared)
        return None

    def _write_reset(self, data: int, old: int) -> int | None:
        """RESET_CLK_GATING: the reset key resets the chip; else the clock gating bits."""
        if data >> 8 == RESET_KEY:
            self.power_on()
            return None
        return data & 0x7

    def _write_freeze(self, data: int, old: int) -> int | None:
        """FREEZE (DFREEZE, IFS_FREEZE) can be written once after a reset."""
        if self._freeze_written:
            return None
        self._freeze_written = True
        return data

    def _write_enc_pos(self, data: int, old: int) -> int | None:
        self.regs[Reg.ENC_POS] = data
        self._enc_rebase(signed32(data))
        self._update_flags()
        return None

    def _write_encoder_setup(self, address: int, data: int, old: int) -> None:
        """ENC_IN_RES, ENC_IN_CONF, STEP_CONF: ENC_POS (and MSCNT) kept where they are, the
        constant and the counting from here on new."""
        self.regs[address] = data
        self._enc_rebase()
        if address == Reg.STEP_CONF:
            self._mscnt_rebase(old)
        self._update_flags()

    def _write_cover_high(self, data: int, old: int) -> int | None:
        self.regs[Reg.COVER_HIGH] = data
        self._raise(Event.COVER_DONE)  # the datagram goes out at once
        return None

    def _write_reference_conf(self, data: int, old: int) -> int | None:
        if not data & RefConf.START_HOME_TRACKING or not old & RefConf.START_HOME_TRACKING:
            self._home_latched = False  # armed again by a 0 -> 1 write
        return data

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


def _encoder_setup(address: int) -> Callable[[TMC4361A, int, int], int | None]:
    def write(chip: TMC4361A, data: int, old: int) -> None:
        chip._write_encoder_setup(address, data, old)
    return write


#: Reads that are worked out (the others read what was written); every other address of
#: READ_COMPUTED reads 0: write-only views, and closed-loop and serial-encoder results.
_COMPUTED_READS: dict[int, Callable[[TMC4361A], int]] = {
    **{address: lambda chip: 0 for address in READ_COMPUTED},
    Reg.EVENTS: TMC4361A._read_events,
    Reg.STATUS: lambda chip: chip._flags & MASK32,
    Reg.XACTUAL: lambda chip: chip.xactual,
    Reg.VACTUAL: TMC4361A._read_vactual,
    Reg.AACTUAL: TMC4361A._read_aactual,
    Reg.X_LATCH: TMC4361A._read_x_latch,
    Reg.ENC_POS: lambda chip: chip.enc_pos() & MASK32,  # ENC_LATCH reads 0: no N channel
    Reg.ENC_POS_DEV: lambda chip: chip._enc_dev(chip.motor_position) & MASK32,
    Reg.ENC_CONST: lambda chip: chip._enc_const[2],
    Reg.V_ENC: lambda chip: chip._v_enc() & MASK32,
    Reg.V_ENC_MEAN: lambda chip: chip._v_enc() & MASK32,
    Reg.MSCNT: TMC4361A._mscnt,
    Reg.CURRENTA_B: lambda chip: CURRENT_AB_POWER_ON,
    Reg.TZEROWAIT: lambda chip: CURRENT_AB_POWER_ON,  # its read view is CURRENTA_B
    Reg.VERSION_NO: lambda chip: VERSION,
    Reg.RESET_CLK_GATING: lambda chip: chip.regs.get(Reg.RESET_CLK_GATING, 0) & 0x7,
    # CIRCULAR_DEC reads SCALE_PARAM 0; COVER_DRV_LOW/HIGH 0: no driver answers behind SPI
}

#: Writes with side effects of their own (the others are stored, then act on the ramp).
_SPECIAL_WRITES: dict[int, Callable[[TMC4361A, int, int], int | None]] = {
    Reg.XACTUAL: TMC4361A._write_xactual,
    Reg.EVENTS: TMC4361A._write_events,
    Reg.RESET_CLK_GATING: TMC4361A._write_reset,
    Reg.FREEZE: TMC4361A._write_freeze,
    Reg.ENC_POS: TMC4361A._write_enc_pos,
    Reg.ENC_IN_RES: _encoder_setup(Reg.ENC_IN_RES),
    Reg.ENC_IN_CONF: _encoder_setup(Reg.ENC_IN_CONF),
    Reg.STEP_CONF: _encoder_setup(Reg.STEP_CONF),
    Reg.COVER_HIGH: TMC4361A._write_cover_high,
    Reg.REFERENCE_CONF: TMC4361A._write_reference_conf,
}
