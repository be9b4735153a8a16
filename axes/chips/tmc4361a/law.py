"""The TMC4361A ramp generator's law: its state and what one clock does to it.

Written down in ``docs/tmc4361a.md`` ("The motion law"), on exact integers in fine units
(:mod:`axes.chips.tmc4361a.params`): each clock the ramp decides (:meth:`RampLaw.decide`),
the velocity changes by the acceleration, in S-shaped ramps the acceleration by one bow
quantum every 64 clocks (datasheet: "AACTUAL alters every 64 clock cycles during the bow
phases") counted from the start of each bow phase, and the position moves by the velocity
(:meth:`RampLaw.tick`).  A positioning move keeps doing what velocity mode would do only
while the final approach started one clock later would still end short of its aim point;
that distance, :meth:`RampLaw.braking_distance`, is the law's own falling-slope clocks
summed, which the fast shortcut computes segment by segment.

The law lives in the product: the chip does every clock that is not plain continuation with
:meth:`RampLaw.tick` (:meth:`axes.chips.tmc4361a.chip.TMC4361A._tick`), and the shortcut
(:class:`axes.chips.tmc4361a.ramp.Ramp`, the segment jumper) must equal it between those
clocks.  ``tests/axes/reference_tmc4361a.py`` stays an independent, literal transcription of
the same law (its braking distance run clock by clock), written apart: the tests hold the
chip to it, and ``tests/axes/test_tmc4361a_law.py`` holds the shortcut to this law.
"""

from __future__ import annotations

from typing import Self

from axes.chips.tmc4361a.params import (
    A_FALL,
    A_IDLE,
    A_NORAMP,
    A_POSITION,
    A_SPEED,
    A_START,
    A_STOP,
    A_WAIT,
    FALL,
    NEVER,
    RISE,
    Context,
    Params,
    Stage,
    Variant,
    ceil_div,
    sign,
)

#: (j_rec, j_up, j_down, g_max, g_end, continuous, vstop_end) of an S-ramp slope.
SlopeConstants = tuple[int, int, int, int, int, bool, bool]


class RampLaw:
    """The ramp generator's state and the law for one clock."""

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

    def copy(self) -> Self:
        twin = type(self).__new__(type(self))
        for name in RampLaw.__slots__:
            setattr(twin, name, getattr(self, name))
        return twin

    def braking_distance(self) -> int:
        """Fine distance the final approach covers from the next tick on, from this state:
        the sum of ``w`` over the clocks of ``fall_tick(TO_TARGET)`` until it rests or
        crawls (NEVER if it never does).  The law leaves how to sum them to the engine."""
        raise NotImplementedError

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
        if self.wait:
            return (A_WAIT,)
        if self.stopping:
            return (A_STOP,)
        if self.P.profile == 0:
            return (A_NORAMP,)
        return self._decide_positioning(ctx) if self.P.positioning else self._decide_velocity(ctx)

    def _decide_positioning(self, ctx: Context) -> tuple:
        n = ctx.target - self.x
        if self.braking:
            if n * self.s < 0:  # the final approach passed the target: a U-turn (§6.6)
                return (A_FALL, Variant.TO_ZERO, 0, True)
            return (A_FALL, Variant.TO_TARGET, 0, False)
        direction = sign(n)
        if self.P.V == 0 or ctx.blocks(direction):
            return (A_FALL, Variant.TO_ZERO, 0, False) if self.stage else (A_IDLE,)
        if self.stage == Stage.IDLE:
            return (A_START, direction) if n else (A_IDLE,)
        if n * self.s < 0:
            return (A_FALL, Variant.TO_ZERO, 0, True)
        rem = self.aim_rem(ctx.target)
        if rem * self.s <= 0:
            return (A_FALL, Variant.TO_ZERO, 0, False)
        return (A_POSITION, abs(rem))

    def _decide_velocity(self, ctx: Context) -> tuple:
        sv = self.P.sv
        V = 0 if ctx.blocks(sv) else self.P.V
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
        if kind == A_STOP:
            self._soft_stop_tick()
        elif kind == A_NORAMP:
            self._no_ramp_tick(ctx)
        elif kind != A_IDLE:
            self._apply(action, ctx)
        self.p += self.s * self.w
        if self._arrives(ctx, moving):
            self.hard_stop()
            return True, False
        if self.w == 0 and self.stage == Stage.IDLE:
            self.braking = False
        # a stop ends at rest: a BOW2 = BOW4 U-turn that hits v = 0 exactly passes through
        return False, moving and self.w == 0 and self.stage == Stage.IDLE

    def _arrives(self, ctx: Context, moving: bool) -> bool:
        """A positioning move ends in the target step: without a ramp at once, else on a clock
        that began moving and ends with |v| <= VSTOP (§5.4)."""
        P = self.P
        if not P.positioning or self.x != ctx.target:
            return False
        if P.profile == 0:
            return moving or self.w != 0
        return moving and self.w <= P.VSTOP

    def _soft_stop_tick(self) -> None:
        """A soft stop (a switch with soft stops, a virtual stop in mode 2): DSTOP every
        clock down to rest."""
        DSTOP = self.P.DSTOP
        self.w = max(self.w - DSTOP, 0)
        self.a = -DSTOP if self.w else 0
        if self.w == 0:
            self.hard_stop()

    def no_ramp_goal(self, ctx: Context) -> tuple[int, int]:
        """(direction, speed) a clock without a ramp (RAMPMODE 1..0 = 0) sets: positioning,
        towards XTARGET at VMAX (0 there); velocity mode, VMAX's sign; 0 where a stop blocks.
        Direction 0: the direction stays."""
        P = self.P
        direction = sign(ctx.target - self.x) if P.positioning else P.sv
        return direction, 0 if not direction or ctx.blocks(direction) else P.V

    def _no_ramp_tick(self, ctx: Context) -> None:
        direction, speed = self.no_ramp_goal(ctx)
        self.a = 0
        if direction:
            self.s = direction
        self.w = speed
        self.stage = Stage.CRUISE if speed else Stage.IDLE

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
            self._position_tick(action[1])

    def _position_tick(self, rem: int) -> None:
        """A positioning clock ``rem`` fine units short of the aim: what velocity mode would
        do towards VMAX if the final approach started a clock later still ends short; else,
        at a B1 quantum of an S-ramp, the same without the quantum; else the final approach."""
        P = self.P
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

    # == trapezoid and SixPoint ================================================================

    def _trapezoid_tick(self, slope: int, goal: int, variant: int) -> None:
        self.slope = slope
        if slope == RISE:
            self._trapezoid_rise(goal)
        else:
            self._trapezoid_fall(goal, variant)

    def _trapezoid_rise(self, goal: int) -> None:
        """ASTART up to VBREAK (landing on it), AMAX above it, up to ``goal``."""
        P = self.P
        vb = P.VBREAK
        if vb and self.w < vb:
            rate, w = P.ASTART, min(self.w + P.ASTART, vb)
        else:
            rate, w = P.AMAX, self.w + P.AMAX
        self.a = rate
        self.w = min(w, goal)
        self.stage = Stage.UP if self.w < goal else Stage.CRUISE
        if self.w == goal:
            self.a = 0

    def _trapezoid_fall(self, goal: int, variant: int) -> None:
        """DMAX down to VBREAK (landing on it), DFINAL below it: to ``goal`` (TO_SPEED), to
        rest at VSTOP (TO_ZERO), or to the VSTOP crawl (TO_TARGET)."""
        P = self.P
        vb = P.VBREAK
        if vb and self.w <= vb:
            rate, w = P.DFINAL, self.w - P.DFINAL
        else:
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

    # == S-shaped ramps ========================================================================

    def slope_constants(self, slope: int, variant: int, reversal: bool) -> SlopeConstants:
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
        """One clock of an S-ramp slope towards ``goal``: the stage's gain (its quantum, if
        due), the velocity, its clamps at the goal, 0 or VSTOP, and the next stage.  ``hold``:
        the acceleration stays (a skipped B1 quantum)."""
        if self.slope != slope:
            self.switch_slope(slope)
        constants = self.slope_constants(slope, variant, reversal)
        stage, next_stage, g, ended = self._s_gain(slope, goal, hold, constants)
        w = self.w + slope * g
        self.a = slope * g
        if constants[5] and slope == FALL and w < 0:  # continuous: through 0, on to XTARGET
            self._pass_zero(w, g)
            return
        w, next_stage, ended = self._s_clamp(slope, goal, variant, constants, w, g, next_stage,
                                             ended)
        if ended:  # DOWN reached its end gain: the DFINAL tail, or at the goal (snapped to it)
            w = goal if not g and self.goal == goal else w
            next_stage = Stage.END if g else Stage.CRUISE if w else Stage.IDLE
        self._settle(stage, next_stage, w)

    def _settle(self, stage: Stage, next_stage: Stage, w: int) -> None:
        """End an S-ramp clock at speed ``w`` in ``next_stage`` (its counter goes on in the same
        stage); a slope that ends (cruise, rest) drops its acceleration, the crawl keeps its
        slope."""
        if next_stage in (Stage.CRUISE, Stage.IDLE, Stage.CRAWL):
            self.a = 0
            if next_stage != Stage.CRAWL:
                self.slope = 0
        self.w = w
        self.q = self.q + 1 if next_stage == stage else 0
        self.stage = next_stage

    def _s_gain(self, slope: int, goal: int, hold: bool, constants: SlopeConstants
                ) -> tuple[Stage, Stage, int, bool]:
        """(stage, next stage, gain this clock, DOWN ended) of an S-ramp clock: the quantum
        falls half-way through each block of Q clocks of a bow stage (REC, UP, DOWN)."""
        j_rec, _, j_down, _, g_end, _, _ = constants
        Q = self.P.quantum
        H = Q // 2
        g = slope * self.a
        stage = self.stage
        if stage == Stage.CRAWL:
            stage = Stage.UP
            self.q = 0
        if stage == Stage.REC:
            if self.q % Q == H:
                g = min(g + j_rec, 0)
            return stage, Stage.UP if g == 0 else Stage.REC, g, False
        if stage in (Stage.UP, Stage.HOLD):
            next_stage, g = self._s_up_or_hold(stage, goal, g, hold, constants)
            if next_stage != Stage.DOWN:
                return stage, next_stage, g, False
            stage = Stage.DOWN
            self.q = 0
            self.goal = goal
        if stage == Stage.DOWN:
            ended = False
            if self.q % Q == H:
                low = min(g_end, g)
                g -= j_down
                if g <= low:
                    g = low
                    ended = True
            return stage, Stage.DOWN, g, ended
        return stage, stage, g, False  # END (the DFINAL tail) stays

    def _s_up_or_hold(self, stage: Stage, goal: int, g: int, hold: bool,
                      constants: SlopeConstants) -> tuple[Stage, int]:
        """UP or HOLD (docs: "When DOWN starts"): the ramp goes on (taking the quantum if due)
        only if a DOWN stage started at the next clock would not overshoot the goal speed;
        else, at a quantum clock with |a| > 0, it skips the quantum; at |a| = 0 it takes it;
        else DOWN starts now.  Returns (next stage, gain), the stage DOWN for "starts now"."""
        g_max = constants[3]
        due = stage == Stage.UP and g < g_max and self._quantum_due()
        g_up = min(g + constants[1], g_max) if due else g
        if hold:
            return Stage.HOLD, g
        if self._down_fits(goal, g_up, constants):
            return (Stage.HOLD if g_up == g_max or stage == Stage.HOLD else Stage.UP), g_up
        if not due or g < 0:
            return Stage.DOWN, g
        if g > 0:  # skip the quantum: the peak acceleration stays here, if DOWN fits then
            return (Stage.HOLD if self._down_fits(goal, g, constants) else Stage.DOWN), g
        # nothing to hold at 0: take the quantum, DOWN follows next tick
        return (Stage.HOLD if g_up == g_max else Stage.UP), g_up

    def _quantum_due(self) -> bool:
        """The bow quantum falls on this clock: half-way through a block of Q clocks of the
        stage."""
        Q = self.P.quantum
        return self.q % Q == Q // 2

    def _down_fits(self, goal: int, g: int, constants: SlopeConstants) -> bool:
        """A DOWN stage started at the next clock after gain ``g`` stays short of ``goal`` (or
        the slope has no DOWN: a pass through 0, an end at VSTOP)."""
        _, _, j_down, _, g_end, continuous, vstop_end = constants
        return (continuous or vstop_end
                or abs(goal - self.w) - g >= self.reach_down(g, j_down, g_end))

    def _s_clamp(self, slope: int, goal: int, variant: int, constants: SlopeConstants,
                 w: int, g: int, next_stage: Stage, ended: bool) -> tuple[int, Stage, bool]:
        """The new speed ``w`` clamped where the slope ends: (speed, next stage, ended)."""
        if slope == RISE:
            return self._rise_clamp(goal, w, g, next_stage, ended)
        if variant == Variant.TO_SPEED:
            return (goal, Stage.CRUISE, False) if w <= goal else (w, next_stage, ended)
        if constants[5]:  # continuous: a pass through 0 (_pass_zero) is not a clamp
            return w, next_stage, ended
        if not constants[6]:  # to rest at 0
            return (0, Stage.IDLE, False) if w <= 0 else (w, next_stage, ended)
        # the slope ends at VSTOP: at rest, or the crawl to the target
        if w > self.P.VSTOP:
            return w, next_stage, ended
        if variant == Variant.TO_ZERO:
            return 0, Stage.IDLE, False
        return min(self.w, self.P.VSTOP), Stage.CRAWL, False

    @staticmethod
    def _rise_clamp(goal: int, w: int, g: int, next_stage: Stage, ended: bool
                    ) -> tuple[int, Stage, bool]:
        """A rising slope's clamps: at the goal it cruises; still taking back a deceleration,
        at 0 it is at rest."""
        if w >= goal:
            return goal, Stage.CRUISE, False
        return (0, Stage.IDLE, False) if w <= 0 and g < 0 else (w, next_stage, ended)

    def _pass_zero(self, w: int, g: int) -> None:
        """A BOW2 = BOW4 reversal through v = 0 (§6.6): the motion continues the other way,
        a new approach, rising with |a| = min(|a|, AMAX)."""
        self.s = -self.s
        self.braking = False
        self.a = min(g, self.P.AMAX)
        self.slope = RISE
        self.stage = Stage.HOLD if self.a >= self.P.AMAX else Stage.UP
        self.q = 0
        self.w = -w

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


#: The slots that make up the motion state (what a tick may change).
MOTION_SLOTS = tuple(name for name in RampLaw.__slots__ if name not in ("P", "_distances"))
