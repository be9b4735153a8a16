"""The TMC4361A ramp generator: the motion law, and a fast engine that jumps whole segments.

The law (``docs/tmc4361a.md``, "The motion law") works on exact integers in *fine units*: one
microstep is ``S`` fine units, where ``S`` is chosen so that every register value, at the
programmed CLK_FREQ, is a whole number of fine units per clock (per clock squared, per clock
cubed).  The velocity changes every clock by the acceleration; in S-shaped ramps the
acceleration changes by one *bow quantum* every 64 clocks (datasheet: "AACTUAL alters every
64 clock cycles during the bow phases"), counted from the start of each bow phase.

:meth:`Ramp.tick` is the law for one clock.  :meth:`Ramp.horizon` finds the first upcoming
clock at which the law would do anything but continue the present segment (constant
acceleration, or constant jerk in quanta), and :meth:`Ramp.advance` jumps to just before it
in closed form, so the engine does O(segments) work.  ``tests/axes/reference_tmc4361a.py``
is an independent tick-by-tick transcription of the same law; the tests hold the two equal.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum
from math import isqrt, lcm

#: Clocks per bow quantum (datasheet §6.3.10: AACTUAL alters every 64 clock cycles).
BOW_QUANTUM = 64
#: A braking distance for a ramp that never comes to an end (a bow or deceleration of 0).
NEVER = 1 << 400


class Stage(IntEnum):
    """Where a slope stands; the datasheet's B1..B4 / A1..A3 phases map onto these."""

    IDLE = 0  # at rest
    CRUISE = 1  # |v| constant, no slope in progress
    REC = 2  # the acceleration of the other slope is being taken back to 0
    UP = 3  # |a| rising (B1 on the rising slope, B3 on the falling slope)
    HOLD = 4  # |a| constant (B12 / B34)
    DOWN = 5  # |a| falling (B2 / B4)
    END = 6  # the DFINAL tail of a stop in velocity mode
    CRAWL = 7  # the VSTOP crawl to the target in positioning


RISE, FALL = 1, -1


class Variant(IntEnum):
    """What a falling slope is for."""

    TO_SPEED = 0  # down to a lower target speed (velocity mode, or VMAX lowered)
    TO_ZERO = 1  # to standstill: VMAX = 0, a direction reversal, a stop in velocity mode
    TO_TARGET = 2  # the final approach of a positioning move


def sign(value: int) -> int:
    return (value > 0) - (value < 0)


def signed32(value: int) -> int:
    value &= 0xFFFF_FFFF
    return value - (1 << 32) if value & 0x8000_0000 else value


def fine_scale(clk_freq: int) -> int:
    """Fine units per microstep: every register unit at ``clk_freq`` is a whole number of them.

    Velocity registers count 1/256 pps (1/(256 f) steps per clock), accelerations 1/4 pps²
    (1/(4 f²) per clock²) or, in direct mode, 2^-37 steps per clock²; bows 1 pps³ (1/f³ per
    clock³) or 2^-53 in direct mode.
    """
    f = max(clk_freq, 1)
    return lcm(f ** 3, 1 << 53, 4 * f * f, 256 * f)


@dataclass(frozen=True, slots=True)
class RampRegisters:
    """The raw register values the ramp generator reads."""

    rampmode: int = 0
    vmax: int = 0
    vstart: int = 0
    vstop: int = 0
    vbreak: int = 0
    amax: int = 0
    dmax: int = 0
    astart: int = 0
    dfinal: int = 0
    dstop: int = 0
    bow1: int = 0
    bow2: int = 0
    bow3: int = 0
    bow4: int = 0
    clk_freq: int = 16_000_000
    tzerowait: int = 0
    general_conf: int = 0


@dataclass(frozen=True, slots=True)
class Params:
    """The ramp registers in fine units (see :func:`fine_scale`)."""

    S: int
    f: int
    positioning: bool
    profile: int  # RAMPMODE(1:0): 0 no ramp, 1 trapezoid / SixPoint, 2 S-shaped
    V: int  # |VMAX|
    sv: int  # sign of VMAX
    VSTART: int
    VSTOP: int
    VBREAK: int
    AMAX: int
    DMAX: int
    ASTART: int
    DFINAL: int
    DSTOP: int
    J1: int  # bow quanta (acceleration change per quantum)
    J2: int
    J3: int
    J4: int
    tzerowait: int
    use_astart: bool
    bows_equal: bool  # BOW2 == BOW4: S-ramps pass through v = 0 without stopping
    quantum: int
    margin: int  # how far past the entry of the target step a positioning move aims

    @classmethod
    def from_registers(cls, regs: RampRegisters, quantum: int = BOW_QUANTUM) -> Params:
        f = max(regs.clk_freq, 1)
        S = fine_scale(f)
        direct_a = bool(regs.general_conf & 2)
        direct_j = bool(regs.general_conf & 4)

        def vel(reg: int) -> int:
            return min(reg * S // (256 * f), S)

        def acc(reg: int) -> int:
            return (reg * S) >> 37 if direct_a else reg * S // (4 * f * f)

        def jerk(reg: int) -> int:
            return quantum * ((reg * S) >> 53 if direct_j else reg * S // f ** 3)

        vmax = signed32(regs.vmax)
        V, AMAX, ASTART = vel(abs(vmax)), acc(regs.amax), acc(regs.astart)
        DMAX, DFINAL, VBREAK = acc(regs.dmax), acc(regs.dfinal), vel(regs.vbreak)
        J3, J4 = jerk(regs.bow3), jerk(regs.bow4)
        margin = landing_margin(S, regs.rampmode & 3, V, AMAX, ASTART, DMAX, DFINAL, VBREAK, J3,
                                J4, quantum)
        return cls(S=S, f=f, margin=margin, positioning=bool(regs.rampmode & 4), profile=regs.rampmode & 3,
                   V=vel(abs(vmax)), sv=sign(vmax), VSTART=vel(regs.vstart),
                   VSTOP=vel(regs.vstop), VBREAK=vel(regs.vbreak), AMAX=acc(regs.amax),
                   DMAX=acc(regs.dmax), ASTART=acc(regs.astart), DFINAL=acc(regs.dfinal),
                   DSTOP=acc(regs.dstop), J1=jerk(regs.bow1), J2=jerk(regs.bow2),
                   J3=jerk(regs.bow3), J4=jerk(regs.bow4), tzerowait=regs.tzerowait,
                   use_astart=bool(regs.general_conf & 1),
                   bows_equal=regs.bow2 == regs.bow4, quantum=quantum)


def landing_margin(S: int, profile: int, V: int, AMAX: int, ASTART: int, DMAX: int,
                   DFINAL: int, VBREAK: int, J3: int, J4: int, quantum: int) -> int:
    """How far past the entry of the target step a positioning move aims (fine units).

    The braking decision, taken once per clock, can leave the final approach short of its aim
    by at most one clock of travel plus one clock of acceleration carried through the whole
    braking ramp; aiming that far into the target step lands every normal move inside it.
    Capped at half a step.
    """
    if profile == 2:
        if not (DMAX and J3 and J4):
            return S // 2
        brake_ticks = V // DMAX + 1 + quantum * (DMAX // J3 + DMAX // J4 + 2)
    else:
        decel = min([DMAX] + ([DFINAL] if VBREAK else []))
        if decel == 0:
            return S // 2
        brake_ticks = V // decel + 1
    a = max(AMAX, ASTART)
    return min(S // 2, V + a + a * brake_ticks)


@dataclass(slots=True)
class Context:
    """What the ramp needs from the rest of the chip for one decision."""

    target: int = 0  # XTARGET as an unwrapped microstep position
    blocked_neg: bool = False  # motion in - direction locked by a (virtual) stop switch
    blocked_pos: bool = False


# Actions (what a tick does), chosen by Ramp.decide.
A_IDLE, A_WAIT, A_STOP, A_NORAMP, A_START, A_SPEED, A_FALL, A_POSITION = range(8)


# == closed forms ==============================================================================


def quanta_sums(q0: int, i: int, quantum: int) -> tuple[int, int, int]:
    """For ticks 1..i of a bow phase whose next tick has phase counter ``q0``:

    (c_i, sum of c_k, sum of (i - k + 1) * c_k), where c_k counts the quantum ticks among
    ticks 1..k (a quantum falls on every tick whose phase counter is a multiple of quantum).

    The quanta fall on ticks k_j = k_1 + j * quantum; quantum j adds 1 to every c_k with
    k >= k_j, so the sums are sums over j of M - j * quantum and of its triangle numbers
    (M = i - k_1 + 1): closed forms in small integers.
    """
    first = -q0 % quantum + 1  # k_1
    if i < first:
        return 0, 0, 0
    n = (i - first) // quantum + 1
    M = i - first + 1
    pairs = n * (n - 1)
    s1 = n * M - quantum * pairs // 2
    s2 = (6 * n * M * (M + 1) - 3 * quantum * (2 * M + 1) * pairs
          + quantum * quantum * pairs * (2 * n - 1)) // 12
    return n, s1, s2


def first_nonneg(margin, limit: int) -> int:
    """Smallest i in 1..limit with margin(i) >= 0, for a margin non-decreasing in i.

    Bracketed false position on the exact integer margins (interpolating in floating point),
    with a bisection step whenever an interpolation fails to halve the bracket: a handful of
    evaluations for the smooth margins of a ramp segment, O(log) in the worst case.
    """
    if limit < 1:
        return limit + 1
    f_high = margin(limit)
    if f_high < 0:
        return limit + 1
    f_low = margin(1)
    if f_low >= 0:
        return 1
    low, high = 1, limit
    bisect = False
    while high - low > 1:
        width = high - low
        if bisect:
            probe = (low + high) // 2
        else:
            fl, fh = float(f_low), float(f_high)
            span = fh - fl
            step = int(width * (-fl / span)) if span > 0 else width // 2
            probe = min(max(low + step, low + 1), high - 1)
        f = margin(probe)
        if f >= 0:
            high, f_high = probe, f
        else:
            low, f_low = probe, f
        bisect = not bisect and (high - low) * 2 > width
    return high


def ceil_div(a: int, b: int) -> int:
    return -(-a // b)


# == the ramp ==================================================================================


class Ramp:
    """The ramp generator's state, the law for one clock, and the segment jumper."""

    __slots__ = (
        "P",
        "_distances",
        "a",
        "braking",
        "goal",
        "no_vstart",
        "p",
        "q",
        "s",
        "slope",
        "stage",
        "stopping",
        "w",
        "wait",
    )

    def __init__(self, params: Params) -> None:
        self.P = params
        self.p = 0  # fine position
        self.w = 0  # |velocity|, fine units per clock
        self.s = 1  # direction of motion
        self.a = 0  # acceleration applied in the last tick, + means |v| grew
        self.slope = 0
        self.stage = Stage.IDLE
        self.q = 0  # ticks spent in the present stage
        self.goal: int | None = None  # the speed a DOWN stage was started towards
        self.braking = False  # the final approach of a positioning move is under way
        self.wait = 0  # TZEROWAIT clocks left
        self.no_vstart = False  # a U-turn without TZEROWAIT restarts from 0, not VSTART
        self.stopping = False  # a soft stop (DSTOP) is under way
        #: braking distances by motion state, shared with copies (cleared on new parameters)
        self._distances: dict[tuple, int] = {}

    def copy(self) -> Ramp:
        twin = Ramp.__new__(Ramp)
        for name in Ramp.__slots__:
            setattr(twin, name, getattr(self, name))
        return twin

    # == parameters ============================================================================

    def set_params(self, params: Params) -> None:
        """New register values; the state is kept (rescaled if CLK_FREQ changed)."""
        old = self.P
        self.P = params
        self._distances = {}
        if params.S != old.S:
            self.p = self.p * params.S // old.S
            self.w = self.w * params.S // old.S
            self.a = self.a * params.S // old.S
            if self.goal is not None:
                self.goal = self.goal * params.S // old.S

    def replan(self) -> None:
        """A write that restarts the positioning decision (XTARGET, VMAX changed; BOW3)."""
        self.braking = False

    def mode_changed(self) -> None:
        """RAMPMODE was rewritten: the acceleration starts again from 0 (docs)."""
        self.braking = False
        self.a = 0
        self.slope = 0
        self.stage = Stage.CRUISE if self.w else Stage.IDLE

    def hard_stop(self) -> None:
        self.wait = 0
        self.no_vstart = False
        self.w = 0
        self.a = 0
        self.slope = 0
        self.stage = Stage.IDLE
        self.braking = False
        self.stopping = False

    @property
    def x(self) -> int:
        """The unwrapped microstep position."""
        return self.p // self.P.S

    @property
    def v(self) -> int:
        return self.s * self.w

    def moving_or_due(self, ctx: Context) -> bool:
        """False if nothing will change by itself (at rest, nowhere to go)."""
        return self.w != 0 or self.wait != 0 or self.decide(ctx)[0] != A_IDLE

    # == decisions =============================================================================

    def aim_rem(self, target: int) -> int:
        """Signed fine distance to the aim point of a positioning move (docs: aim point):
        the landing margin past the entry into the target step."""
        S = self.P.S
        offset = self.P.margin
        if self.s > 0:
            return target * S + offset - self.p
        return (target + 1) * S - 1 - offset - self.p

    def decide(self, ctx: Context) -> tuple:
        """The action of the next tick (without performing it)."""
        P = self.P
        if self.wait:
            return (A_WAIT,)
        if self.stopping:
            return (A_STOP,)
        if P.profile == 0:
            return (A_NORAMP,)
        if P.positioning:
            n = ctx.target - self.x
            if self.braking:
                if n * self.s < 0:  # the final approach passed the target: a U-turn (§6.6)
                    return (A_FALL, Variant.TO_ZERO, 0, True)
                return (A_FALL, Variant.TO_TARGET, 0, False)
            direction = sign(n)
            V = P.V
            if (direction < 0 and ctx.blocked_neg) or (direction > 0 and ctx.blocked_pos):
                V = 0
            if V == 0:
                return (A_FALL, Variant.TO_ZERO, 0, False) if self.stage else (A_IDLE,)
            if self.stage == Stage.IDLE:
                return (A_START, direction) if n else (A_IDLE,)
            if n * self.s < 0:
                return (A_FALL, Variant.TO_ZERO, 0, True)
            rem = self.aim_rem(ctx.target)
            if rem * self.s <= 0:
                return (A_FALL, Variant.TO_ZERO, 0, False)
            return (A_POSITION, abs(rem))
        V, sv = P.V, P.sv
        if (sv < 0 and ctx.blocked_neg) or (sv > 0 and ctx.blocked_pos):
            V = 0
        if self.stage == Stage.IDLE:
            return (A_START, sv) if V and sv else (A_IDLE,)
        if sv != self.s or V == 0:
            return (A_FALL, Variant.TO_ZERO, 0, V > 0 and sv != 0)
        return (A_SPEED, V)

    # == one clock =============================================================================

    def tick(self, ctx: Context) -> tuple[bool, bool]:
        """One clock of the law.  Returns (arrived at the target, stopped some other way)."""
        moving = self.w > 0
        if self.wait:
            self.wait -= 1
            return False, False
        action = self.decide(ctx)
        kind = action[0]
        P = self.P
        if kind == A_STOP:
            self.w = max(self.w - P.DSTOP, 0)
            self.a = -P.DSTOP if self.w else 0
            if self.w == 0:
                self.hard_stop()
        elif kind == A_NORAMP:
            self._no_ramp_tick(ctx)
        elif kind != A_IDLE:
            self._apply(action, ctx)
        self.p += self.s * self.w
        if P.positioning and self.x == ctx.target and (
                (P.profile == 0 and (moving or self.w)) or (moving and self.w <= P.VSTOP)):
            self.hard_stop()
            return True, False
        if self.w == 0 and self.stage == Stage.IDLE:
            self.braking = False
        # a stop ends at rest: a BOW2 = BOW4 U-turn that hits v = 0 exactly passes through
        return False, moving and self.w == 0 and self.stage == Stage.IDLE

    def _no_ramp_tick(self, ctx: Context) -> None:
        P = self.P
        self.a = 0
        if P.positioning:
            n = ctx.target - self.x
            blocked = (n < 0 and ctx.blocked_neg) or (n > 0 and ctx.blocked_pos)
            if n:
                self.s = sign(n)
            self.w = P.V if n and not blocked else 0
        else:
            blocked = (P.sv < 0 and ctx.blocked_neg) or (P.sv > 0 and ctx.blocked_pos)
            if P.sv:
                self.s = P.sv
            self.w = P.V if P.sv and not blocked else 0
        self.stage = Stage.CRUISE if self.w else Stage.IDLE

    def _apply(self, action: tuple, ctx: Context) -> None:
        kind = action[0]
        P = self.P
        if kind == A_START:
            self.start(action[1])
            action = (A_POSITION, abs(self.aim_rem(ctx.target))) if P.positioning else (
                A_SPEED, P.V)
            kind = action[0]
        if kind == A_SPEED:
            self.speed_tick(action[1])
        elif kind == A_FALL:
            self.fall_tick(action[1], action[2], action[3])
        elif kind == A_POSITION:
            rem = action[1]
            twin = self.copy()
            twin.speed_tick(P.V)
            if rem - twin.w >= twin.braking_distance():
                self.speed_tick(P.V)
                return
            if (P.profile == 2 and self.slope == RISE and self.stage == Stage.UP and self.a > 0
                    and self.q % P.quantum == P.quantum // 2 and self.w < P.V):
                twin = self.copy()  # skip the B1 quantum: the acceleration stays here
                twin._s_tick(RISE, P.V, Variant.TO_SPEED, False, hold=True)
                if rem - twin.w >= twin.braking_distance():
                    self._s_tick(RISE, P.V, Variant.TO_SPEED, False, hold=True)
                    return
            self.braking = True
            self.fall_tick(Variant.TO_TARGET, 0, False)

    def start(self, direction: int) -> None:
        P = self.P
        self.s = direction
        self.w = 0 if self.no_vstart else P.VSTART
        self.no_vstart = False
        self.slope = RISE
        self.q = 0
        if P.profile == 2:
            self.a = P.AMAX if self.w and not P.use_astart else P.ASTART
            self.stage = Stage.HOLD if self.a >= P.AMAX else Stage.UP
        else:
            self.a = 0
            self.stage = Stage.CRUISE

    def speed_tick(self, goal: int) -> None:
        if self.w < goal:
            self.slope_tick(RISE, goal, Variant.TO_SPEED)
        elif self.w > goal:
            self.slope_tick(FALL, goal, Variant.TO_SPEED)
        else:
            self.a = 0
            self.slope = 0
            self.stage = Stage.CRUISE

    def fall_tick(self, variant: int, goal: int, reversal: bool) -> None:
        self.slope_tick(FALL, goal, variant, reversal)
        if self.w == 0 and reversal and self.stage == Stage.IDLE:
            if self.P.tzerowait:
                self.wait = self.P.tzerowait
            else:
                self.no_vstart = True

    def slope_tick(self, slope: int, goal: int, variant: int, reversal: bool = False) -> None:
        if self.P.profile == 1:
            self._trapezoid_tick(slope, goal, variant)
        else:
            self._s_tick(slope, goal, variant, reversal)

    def _trapezoid_tick(self, slope: int, goal: int, variant: int) -> None:
        P = self.P
        vb = P.VBREAK
        self.slope = slope
        if slope == RISE:
            if vb and self.w < vb:  # ASTART up to VBREAK, landing on it
                rate, w = P.ASTART, min(self.w + P.ASTART, vb)
            else:
                rate, w = P.AMAX, self.w + P.AMAX
            self.a = rate
            self.w = min(w, goal)
            self.stage = Stage.UP if self.w < goal else Stage.CRUISE
            if self.w == goal:
                self.a = 0
            return
        if vb and self.w <= vb:
            rate, w = P.DFINAL, self.w - P.DFINAL
        else:  # DMAX down to VBREAK, landing on it
            rate, w = P.DMAX, self.w - P.DMAX
            if vb:
                w = max(w, vb)
        self.a = -rate
        if variant == Variant.TO_SPEED:
            self.w = max(w, goal)
            if self.w == goal:
                self.a = 0
                self.stage = Stage.CRUISE
        elif variant == Variant.TO_ZERO:
            self.w = w
            if self.w <= P.VSTOP:
                self.w = 0
                self.a = 0
                self.stage = Stage.IDLE
        else:
            floor = min(self.w, P.VSTOP)
            self.w = max(w, floor)
            if self.w == floor:
                self.a = 0
                self.stage = Stage.CRAWL if floor else Stage.IDLE

    def slope_constants(self, slope: int, variant: int, reversal: bool
                        ) -> tuple[int, int, int, int, int, bool, bool]:
        """(j_rec, j_up, j_down, g_max, g_end, continuous, vstop_end) of an S-ramp slope."""
        P = self.P
        continuous = variant == Variant.TO_ZERO and reversal and P.bows_equal
        vstop_end = (variant in (Variant.TO_ZERO, Variant.TO_TARGET) and P.VSTOP > 0
                     and not continuous)
        if slope == RISE:
            return P.J4, P.J1, P.J2, P.AMAX, 0, continuous, vstop_end
        g_end = P.DFINAL if variant == Variant.TO_ZERO else 0
        return P.J2, P.J3, P.J4, P.DMAX, g_end, continuous, vstop_end

    def reach_down(self, g: int, j_down: int, g_end: int) -> int:
        """Velocity change of a DOWN stage started at the next tick with gain ``g``.

        The stage keeps ``g`` for half a quantum, then loses ``j_down`` per quantum until the
        gain reaches ``g_end`` (that tick still counts at the final gain).
        """
        Q = self.P.quantum
        low = min(g_end, g)
        head = (Q // 2) * g
        if g - j_down <= low:
            return head + low
        if j_down == 0:
            return NEVER
        n = ceil_div(g - low, j_down)  # quanta until the gain reaches ``low``
        return head + Q * ((n - 1) * g - j_down * (n - 1) * n // 2) + low

    def _s_tick(self, slope: int, goal: int, variant: int, reversal: bool,
                hold: bool = False) -> None:
        P = self.P
        Q = P.quantum
        H = Q // 2  # the quantum falls half-way through each block of Q ticks
        if self.slope != slope:
            self.switch_slope(slope)
        j_rec, j_up, j_down, g_max, g_end, continuous, vstop_end = self.slope_constants(
            slope, variant, reversal)
        has_down = not (continuous or vstop_end)
        rem = abs(goal - self.w)
        g = slope * self.a
        stage = self.stage
        ended = False
        next_stage = stage
        if stage == Stage.CRAWL:
            stage = Stage.UP
            self.q = 0
        if stage == Stage.REC:
            if self.q % Q == H:
                g = min(g + j_rec, 0)
            next_stage = Stage.UP if g == 0 else Stage.REC
        elif stage in (Stage.UP, Stage.HOLD):
            due = stage == Stage.UP and self.q % Q == H and g < g_max
            g_up = min(g + j_up, g_max) if due else g
            if hold:
                next_stage = Stage.HOLD
            elif not has_down or rem - g_up >= self.reach_down(g_up, j_down, g_end):
                g = g_up
                next_stage = Stage.HOLD if g == g_max or stage == Stage.HOLD else Stage.UP
            elif due and g > 0 and rem - g >= self.reach_down(g, j_down, g_end):
                next_stage = Stage.HOLD  # skip the quantum: the peak acceleration stays here
            elif due and g == 0:
                g = g_up  # nothing to hold at 0: take the quantum, DOWN follows next tick
                next_stage = Stage.HOLD if g == g_max else Stage.UP
            else:
                stage = Stage.DOWN
                self.q = 0
                self.goal = goal
        if stage == Stage.DOWN:
            if self.q % Q == H:
                low = min(g_end, g)
                g -= j_down
                if g <= low:
                    g = low
                    ended = True
            next_stage = Stage.DOWN
        elif stage == Stage.END:
            next_stage = Stage.END
        w = self.w + slope * g
        self.a = slope * g
        if slope == RISE:
            if w >= goal:
                w, next_stage, ended = goal, Stage.CRUISE, False
            elif w <= 0 and g < 0:  # still taking back a deceleration: standstill
                w, next_stage, ended = 0, Stage.IDLE, False
        elif variant == Variant.TO_SPEED:
            if w <= goal:
                w, next_stage, ended = goal, Stage.CRUISE, False
        elif continuous:
            if w < 0:  # through 0: motion continues to XTARGET (§6.6), a new approach
                self.s = -self.s
                self.braking = False
                self.a = min(g, P.AMAX)
                self.slope = RISE
                self.stage = Stage.HOLD if self.a >= P.AMAX else Stage.UP
                self.q = 0
                self.w = -w
                return
        elif vstop_end:
            if w <= P.VSTOP:
                if variant == Variant.TO_ZERO:
                    w, next_stage = 0, Stage.IDLE
                else:
                    w, next_stage = min(self.w, P.VSTOP), Stage.CRAWL
                ended = False
        elif w <= 0:
            w, next_stage, ended = 0, Stage.IDLE, False
        if ended:
            if g == 0:
                if self.goal == goal:
                    w = goal
                next_stage = Stage.CRUISE if w else Stage.IDLE
            else:
                next_stage = Stage.END
        if next_stage in (Stage.CRUISE, Stage.IDLE, Stage.CRAWL):
            self.a = 0
            if next_stage != Stage.CRAWL:
                self.slope = 0
        self.w = w
        self.q = self.q + 1 if next_stage == stage else 0
        self.stage = next_stage

    def switch_slope(self, slope: int) -> None:
        """Map the stage onto the other slope (a shared bow phase keeps its quantum grid)."""
        g_old = self.slope * self.a if self.slope else 0
        if self.slope and self.stage == Stage.DOWN and g_old != 0:
            self.stage = Stage.REC  # RISE DOWN (BOW2) is FALL REC; FALL DOWN (BOW4) RISE REC
        elif self.a * slope < 0:
            self.stage = Stage.REC
            self.q = 0
        else:
            self.stage = Stage.UP
            self.q = 0
        self.slope = slope

    # == braking distance ======================================================================

    def braking_distance(self) -> int:
        """Fine distance the final approach covers from the next tick on, from this state."""
        P = self.P
        if P.profile == 1:
            return self._trapezoid_braking(self.w)
        key = (self.w, self.a, self.slope, self.stage, self.q % P.quantum, self.goal)
        cached = self._distances.get(key)
        if cached is None:
            if len(self._distances) > 4096:
                self._distances.clear()
            cached = self._distances[key] = self._s_braking()
        return cached

    def _s_braking(self) -> int:
        twin = self.copy()
        twin.braking = True
        action = (A_FALL, Variant.TO_TARGET, 0, False)
        ctx = Context()
        total = 0
        while True:
            seg = twin._segment(action)
            if seg is not None:
                e = twin._slope_horizon(action, seg, NEVER)
                if e > NEVER:
                    return NEVER
                total += twin._advance_segment(e - 1, seg)
            twin._apply(action, ctx)
            total += twin.w
            if twin.w == 0 or twin.stage == Stage.CRAWL:
                return total

    def _trapezoid_braking(self, w: int) -> int:
        """D(w) of a trapezoid/SixPoint final approach (monotone in w: the DMAX part lands
        exactly on VBREAK, the rest runs with DFINAL down to the VSTOP floor)."""
        P = self.P
        floor = min(w, P.VSTOP)
        if w == floor:
            return floor
        vb = P.VBREAK
        total = 0
        if not vb or w > vb:
            if P.DMAX == 0:
                return NEVER
            land = max(vb, floor)  # the first clamp the DMAX ticks run into
            n = ceil_div(w - land, P.DMAX) - 1  # ticks strictly above it
            total = n * w - P.DMAX * n * (n + 1) // 2 + land
            if land == floor:
                return total
            w = vb
        if P.DFINAL == 0:
            return NEVER
        n = ceil_div(w - floor, P.DFINAL) - 1
        return total + n * w - P.DFINAL * n * (n + 1) // 2 + floor

    # == the segment jumper ====================================================================

    def _segment(self, action: tuple) -> tuple[int, int, int] | None:
        """(alpha, delta, q0) of the next ticks if they just continue, or None if the next tick
        itself is special.  alpha is the acceleration of the next tick before its quantum (the
        gain is ``alpha + delta * quanta``); delta is the bow quantum (0 for constant)."""
        P = self.P
        kind = action[0]
        if kind == A_STOP:
            return (-P.DSTOP, 0, 0)
        if kind == A_NORAMP:
            return None
        if kind in (A_SPEED, A_POSITION):
            goal = action[1] if kind == A_SPEED else P.V
            if self.w == goal:
                if self.stage != Stage.CRUISE or self.a != 0 or self.slope != 0:
                    return None
                return (0, 0, 0)
            slope = RISE if self.w < goal else FALL
            variant = Variant.TO_SPEED
            reversal = False
        else:
            variant, goal, reversal = action[1], action[2], action[3]
            slope = FALL
        if P.profile == 1:
            if self.slope != slope:
                return None
            vb = P.VBREAK
            if slope == RISE:
                return (P.ASTART if vb and self.w < vb else P.AMAX, 0, 0)
            if variant == Variant.TO_TARGET and self.stage == Stage.CRAWL:
                return (0, 0, 0)
            return (-(P.DFINAL if vb and self.w <= vb else P.DMAX), 0, 0)
        if self.slope != slope:
            return None
        stage = self.stage
        j_rec, j_up, j_down, g_max, g_end, continuous, vstop_end = self.slope_constants(
            slope, variant, reversal)
        del g_end, continuous, vstop_end
        if stage == Stage.CRAWL:
            if variant == Variant.TO_TARGET:
                return (0, 0, 0)
            return None
        if stage == Stage.REC:
            return (self.a, slope * j_rec, self.q)
        if stage == Stage.UP:
            g = slope * self.a
            if g >= g_max:
                return None
            return (self.a, slope * j_up, self.q)
        if stage == Stage.HOLD or stage == Stage.END:
            return (self.a, 0, 0)
        if stage == Stage.DOWN:
            return (self.a, -slope * j_down, self.q)
        return None

    def _state_after(self, seg: tuple[int, int, int], i: int) -> tuple[int, int, int]:
        """(w, gain of tick i, distance) after i continuing ticks of segment ``seg``."""
        alpha, delta, q0 = seg
        if delta == 0:
            return self.w + i * alpha, alpha, i * self.w + alpha * i * (i + 1) // 2
        Q = self.P.quantum
        c_i, s1, s2 = quanta_sums(q0 - Q // 2 + Q, i, Q)
        return (self.w + i * alpha + delta * s1, alpha + delta * c_i,
                i * self.w + alpha * i * (i + 1) // 2 + delta * s2)

    def _advance_segment(self, k: int, seg: tuple[int, int, int]) -> int:
        """Jump ``k`` continuing ticks of segment ``seg``; returns the distance covered."""
        if k <= 0:
            return 0
        w, a, dist = self._state_after(seg, k)
        self.w = w
        self.a = a
        self.p += self.s * dist
        self.q += k
        return dist

    def _quantum_end(self, seg: tuple[int, int, int], limit_value: int) -> int | None:
        """Tick of the quantum that brings the acceleration to ``limit_value`` (None: never)."""
        alpha, delta, q0 = seg
        if delta == 0:
            return None
        n = (ceil_div(limit_value - alpha, delta) if delta > 0
             else ceil_div(alpha - limit_value, -delta))
        Q = self.P.quantum
        first = (Q // 2 - q0) % Q + 1
        return first + (max(n, 1) - 1) * Q

    def _slope_horizon(self, action: tuple, seg: tuple[int, int, int], limit: int) -> int:
        """First tick (1..limit) at which a continuing segment must be done by :meth:`tick`,
        leaving out the braking decision of a positioning move (:meth:`_braking_limit`).

        Returns limit + 1 if the segment lasts beyond ``limit`` (which may be NEVER).
        """
        P = self.P
        kind = action[0]
        alpha = seg[0]
        if kind in (A_SPEED, A_POSITION):
            goal = action[1] if kind == A_SPEED else P.V
            slope = RISE if self.w < goal else FALL if self.w > goal else 0
            variant, reversal = Variant.TO_SPEED, False
        elif kind == A_STOP:
            goal, slope, variant, reversal = 0, FALL, Variant.TO_ZERO, False
        else:
            variant, goal, reversal = action[1], action[2], action[3]
            slope = FALL
        if slope == 0:
            return limit + 1  # cruise
        if kind == A_STOP:
            return min(limit + 1, ceil_div(self.w, -alpha)) if alpha < 0 else limit + 1
        if P.profile == 1:
            return min(limit + 1, self._trapezoid_limits(slope, goal, variant, alpha))
        return self._s_limits(slope, goal, variant, reversal, seg, limit)

    def _trapezoid_limits(self, slope: int, goal: int, variant: int, alpha: int) -> int:
        P = self.P
        w = self.w
        best = NEVER
        if alpha == 0:
            return best
        vb = P.VBREAK
        if vb:  # the tick that lands on VBREAK (the rate changes after it)
            if w < vb and alpha > 0:
                best = min(best, ceil_div(vb - w, alpha))
            elif w > vb and alpha < 0:
                best = min(best, ceil_div(w - vb, -alpha))
        if slope == RISE:
            best = min(best, ceil_div(goal - w, alpha))
        elif variant == Variant.TO_SPEED:
            best = min(best, ceil_div(w - goal, -alpha))
        elif variant == Variant.TO_ZERO:
            best = min(best, max(1, ceil_div(w - P.VSTOP, -alpha)))
        else:
            best = min(best, max(1, ceil_div(w - min(w, P.VSTOP), -alpha)))
        return best

    def _s_limits(self, slope: int, goal: int, variant: int, reversal: bool,
                  seg: tuple[int, int, int], limit: int) -> int:
        P = self.P
        stage = self.stage
        _, _, j_down, g_max, g_end, continuous, vstop_end = self.slope_constants(
            slope, variant, reversal)
        has_down = not (continuous or vstop_end)
        best = limit + 1
        # the quantum that ends the stage
        e = None
        if stage == Stage.REC:
            e = self._quantum_end(seg, 0)
        elif stage == Stage.UP:
            e = self._quantum_end(seg, slope * g_max)
        elif stage == Stage.DOWN:
            e = self._quantum_end(seg, slope * g_end)
        if e is not None:
            best = min(best, e)
        # the velocity clamp
        if slope == RISE:
            threshold, above = goal, True
        elif variant == Variant.TO_SPEED:
            threshold, above = goal, False
        elif continuous:
            threshold, above = -1, False
        elif vstop_end:
            threshold, above = P.VSTOP, False
        else:
            threshold, above = 0, False
        state_after = self._state_after
        if above:
            best = first_nonneg(lambda i: state_after(seg, i)[0] - threshold, best - 1)
            if seg[0] < 0:  # a REC stage of a rising slope may come to rest first
                best = first_nonneg(lambda i: -state_after(seg, i)[0], best - 1)
        else:
            best = first_nonneg(lambda i: threshold - state_after(seg, i)[0], best - 1)
        # the rising/falling rule switching to DOWN (or to HOLD)
        if has_down and stage in (Stage.UP, Stage.HOLD):
            reach_down = self.reach_down

            def fires(i: int) -> int:
                w, a, _ = state_after(seg, i)
                return reach_down(slope * a, j_down, g_end) - abs(goal - w) - 1

            best = first_nonneg(fires, best - 1)
        return best

    def _braking_limit(self, seg: tuple[int, int, int], rem0: int, limit: int) -> int:
        """First tick at which a positioning move must start its final approach."""
        if limit < 1:
            return limit + 1
        if seg == (0, 0, 0) and self.stage == Stage.CRUISE and self.w:
            d = self.braking_distance()  # the same at every tick of a cruise
            if d >= NEVER:
                return 1
            return min(max(1, (rem0 - d) // self.w + 1), limit + 1)

        if self.P.profile == 1:  # the trapezoid's braking distance depends on |v| alone
            state_after = self._state_after
            braking = self._trapezoid_braking

            def brakes_at(i: int) -> int:
                w, _, dist = state_after(seg, i)
                return braking(w) - rem0 + dist - 1

            return first_nonneg(brakes_at, limit)

        def brakes(i: int) -> int:
            twin = self.copy()
            dist = twin._advance_segment(i, seg)
            return twin.braking_distance() - rem0 + dist - 1

        return first_nonneg(brakes, limit)

    def segment_for(self, ctx: Context) -> tuple[tuple, tuple[int, int, int] | None]:
        """The action of the next tick and its continuing segment (None: the tick is special)."""
        action = self.decide(ctx)
        kind = action[0]
        if kind in (A_IDLE, A_WAIT, A_START):
            return action, None
        if kind == A_NORAMP:
            return action, (0, 0, 0) if self._noramp_steady(ctx) else None
        return action, self._segment(action)

    def _noramp_steady(self, ctx: Context) -> bool:
        """True if a no-ramp tick would leave velocity and direction as they are."""
        P = self.P
        if P.positioning:
            n = ctx.target - self.x
            blocked = (n < 0 and ctx.blocked_neg) or (n > 0 and ctx.blocked_pos)
            want = P.V if n and not blocked else 0
            if n and sign(n) != self.s:
                return False
        else:
            blocked = (P.sv < 0 and ctx.blocked_neg) or (P.sv > 0 and ctx.blocked_pos)
            want = P.V if P.sv and not blocked else 0
            if P.sv and P.sv != self.s:
                return False
        return want == self.w and self.a == 0

    def horizon(self, ctx: Context, limit: int, positions: tuple[int, ...] = (),
                plan: tuple[tuple, tuple[int, int, int] | None] | None = None) -> int:
        """First tick (1..limit) that :meth:`tick` must do; limit + 1 if none.

        ``positions``: further unwrapped microstep positions whose arrival the caller wants
        to handle itself (switch marks, compare positions, virtual stops, ...).  ``plan``:
        :meth:`segment_for` of this state and ``ctx``, if the caller has it already.
        """
        if limit < 1:
            return 1
        action, seg = self.segment_for(ctx) if plan is None else plan
        kind = action[0]
        if kind == A_IDLE:
            return limit + 1
        if kind == A_WAIT:
            return min(self.wait + 1, limit + 1)
        if seg is None:
            if kind == A_START and self.start_is_void(ctx):
                return limit + 1  # the start changes nothing, at every tick: at rest
            return 1
        best = limit + 1 if kind == A_NORAMP else self._slope_horizon(action, seg, limit)
        if self.w or seg[0] or seg[1]:
            wanted = list(positions)
            if self.P.positioning:
                wanted += [ctx.target, ctx.target + self.s]
            best = self._steps_limit(wanted, seg, best - 1)
        P = self.P
        if P.positioning and self.x == ctx.target and (self.w or self.stage != Stage.IDLE):
            # inside the target microstep: the move ends at the first tick that starts moving
            # (|v| > 0 before it) and ends with |v| <= VSTOP.  Within a segment |v| is monotone:
            # falling, that tick is a threshold crossing; rising (a move that starts inside its
            # target step, e.g. one step behind), it is the first moving tick or none at all.
            if P.profile == 0:
                return 1
            state_after = self._state_after
            if self.w == 0:  # not moving yet: no arrival before the tick after |v| > 0
                best = min(best, first_nonneg(lambda i: state_after(seg, i)[0] - 1,
                                              best - 1) + 1)
            elif state_after(seg, 1)[0] <= P.VSTOP:
                return 1
            else:
                best = first_nonneg(lambda i: P.VSTOP - state_after(seg, i)[0], best - 1)
        if kind == A_POSITION:
            best = self._braking_limit(seg, action[1], best - 1)
            best = min(best, self._rem_sign_limit(action[1], seg, best - 1))
        return best

    def start_is_void(self, ctx: Context) -> bool:
        """True if a start tick leaves the ramp exactly as it is (e.g. DMAX = 0: a move that
        could never brake does not begin), so every later tick does the same until a register
        or a pin changes: the motor is at rest although a start is pending."""
        twin = self.copy()
        twin.tick(ctx)
        return all(getattr(twin, name) == getattr(self, name) for name in _STATE_SLOTS)

    def _rem_sign_limit(self, rem: int, seg: tuple[int, int, int], limit: int) -> int:
        """The tick after the one that reaches the aim point (the decision changes there)."""
        if limit < 1:
            return limit + 1
        e = self.ticks_to_cover(seg, rem, limit)
        return min(e + 1, limit + 1)

    def _steps_limit(self, positions: list[int], seg: tuple[int, int, int], limit: int) -> int:
        """First tick at which the motor reaches the nearest of ``positions`` ahead of it."""
        nearest = None
        for position in positions:
            d = self.step_distance(position)
            if d is not None and (nearest is None or d < nearest):
                nearest = d
        if nearest is None or limit < 1:
            return limit + 1
        return self.ticks_to_cover(seg, nearest, limit)

    def ticks_to_cover(self, seg: tuple[int, int, int], distance: int, limit: int) -> int:
        """First tick (1..limit, else limit + 1) by which the segment has covered ``distance``."""
        alpha, delta, _ = seg
        w = self.w
        if delta == 0:
            # i*w + alpha*i*(i+1)/2 >= distance: solve the quadratic, then settle exactly
            if alpha == 0:
                if w <= 0:
                    return limit + 1
                return min(ceil_div(distance, w), limit + 1)
            b = 2 * w + alpha
            disc = b * b + 8 * alpha * distance
            if disc < 0:
                return limit + 1
            root = isqrt(disc)
            guess = max(1, (root - b) // (2 * alpha)) if alpha > 0 else max(
                1, (b - root) // (-2 * alpha))
            if guess > limit + 1:
                guess = limit + 1

            def covered(i: int) -> bool:
                return i * w + alpha * i * (i + 1) // 2 >= distance

            while guess > 1 and covered(guess - 1):
                guess -= 1
            while guess <= limit and not covered(guess):
                guess += 1
            return guess
        return first_nonneg(lambda i: self._state_after(seg, i)[2] - distance, limit)

    def step_distance(self, position: int) -> int | None:
        """Fine distance until the unwrapped position ``position`` is reached in direction s."""
        S = self.P.S
        if self.s > 0:
            return position * S - self.p if position > self.x else None
        return self.p - ((position + 1) * S - 1) if position < self.x else None

    def advance(self, ctx: Context, k: int,
                plan: tuple[tuple, tuple[int, int, int] | None] | None = None) -> None:
        """Jump ``k`` ticks that :meth:`horizon` found to be plain continuation (``plan``: as
        for :meth:`horizon`)."""
        if k <= 0:
            return
        action, seg = self.segment_for(ctx) if plan is None else plan
        kind = action[0]
        if kind == A_IDLE:
            return
        if kind == A_WAIT:
            self.wait -= k
            return
        if seg is None and kind == A_START:
            return  # a void start (horizon checked it): nothing changes
        assert seg is not None
        self._advance_segment(k, seg)


#: The slots that make up the motion state (what a tick may change).
MOTION_SLOTS = _STATE_SLOTS = tuple(name for name in Ramp.__slots__
                                    if name not in ("P", "_distances"))
