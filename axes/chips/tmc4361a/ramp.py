"""The TMC4361A ramp generator's fast shortcut: the law jumped over whole segments.

:class:`Ramp` is the law (:class:`axes.chips.tmc4361a.law.RampLaw`, one clock at a time) and
a *segment jumper*: :meth:`Ramp.horizon` finds the first upcoming clock at which the law would
do anything but continue the present segment (constant acceleration, or constant jerk in
quanta), and :meth:`Ramp.advance` jumps to just before it in closed form, so the chip does
O(segments) work.  Equal to the law means: for ``k`` below the horizon, ``advance(ctx, k)``
leaves the state ``k`` clocks of :meth:`RampLaw.tick` reach (``tests/axes/test_tmc4361a_law.py``
holds them equal on random states), and the braking distance it sums segment by segment is
the law's falling-slope clocks summed.  The chip does the clock at the horizon with the law
itself, so ``TMC4361A.run`` equals ``TMC4361A.step``, the law clock by clock.
"""

from __future__ import annotations

from math import isqrt

from axes.chips.tmc4361a.law import MOTION_SLOTS, RampLaw
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
    Stage,
    Variant,
    ceil_div,
    sign,
)

#: The stages whose clocks the law counts in ``q`` (S-shaped slopes; a cruise, a crawl, a
#: trapezoid and no ramp leave it where it is).
_COUNTED_STAGES = frozenset({Stage.REC, Stage.UP, Stage.HOLD, Stage.DOWN, Stage.END})
#: A continuing segment: (acceleration of its next tick before the quantum, the bow quantum
#: (0: constant), the stage's tick counter at its start).
Segment = tuple[int, int, int]


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


class Ramp(RampLaw):
    """The law's state and clock, plus the segment jumper that must equal its clocks."""

    __slots__ = ()

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

    def _slope_of(self, action: tuple) -> tuple[int, int, int, bool]:
        """(slope, goal speed, variant, reversal) of the slope an action runs (slope 0: the
        speed is at its goal already)."""
        kind = action[0]
        if kind in (A_SPEED, A_POSITION):
            goal = action[1] if kind == A_SPEED else self.P.V
            slope = RISE if self.w < goal else FALL if self.w > goal else 0
            return slope, goal, Variant.TO_SPEED, False
        if kind == A_STOP:
            return FALL, 0, Variant.TO_ZERO, False
        return FALL, action[2], action[1], action[3]

    def _segment(self, action: tuple) -> Segment | None:
        """(alpha, delta, q0) of the next ticks if they just continue, or None if the next tick
        itself is special.  alpha is the acceleration of the next tick before its quantum (the
        gain is ``alpha + delta * quanta``); delta is the bow quantum (0 for constant)."""
        kind = action[0]
        if kind == A_STOP:
            return (-self.P.DSTOP, 0, 0)
        if kind == A_NORAMP:
            return None
        slope, _, variant, reversal = self._slope_of(action)
        if slope == 0:  # at the goal speed: a cruise goes on, anything else is special
            cruising = self.stage == Stage.CRUISE and self.a == 0 and self.slope == 0
            return (0, 0, 0) if cruising else None
        if self.slope != slope:
            return None
        if self.P.profile == 1:
            return self._trapezoid_segment(slope, variant)
        return self._s_segment(slope, variant, reversal)

    def _trapezoid_segment(self, slope: int, variant: int) -> Segment:
        """A trapezoid/SixPoint slope's constant rate: ASTART below VBREAK, AMAX above it;
        DMAX above VBREAK, DFINAL at or below it; 0 in the VSTOP crawl."""
        P = self.P
        vb = P.VBREAK
        if slope == RISE:
            return (P.ASTART if vb and self.w < vb else P.AMAX, 0, 0)
        if variant == Variant.TO_TARGET and self.stage == Stage.CRAWL:
            return (0, 0, 0)
        return (-(P.DFINAL if vb and self.w <= vb else P.DMAX), 0, 0)

    def _s_segment(self, slope: int, variant: int, reversal: bool) -> Segment | None:
        """An S-ramp stage as a segment: a bow stage (REC, UP, DOWN) changes the gain by its
        bow quantum on its quantum grid, HOLD and END keep it (so does UP above a lowered
        AMAX: no quantum is due there); an UP stage at its peak, or a crawl that is not the
        final approach's, is special."""
        stage = self.stage
        j_rec, j_up, j_down, g_max, _, _, _ = self.slope_constants(slope, variant, reversal)
        if stage == Stage.CRAWL:
            return (0, 0, 0) if variant == Variant.TO_TARGET else None
        if stage == Stage.REC:
            return (self.a, slope * j_rec, self.q)
        if stage == Stage.UP:
            if slope * self.a > g_max:  # above a lowered AMAX: held, as in HOLD, until DOWN
                return (self.a, 0, 0)
            return None if slope * self.a == g_max else (self.a, slope * j_up, self.q)
        if stage in (Stage.HOLD, Stage.END):
            return (self.a, 0, 0)
        if stage == Stage.DOWN:
            return (self.a, -slope * j_down, self.q)
        return None

    def _state_after(self, seg: Segment, i: int) -> tuple[int, int, int]:
        """(w, gain of tick i, distance) after i continuing ticks of segment ``seg``."""
        alpha, delta, q0 = seg
        if delta == 0:
            return self.w + i * alpha, alpha, i * self.w + alpha * i * (i + 1) // 2
        Q = self.P.quantum
        c_i, s1, s2 = quanta_sums(q0 - Q // 2 + Q, i, Q)
        return (self.w + i * alpha + delta * s1, alpha + delta * c_i,
                i * self.w + alpha * i * (i + 1) // 2 + delta * s2)

    def _advance_segment(self, k: int, seg: Segment, counted: bool = True) -> int:
        """Jump ``k`` continuing ticks of segment ``seg``; returns the distance covered.  The
        stage's tick counter moves on where the law's clocks count it (``counted``: a slope's
        clock, not a soft stop's): the stages of an S-shaped slope (``_settle``)."""
        if k <= 0:
            return 0
        w, a, dist = self._state_after(seg, k)
        self.w = w
        self.a = a
        self.p += self.s * dist
        if counted and self.P.profile == 2 and self.stage in _COUNTED_STAGES:
            self.q += k
        return dist

    def _quantum_end(self, seg: Segment, limit_value: int) -> int | None:
        """Tick of the quantum that brings the acceleration to ``limit_value`` (None: never)."""
        alpha, delta, q0 = seg
        if delta == 0:
            return None
        n = (ceil_div(limit_value - alpha, delta) if delta > 0
             else ceil_div(alpha - limit_value, -delta))
        Q = self.P.quantum
        first = (Q // 2 - q0) % Q + 1
        return first + (max(n, 1) - 1) * Q

    def _slope_horizon(self, action: tuple, seg: Segment, limit: int) -> int:
        """First tick (1..limit) at which a continuing segment must be done by :meth:`tick`,
        leaving out the braking decision of a positioning move (:meth:`_braking_limit`).

        Returns limit + 1 if the segment lasts beyond ``limit`` (which may be NEVER).
        """
        kind = action[0]
        alpha = seg[0]
        slope, goal, variant, reversal = self._slope_of(action)
        if slope == 0:
            return limit + 1  # cruise
        if kind == A_STOP:
            return min(limit + 1, ceil_div(self.w, -alpha)) if alpha < 0 else limit + 1
        if self.P.profile == 1:
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
                  seg: Segment, limit: int) -> int:
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
        state_after = self._state_after
        if slope == RISE:
            best = first_nonneg(lambda i: state_after(seg, i)[0] - goal, best - 1)
            if seg[0] < 0:  # a REC stage of a rising slope may come to rest first
                best = first_nonneg(lambda i: -state_after(seg, i)[0], best - 1)
        else:
            floor = self._fall_floor(goal, variant, continuous, vstop_end)
            best = first_nonneg(lambda i: floor - state_after(seg, i)[0], best - 1)
        # the rising/falling rule switching to DOWN (or to HOLD)
        if has_down and stage in (Stage.UP, Stage.HOLD):
            reach_down = self.reach_down

            def fires(i: int) -> int:
                w, a, _ = state_after(seg, i)
                return reach_down(slope * a, j_down, g_end) - abs(goal - w) - 1

            best = first_nonneg(fires, best - 1)
        return best

    def _fall_floor(self, goal: int, variant: int, continuous: bool, vstop_end: bool) -> int:
        """The speed at or below which a falling S-ramp slope is clamped (the law's
        ``_s_clamp``): the goal, -1 for a pass through 0 (only below 0), VSTOP, or 0."""
        if variant == Variant.TO_SPEED:
            return goal
        if continuous:
            return -1
        return self.P.VSTOP if vstop_end else 0

    def _braking_limit(self, seg: Segment, rem0: int, limit: int) -> int:
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

    def segment_for(self, ctx: Context) -> tuple[tuple, Segment | None]:
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
        direction, speed = self.no_ramp_goal(ctx)
        if direction and direction != self.s:
            return False
        return speed == self.w and self.a == 0

    def horizon(self, ctx: Context, limit: int, positions: tuple[int, ...] = (),
                plan: tuple[tuple, Segment | None] | None = None) -> int:
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
        return self._segment_horizon(ctx, action, seg, limit, positions)

    def _segment_horizon(self, ctx: Context, action: tuple, seg: Segment, limit: int,
                         positions: tuple[int, ...]) -> int:
        """horizon for a continuing segment: the first of its own end, a position reached,
        the arrival in the target step, and the braking decision of a positioning move."""
        kind = action[0]
        best = limit + 1 if kind == A_NORAMP else self._slope_horizon(action, seg, limit)
        best = self._vmax_limit(seg, best)
        if self.w or seg[0] or seg[1]:
            wanted = list(positions)
            if self.P.positioning:
                wanted += [ctx.target, ctx.target + self.s]
            best = self._steps_limit(wanted, seg, best - 1)
        best = self._arrival_limit(ctx, seg, best)
        if kind == A_POSITION:
            best = self._braking_limit(seg, action[1], best - 1)
            best = min(best, self._rem_sign_limit(action[1], seg, best - 1))
        return best

    def _vmax_limit(self, seg: Segment, best: int) -> int:
        """The tick that reaches or passes |VMAX|, or ``best`` if that is later: VEL_REACHED
        is the speed equal to VMAX, which a speed that only passes through it (a slope that
        does not end there, e.g. a braking REC stage whose bow is 0) shows for one tick, and
        the event latches (the law does that tick; within a segment |v| is monotone)."""
        V, w = self.P.V, self.w
        if w == V or not (seg[0] or seg[1]):
            return best
        state_after = self._state_after
        if w < V:
            return first_nonneg(lambda i: state_after(seg, i)[0] - V, best - 1)
        return first_nonneg(lambda i: V - state_after(seg, i)[0], best - 1)

    def _arrival_limit(self, ctx: Context, seg: Segment, best: int) -> int:
        """Inside the target microstep (positioning, moving or about to): the move ends at the
        first tick that starts moving (|v| > 0 before it) and ends with |v| <= VSTOP (the law's
        ``_arrives``), or ``best`` if that is later.  Within a segment |v| is monotone:
        falling, that tick is a threshold crossing; rising (a move that starts inside its
        target step, e.g. one step behind), it is the first moving tick or none at all."""
        P = self.P
        if not P.positioning or self.x != ctx.target or not (self.w or self.stage):
            return best
        if P.profile == 0:
            return 1
        state_after = self._state_after
        if self.w == 0:  # not moving yet: no arrival before the tick after |v| > 0
            return min(best, first_nonneg(lambda i: state_after(seg, i)[0] - 1, best - 1) + 1)
        if state_after(seg, 1)[0] <= P.VSTOP:
            return 1
        return first_nonneg(lambda i: P.VSTOP - state_after(seg, i)[0], best - 1)

    def motion_state_limit(self, seg: Segment | None, limit: int) -> int:
        """First tick (1..limit, else limit + 1) of the segment ahead at which the state the
        chip's VEL_STATE_F and RAMP_STATE_F show changes without the segment ending: the
        acceleration's sign at the segment's first tick (it applies ``alpha`` from there), or
        at the first quantum of a bow stage started at |a| = 0; the speed leaving 0 on a
        segment that starts at rest, or landing on 0 on one that falls.  (Everywhere else
        they change only where :meth:`horizon` stops anyway: the chip asks for this only when
        INTR_CONF wants their events at once.)  ``seg``: the segment ahead (:meth:`segment_for`)."""
        if seg is None or limit < 1:
            return limit + 1
        alpha, delta, q0 = seg
        state_after = self._state_after
        if sign(state_after(seg, 1)[1]) != sign(self.a):
            return 1
        best = limit + 1
        if alpha == 0 and delta:
            Q = self.P.quantum
            best = min(best, (Q // 2 - q0) % Q + 1)
        if self.w == 0 and (alpha or delta):
            best = first_nonneg(lambda i: state_after(seg, i)[0] - 1, best - 1)
        elif self.w > 0 and (alpha < 0 or delta < 0):
            # the speed landing on 0 exactly: a slope that passes through 0 (BOW2 = BOW4)
            # goes on, and its horizon stops only below 0 (falling as that horizon assumes)
            best = first_nonneg(lambda i: -state_after(seg, i)[0], best - 1)
        return best

    def start_is_void(self, ctx: Context) -> bool:
        """True if a start tick leaves the ramp exactly as it is (e.g. DMAX = 0: a move that
        could never brake does not begin), so every later tick does the same until a register
        or a pin changes: the motor is at rest although a start is pending."""
        twin = self.copy()
        twin.tick(ctx)
        return all(getattr(twin, name) == getattr(self, name) for name in _STATE_SLOTS)

    def _rem_sign_limit(self, rem: int, seg: Segment, limit: int) -> int:
        """The tick after the one that reaches the aim point (the decision changes there)."""
        if limit < 1:
            return limit + 1
        e = self.ticks_to_cover(seg, rem, limit)
        return min(e + 1, limit + 1)

    def _steps_limit(self, positions: list[int], seg: Segment, limit: int) -> int:
        """First tick at which the motor reaches the nearest of ``positions`` ahead of it."""
        nearest = None
        for position in positions:
            d = self.step_distance(position)
            if d is not None and (nearest is None or d < nearest):
                nearest = d
        if nearest is None or limit < 1:
            return limit + 1
        return self.ticks_to_cover(seg, nearest, limit)

    def ticks_to_cover(self, seg: Segment, distance: int, limit: int) -> int:
        """First tick (1..limit, else limit + 1) by which the segment has covered ``distance``."""
        if seg[1] == 0:
            return self._ticks_at_constant_rate(seg[0], distance, limit)
        return first_nonneg(lambda i: self._state_after(seg, i)[2] - distance, limit)

    def _ticks_at_constant_rate(self, alpha: int, distance: int, limit: int) -> int:
        """ticks_to_cover for a constant acceleration ``alpha``: i*w + alpha*i*(i+1)/2 >=
        distance, the quadratic solved, then settled exactly."""
        w = self.w
        if alpha == 0:
            return limit + 1 if w <= 0 else min(ceil_div(distance, w), limit + 1)
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

    def step_distance(self, position: int) -> int | None:
        """Fine distance until the unwrapped position ``position`` is reached in direction s."""
        S = self.P.S
        if self.s > 0:
            return position * S - self.p if position > self.x else None
        return self.p - ((position + 1) * S - 1) if position < self.x else None

    def advance(self, ctx: Context, k: int,
                plan: tuple[tuple, Segment | None] | None = None) -> None:
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
        self._advance_segment(k, seg, kind != A_STOP)


#: The slots that make up the motion state (what a tick may change).
_STATE_SLOTS = MOTION_SLOTS
