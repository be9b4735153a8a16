"""The TMC4361A ramp generator, one clock tick at a time: the law the fast engine must obey.

A literal transcription of the motion law written down in ``docs/tmc4361a.md`` ("The motion
law"): exact integer state in *fine units* (one microstep = ``S`` fine units, velocities in
fine units per clock, accelerations in fine units per clock squared); the velocity changes
every clock; in S-ramps the acceleration changes by one bow quantum half-way through each
block of ``quantum`` clocks, counted from the start of the bow stage; a positioning move keeps
doing what velocity mode would do only while the final approach started one clock later
would still end short of its aim point (a landing margin past the entry of the target step).
The braking distance is found by simply running the final approach on a copy, tick by tick
(memoised; a final approach longer than a million clocks counts as never ending).  Slow on
purpose: ``tests/axes/test_tmc4361a.py`` compares the fast engine of ``axes/chips/tmc4361a`` with
it.  No switches, events or encoder here: motion only.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from math import lcm

# Stages of a slope (the same numbers as the chip's, but defined here on their own).
IDLE, CRUISE, REC, UP, HOLD, DOWN, END, CRAWL = range(8)
RISE, FALL = 1, -1
# Falling-slope variants
TO_SPEED, TO_ZERO, TO_TARGET = range(3)
NEVER = 1 << 200  # braking distance of a ramp that never ends


def _signed32(value: int) -> int:
    value &= 0xFFFF_FFFF
    return value - (1 << 32) if value & 0x8000_0000 else value


def _sign(value: int) -> int:
    return (value > 0) - (value < 0)


@dataclass
class Registers:
    """The ramp registers, as written over SPI (raw register values)."""

    rampmode: int = 0
    vmax: int = 0  # signed 24.8
    vstart: int = 0
    vstop: int = 0
    vbreak: int = 0
    amax: int = 0
    dmax: int = 0
    astart: int = 0
    dfinal: int = 0
    bow1: int = 0
    bow2: int = 0
    bow3: int = 0
    bow4: int = 0
    clk_freq: int = 16_000_000
    tzerowait: int = 0
    general_conf: int = 0
    xtarget: int = 0


class ReferenceRamp:
    def __init__(self, regs: Registers, quantum: int = 64) -> None:
        self.regs = regs
        self.quantum = quantum
        self.t = 0
        self.p = 0  # fine position; XACTUAL = p // S
        self.w = 0  # speed magnitude, fine units per clock
        self.s = 1  # direction of motion
        self.a = 0  # acceleration applied in the last tick, signed in the |v| frame
        self.slope = 0
        self.stage = IDLE
        self.q = 0  # ticks spent in the current stage
        self.goal: int | None = None  # the speed a DOWN stage was started towards
        self.braking = False
        self.wait = 0
        self.no_vstart = False
        self.arrivals: list[int] = []
        self.stops: list[int] = []
        self._distances: dict[tuple, int] = {}
        self._reaches: dict[tuple, int] = {}
        self._derive()

    # == units =================================================================================

    def _derive(self) -> None:
        r = self.regs
        f = max(r.clk_freq, 1)
        self.S = S = lcm(f ** 3, 1 << 53, 4 * f * f, 256 * f)
        direct_a = r.general_conf & 2
        direct_j = r.general_conf & 4

        def vel(reg: int) -> int:
            return min(reg * S // (256 * f), S)

        def acc(reg: int) -> int:
            return (reg * S) >> 37 if direct_a else reg * S // (4 * f * f)

        def jerk(reg: int) -> int:
            return self.quantum * ((reg * S) >> 53 if direct_j else reg * S // f ** 3)

        vmax = _signed32(r.vmax)
        self.V = vel(abs(vmax))
        self.sv = _sign(vmax)
        self.VSTART, self.VSTOP, self.VBREAK = vel(r.vstart), vel(r.vstop), vel(r.vbreak)
        self.AMAX, self.DMAX = acc(r.amax), acc(r.dmax)
        self.ASTART, self.DFINAL = acc(r.astart), acc(r.dfinal)
        self.J1, self.J2, self.J3, self.J4 = (jerk(b) for b in (r.bow1, r.bow2, r.bow3, r.bow4))
        self.positioning = bool(r.rampmode & 4)
        self.profile = r.rampmode & 3
        self.margin = self._landing_margin()

    def _landing_margin(self) -> int:
        """How far past the entry of the target step a positioning move aims (docs)."""
        S, Q = self.S, self.quantum
        if self.profile == 2:
            if not (self.DMAX and self.J3 and self.J4):
                return S // 2
            brake_ticks = self.V // self.DMAX + 1 + Q * (
                self.DMAX // self.J3 + self.DMAX // self.J4 + 2)
        else:
            decel = min([self.DMAX] + ([self.DFINAL] if self.VBREAK else []))
            if decel == 0:
                return S // 2
            brake_ticks = self.V // decel + 1
        a = max(self.AMAX, self.ASTART)
        return min(S // 2, self.V + a + a * brake_ticks)

    def write(self, name: str, value: int) -> None:
        """A register write: the same re-planning rules as the chip (docs/tmc4361a.md)."""
        old = getattr(self.regs, name)
        setattr(self.regs, name, value)
        self._derive()
        self._distances = {}
        self._reaches = {}
        if (name in ("xtarget", "vmax", "rampmode") and value != old) or name == "bow3":
            self.braking = False
        if name == "rampmode" and value != old:
            self.a = 0
            self.slope = 0
            self.stage = CRUISE if self.w else IDLE

    # == observation ===========================================================================

    @property
    def x(self) -> int:
        return self.p // self.S

    @property
    def v(self) -> int:
        return self.s * self.w

    # == one clock tick ========================================================================

    def tick(self) -> None:
        self.t += 1
        moving = self.w > 0
        if self.wait:
            self.wait -= 1
            return
        target = self.x + _signed32(self.regs.xtarget - self.x)
        if self.profile == 0:
            self._no_ramp_tick(target)
        else:
            action = self._choose(target)
            if action is not None:
                self._apply(action, target)
        self.p += self.s * self.w
        at_target = self.positioning and self.x == target
        if at_target and (self.w or moving) if self.profile == 0 else (
                at_target and moving and self.w <= self.VSTOP):
            self._rest()
            self.arrivals.append(self.t)
        elif moving and self.w == 0 and self.stage == IDLE:  # not a BOW2 = BOW4 pass at 0
            self.stops.append(self.t)
        if self.w == 0 and self.stage == IDLE:
            self.braking = False

    def _no_ramp_tick(self, target: int) -> None:
        """RAMPMODE(1:0) = 0: the velocity jumps (positioning: towards XTARGET, 0 there)."""
        self.a = 0
        if self.positioning:
            n = target - self.x
            if n:
                self.s = _sign(n)
            self.w = self.V if n else 0
        else:
            if self.sv:
                self.s = self.sv
            self.w = self.V if self.sv else 0
        self.stage = CRUISE if self.w else IDLE

    def _rest(self) -> None:
        self.wait = 0
        self.no_vstart = False
        self.w = 0
        self.a = 0
        self.slope = 0
        self.stage = IDLE
        self.braking = False

    def _aim_rem(self, target: int) -> int:
        """Signed fine distance from here to the aim point (docs: "aim point"): the landing
        margin past the entry into the target microstep."""
        S = self.S
        offset = self.margin
        if self.s > 0:
            return target * S + offset - self.p
        return (target + 1) * S - 1 - offset - self.p

    def _choose(self, target: int) -> tuple | None:
        if self.positioning:
            if self.braking:
                if (target - self.x) * self.s < 0:  # past the target: U-turn, datasheet §6.6
                    return ("fall", TO_ZERO, 0, True)
                return ("fall", TO_TARGET, 0)
            if self.V == 0:
                return ("fall", TO_ZERO, 0) if self.stage != IDLE else None
            if self.stage == IDLE:
                if target == self.x:
                    return None
                return ("start", _sign(target - self.x))
            if (target - self.x) * self.s < 0:
                return ("fall", TO_ZERO, 0, True)
            rem = self._aim_rem(target)
            if rem * self.s <= 0:
                return ("fall", TO_ZERO, 0, False)
            return ("position", abs(rem))
        if self.stage == IDLE:
            return ("start", self.sv) if self.V and self.sv else None
        if self.sv != self.s or self.V == 0:
            return ("fall", TO_ZERO, 0, self.V > 0 and self.sv != 0)
        return ("speed", self.V)

    def _apply(self, action: tuple, target: int) -> None:
        kind = action[0]
        if kind == "start":
            self._start(action[1])
            if self.positioning:
                kind, action = "position", ("position", abs(self._aim_rem(target)))
            else:
                kind, action = "speed", ("speed", self.V)
        if kind == "speed":
            self._speed_tick(action[1])
        elif kind == "fall":
            self._fall_tick(action[1], action[2], action[3] if len(action) > 3 else False)
        elif kind == "position":
            rem = action[1]
            twin = copy.copy(self)
            twin._speed_tick(self.V)
            if rem - twin.w >= twin._braking_distance():
                self._speed_tick(self.V)
                return
            if (self.profile == 2 and self.slope == RISE and self.stage == UP and self.a > 0
                    and self.q % self.quantum == self.quantum // 2 and self.w < self.V):
                twin = copy.copy(self)  # skip the B1 quantum: the acceleration stays here
                twin._s_tick(RISE, self.V, TO_SPEED, hold=True)
                if rem - twin.w >= twin._braking_distance():
                    self._s_tick(RISE, self.V, TO_SPEED, hold=True)
                    return
            self.braking = True
            self._fall_tick(TO_TARGET, 0, False)

    def _start(self, direction: int) -> None:
        self.s = direction
        self.w = 0 if self.no_vstart else self.VSTART
        self.no_vstart = False
        self.slope = RISE
        self.q = 0
        if self.profile == 2:
            use_astart = self.regs.general_conf & 1
            self.a = self.AMAX if self.w and not use_astart else self.ASTART
            self.stage = HOLD if self.a >= self.AMAX else UP
        else:
            self.a = 0
            self.stage = CRUISE

    def _braking_distance(self) -> int:
        """Distance the braking ramp covers from the next tick on (run on a copy).

        Memoised on the whole motion state the braking ramp depends on (the position does
        not enter it), so a cruise asks only once.
        """
        key = (self.w, self.a, self.s, self.slope, self.stage, self.q % self.quantum, self.goal)
        cached = self._distances.get(key)
        if cached is not None:
            return cached
        twin = copy.copy(self)
        twin.braking = True
        total = 0
        for _ in range(1_000_000):
            twin._fall_tick(TO_TARGET, 0, False)
            total += twin.w
            if twin.w == 0 or twin.stage == CRAWL:
                break
        else:
            total = NEVER
        self._distances[key] = total
        return total

    # == the velocity laws =====================================================================

    def _speed_tick(self, goal: int) -> None:
        """Velocity-mode style: rise to, fall to, or hold ``goal`` in the current direction."""
        if self.w < goal:
            self._slope_tick(RISE, goal, TO_SPEED)
        elif self.w > goal:
            self._slope_tick(FALL, goal, TO_SPEED)
        else:
            self.a = 0
            self.slope = 0
            self.stage = CRUISE

    def _fall_tick(self, variant: int, goal: int, reversal: bool) -> None:
        self._slope_tick(FALL, goal, variant, reversal)
        if self.w == 0 and reversal and self.stage == IDLE:
            if self.regs.tzerowait:
                self.wait = self.regs.tzerowait
            else:
                self.no_vstart = True

    def _slope_tick(self, slope: int, goal: int, variant: int, reversal: bool = False) -> None:
        if self.profile == 1:
            self._trapezoid_tick(slope, goal, variant)
        else:
            self._s_tick(slope, goal, variant, reversal)

    def _trapezoid_tick(self, slope: int, goal: int, variant: int) -> None:
        vb = self.VBREAK
        self.slope = slope
        if slope == RISE:
            if vb and self.w < vb:  # ASTART up to VBREAK, landing on it
                rate, w = self.ASTART, min(self.w + self.ASTART, vb)
            else:
                rate, w = self.AMAX, self.w + self.AMAX
            self.a = rate
            self.w = min(w, goal)
            self.stage = UP if self.w < goal else CRUISE
            if self.w == goal:
                self.a = 0
            return
        if vb and self.w <= vb:
            rate, w = self.DFINAL, self.w - self.DFINAL
        else:  # DMAX down to VBREAK, landing on it
            rate, w = self.DMAX, self.w - self.DMAX
            if vb:
                w = max(w, vb)
        self.a = -rate
        if variant == TO_SPEED:
            self.w = max(w, goal)
            if self.w == goal:
                self.a = 0
                self.stage = CRUISE
        elif variant == TO_ZERO:
            self.w = w
            if self.w <= self.VSTOP:
                self.w = 0
                self.a = 0
                self.stage = IDLE
        else:
            floor = min(self.w, self.VSTOP)
            self.w = max(w, floor)
            if self.w == floor:
                self.a = 0
                self.stage = CRAWL if floor else IDLE

    def _s_tick(self, slope: int, goal: int, variant: int, reversal: bool = False,
                hold: bool = False) -> None:
        Q = self.quantum
        H = Q // 2  # the quantum falls half-way through each block of Q ticks
        if self.slope != slope:
            self._switch_slope(slope)
        continuous = (variant == TO_ZERO and reversal and self.regs.bow2 == self.regs.bow4)
        vstop_end = variant in (TO_ZERO, TO_TARGET) and self.VSTOP > 0 and not continuous
        has_down = not (continuous or vstop_end)
        if slope == RISE:
            j_rec, j_up, j_down, g_max, g_end = self.J4, self.J1, self.J2, self.AMAX, 0
        else:
            j_rec, j_up, j_down, g_max = self.J2, self.J3, self.J4, self.DMAX
            g_end = self.DFINAL if variant == TO_ZERO else 0
        rem = abs(goal - self.w)
        g = slope * self.a
        stage = self.stage
        ended = False
        if stage == CRAWL:
            stage = UP
            self.q = 0
        if stage == REC:
            if self.q % Q == H:
                g = min(g + j_rec, 0)
            next_stage = UP if g == 0 else REC
        elif stage in (UP, HOLD):
            due = stage == UP and self.q % Q == H and g < g_max
            g_up = min(g + j_up, g_max) if due else g
            if hold:
                next_stage = HOLD
            elif not has_down or self._ok(rem, g_up, j_down, g_end):
                g = g_up
                next_stage = HOLD if g == g_max or stage == HOLD else UP
            elif due and g > 0 and self._ok(rem, g, j_down, g_end):
                next_stage = HOLD  # skip the quantum: the peak acceleration stays here
            elif due and g == 0:
                g = g_up  # nothing to hold at 0: take the quantum, DOWN follows next tick
                next_stage = HOLD if g == g_max else UP
            else:
                stage = DOWN
                self.q = 0
                self.goal = goal
        if stage == DOWN:
            if self.q % Q == H:
                low = min(g_end, g)
                g -= j_down
                if g <= low:
                    g = low
                    ended = True
            next_stage = DOWN
        elif stage == END:
            next_stage = END
        elif stage in (CRUISE, IDLE):
            raise AssertionError("slope stage not set")
        # velocity update and clamps
        w = self.w + slope * g
        self.a = slope * g
        if slope == RISE:
            if w >= goal:
                w, next_stage, ended = goal, CRUISE, False
            elif w <= 0 and g < 0:  # still taking back a deceleration: standstill
                w, next_stage, ended = 0, IDLE, False
        elif variant == TO_SPEED:
            if w <= goal:
                w, next_stage, ended = goal, CRUISE, False
        elif continuous:
            if w < 0:  # through 0: on to XTARGET with a new approach (datasheet §6.6)
                self.s = -self.s
                self.braking = False
                w = -w
                self.a = min(g, self.AMAX)
                self.slope = RISE
                self.stage = HOLD if self.a >= self.AMAX else UP
                self.q = 0
                self.w = w
                return
        elif vstop_end:
            if w <= self.VSTOP:
                if variant == TO_ZERO:
                    w, next_stage = 0, IDLE
                else:
                    w, next_stage = min(self.w, self.VSTOP), CRAWL
                ended = False
        elif w <= 0:
            w, next_stage, ended = 0, IDLE, False
        if ended:
            if g == 0:
                if self.goal == goal:
                    w = goal
                next_stage = CRUISE if w else IDLE
            else:
                next_stage = END
        if next_stage in (CRUISE, IDLE, CRAWL):
            self.a = 0
            self.slope = 0 if next_stage != CRAWL else self.slope
        self.w = w
        self.q = self.q + 1 if next_stage == stage else 0
        self.stage = next_stage

    def _ok(self, rem: int, g: int, j_down: int, g_end: int) -> bool:
        """True if applying gain ``g`` now still lets a DOWN stage from the next tick stay short."""
        return rem - g >= self._reach_down(g, j_down, g_end)

    def _reach_down(self, g: int, j_down: int, g_end: int) -> int:
        """Velocity change of a DOWN stage starting at the next tick with gain ``g``."""
        key = (g, j_down, g_end)
        cached = self._reaches.get(key)
        if cached is not None:
            return cached
        low = min(g_end, g)
        total = (self.quantum // 2) * g  # ticks before the first quantum
        while True:  # one bow quantum per round, then ``quantum`` ticks at that gain
            g -= j_down
            if g <= low:
                total += low
                break
            if j_down == 0:
                total = NEVER
                break
            total += self.quantum * g
        self._reaches[key] = total
        return total

    def _switch_slope(self, slope: int) -> None:
        """Map the stage onto the other slope (shared bow phases keep their quantum grid)."""
        g_old = self.slope * self.a if self.slope else 0
        if self.slope and self.stage in (DOWN, REC) and g_old != 0:
            # RISE DOWN (a falling with BOW2) is FALL REC, FALL DOWN (BOW4) is RISE REC
            same = (self.stage == DOWN)
            self.stage = REC if same else self.stage
            if not same:  # REC of one slope is the other's DOWN only for the shared bow
                self.stage = UP
                self.q = 0
        elif self.a * slope < 0:
            self.stage = REC
            self.q = 0
        else:
            self.stage = UP
            self.q = 0
        self.slope = slope
