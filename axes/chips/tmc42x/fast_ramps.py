"""The fast engine's batches of TMC42x ramp ticks: many ticks of the law in one step.

Where the velocity changes, the law (:meth:`axes.chips.tmc42x.law.MotorLaw.ramp_tick` every
``2**RAMP_DIV`` clk32 ticks, :meth:`~axes.chips.tmc42x.law.MotorLaw.pulse_tick` every
``2**PULSE_DIV``) has no closed form for braking along the square-root curve, but long
stretches of it are regular.  Each batch here stands for whole ramp periods of the law and
must equal them: the same velocity, accumulator, position, V_TARGET and A_ACTUAL after its
last tick as the law's ticks give, never stepping onto a position where a step matters (the
caller's ``room``), so no ``Stop`` of the law falls inside a batch except at its end.

* :meth:`RampBatches._linear_batch`: full-A_MAX slew (accelerating, velocity-mode ramps, a
  move slowing while it heads away from its target), its steps as floor sums, with a binary
  search for the tick at which the braking curve takes over;
* :meth:`RampBatches._descend`: braking along the curve, one comparison-loop turn per ramp
  tick and whole bands of the curve at once (docs/motion.md, "How it is fast");
* :meth:`RampBatches._same_target_ticks`: ticks over which the clamped curve stays flat;
* :meth:`RampBatches._fast_brake`: slowing by A_MAX until nearly stopped (a reversal, a move
  too fast to stop at its target, a soft stop at a switch);
* :meth:`RampBatches._fast`: one ramp tick per loop turn with its pulses counted in bulk,
  trying the batches above on the way;
* :meth:`RampBatches.readings`: X_ACTUAL and V_ACTUAL at given ticks without running the
  motor, across a standing velocity or a full-A_MAX slew (a recorder's samples of a ramp).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from functools import lru_cache
from math import isqrt

from axes.chips.tmc42x.fast_steady import FAR, MotorSteady
from axes.chips.tmc42x.law import slew
from axes.chips.tmc42x.registers import (
    DISTANCE_LIMIT,
    HALF24,
    MASK24,
    MODE_HOLD,
    MODE_RAMP,
    MODE_SOFT,
    MODE_VELOCITY,
    SOFT_STOP,
    V_RANGE,
    sdiff24,
)
from axes.core import Stop
from axes.search import first_true

#: Braking runs remembered (_descend): a program's repeated moves brake from the same states.
DESCENT_CACHE_SIZE = 4096
_DESCENTS: dict[tuple[int, ...], tuple[int, int, int, int, int]] = {}
#: Braking runs cut short by their tick limit, remembered apart (a look-ahead's budget and a
#: program's reads cut a repeated move's brake the same way each time; a real clock's cuts
#: never repeat, and must not push the whole runs out): at least this many ticks, at most
#: CUT_DESCENT_CACHE_SIZE of them.
CUT_DESCENT_MIN_TICKS = 64
CUT_DESCENT_CACHE_SIZE = 1024
_CUT_DESCENTS: dict[tuple[int, ...], tuple[int, int, int, int, int]] = {}
#: Ramp ticks of _descend that count as one unit of work (a loop turn of the general path).
DESCENT_TICKS_PER_WORK = 4
#: A batch of ramp ticks: (ticks, speed, accumulator, steps, A_ACTUAL along the travel, ramp
#: target magnitude of the last tick, extra units of work).
Batch = tuple[int, int, int, int, int, int, int]


@lru_cache(maxsize=64)
def band_floors(soft: bool, pmul: int, pdiv: int) -> tuple[int, ...]:
    """The ramp generator's curve as thresholds: for each speed c (0..2047), the largest
    ``D = 2048 * distance - accumulator`` at which the curve is still below c.  The curve at
    distance ``ceil(D / 2048)`` is at least c exactly when ``D > floors[c]`` (a distance
    beyond the 2**19 limit counts as the limit; a speed the curve never reaches has a floor
    above any distance)."""
    floors = []
    never = 1 << 62
    k_mul = pmul << 8
    for c in range(V_RANGE):
        low = max(1, -(-(c << (3 + pdiv)) // pmul) if soft else -(-(c * c << pdiv) // k_mul))
        floors.append((low - 1) << 11 if low <= DISTANCE_LIMIT else never)
    return tuple(floors)


class RampBatches(MotorSteady):
    """The closed forms of :class:`MotorSteady`, plus batches of ramp ticks."""

    # == one ramp tick per loop turn ===========================================================

    def _fast(self, until: int, work: int | None = None) -> Stop | None:
        """Ramp ticks one per iteration with their pulses counted in bulk (no switches active).

        Entered with ``self.t == ramp_next - 1``.  Leaves as soon as a tick would bring the
        motor to a position of interest, the velocity becomes steady or changes sign, or the
        next whole ramp period would pass ``until``; the general path then takes over.
        Equal to the law's ticks up to the ``t`` it leaves at (``ramp_next - 1``, or the tick
        that stopped the motor: ``Stop.STOPPED``).  Where the ticks head (the direction, the
        distance to the target or the velocity-mode target) is worked out here, in line: this
        runs at every ramp of a move.
        """
        nr = self.ramp_next
        v = self.v
        vt_fixed = d = 0
        if self.mode == MODE_VELOCITY:
            vt_fixed = max(-self.v_max, min(self.v_max, self.v_target))
            direction = (v > 0) - (v < 0) or (vt_fixed > 0) - (vt_fixed < 0)
            if not direction:
                return self._slow_tick(nr)
        else:
            dx = ((self.x_target - self.x_actual + HALF24) & MASK24) - HALF24  # sdiff24
            if dx == 0:
                # at the target still moving (too fast to stop there): braking towards 0
                return self._fast_brake(until, 0) if v else self._slow_tick(nr)
            direction = 1 if dx > 0 else -1
            d = dx * direction
            if v * direction < 0:
                return self._fast_brake(until, d)
        room, _ = self._stop_distance(direction)
        window = self._window_steps(direction)
        if window is None:
            return self._fast_ticks(until, work, direction, d, room, vt_fixed)
        if window:  # a switch ahead: go no further than its tolerance window
            return self._fast_ticks(until, work, direction, d, min(room, window), vt_fixed)
        if v * direction > 0 and self.ref_conf & SOFT_STOP:
            # a soft stop at the switch: every tick slows the motor by A_MAX
            return self._fast_brake(until, None)
        return self._slow_tick(nr)

    def _fast_ticks(self, until: int, work: int | None, direction: int, d0: int, room: int,
                    vt_fixed: int) -> Stop | None:
        """_fast from its aim: a full-slew batch, then a loop turn per ramp tick (trying the
        braking and flat-curve batches on the way), then the state the ticks reached.

        One function for the whole loop: a loop turn is one ramp tick of an ordinary ramp (the
        curve's square root and a few comparisons), and a call per turn for its parts would
        cost a good part of a turn."""
        period = 1 << self.ramp_div
        last = until - period + 1
        fixed = vt_fixed * direction
        plan = self._pulse_plan(self.ramp_next)
        per_ramp, every = plan[0], plan[1]  # (the same from any ramp tick on: only the phase moves)
        applied, w, acc, walked, a_step, vt_reg, nr = self._fast_start(last, direction, d0, room,
                                                                      fixed, plan)
        pulse_mask = (1 << self.pulse_div) - 1
        a_max = self.a_max
        v_max = self.v_max
        v_min = self.v_min
        positioning = self.mode != MODE_VELOCITY
        is_ramp = self.mode == MODE_RAMP
        k_mul = self.pmul << 8
        pdiv = self.pdiv
        soft_shift = 3 + pdiv
        pmul = self.pmul
        turns = FAR if work is None else work
        iterations = 0
        prev_mag = -1  # the ramp target's magnitude at the previous tick
        flat = 0  # for how many ticks in a row it has not changed
        while nr <= last:
            iterations += 1
            if iterations > turns:
                break  # out of budget: what was applied stands, the caller looks again
            if positioning:
                d = d0 - walked
                dd = d if d < DISTANCE_LIMIT else DISTANCE_LIMIT
                mag = isqrt((k_mul * dd) >> pdiv) if is_ramp else (pmul * dd) >> soft_shift
                if mag < v_min:
                    mag = v_min
                if mag > v_max:
                    mag = v_max
                target = mag << 8
                if w == target and (mag in (v_max, v_min) or d >= DISTANCE_LIMIT):
                    break  # steady: the closed-form path takes over
                # Braking along the curve: one cheap turn per ramp tick, whole bands in one
                # step (_descend); a speed far above the curve goes on below.  While the
                # clamped curve stays flat the target does: those ticks go in one batch (slow
                # ramps, slow pulses or a long way at the distance limit), tried on entry and
                # once the target has not changed for two ticks (a curve that changes every
                # tick or two, an ordinary ramp, skips the search).
                flat = flat + 1 if mag == prev_mag else 0
                prev_mag = mag
                sub = None
                if target < w < target + (a_max << 4):
                    cap = (last - nr) // period + 1  # (its ticks and work as the loop's)
                    if work is not None:
                        cap = min(cap, (work - iterations + 1) * DESCENT_TICKS_PER_WORK)
                    sub = self._descend(w, d, acc, room - walked, cap, self._pulse_plan(nr))
                if sub is None and (flat >= 2 or iterations == 1):
                    sub = self._same_target_ticks(w, mag, d, room - walked, acc, nr,
                                                  (last - nr) // period + 1)
                if sub is not None:
                    k, w, acc, steps, a_step, mag, extra = sub
                    iterations += extra
                    prev_mag = -1
                    walked += steps
                    applied += k
                    nr += k * period
                    vt_reg = mag * direction
                    if w == 0:
                        break
                    continue
            else:
                target = fixed << 8
                if target < 0:
                    if w < a_max:
                        break  # this tick crosses zero: the general path does it
                    target = 0  # reversing: down towards zero here
                if w == target:
                    break  # steady: the closed-form path takes over
            if w < target:  # (slew in line: one turn per ramp tick)
                nw = w + a_max
                if nw > target:
                    nw = target
            else:
                nw = w - a_max
                if nw < target:
                    nw = target
            # every == 1: per_ramp pulses per ramp period; else a pulse on some ramp ticks
            total = acc + (nw >> 8) * (per_ramp if every == 1 else nr & pulse_mask == 0)
            steps = total >> 11
            if steps >= room - walked:
                break
            a_step = nw - w
            w = nw
            acc = total & 2047
            walked += steps
            applied += 1
            nr += period
            if positioning:
                vt_reg = mag * direction
            if w == 0:
                break
        self._work = max(1, iterations)
        return self._fast_end(applied, w, direction, acc, a_step, walked, nr, vt_reg)

    def _fast_start(self, last: int, direction: int, d: int, room: int, fixed: int,
                    plan: tuple[int, int, int]) -> tuple[int, int, int, int, int, int, int]:
        """_fast's opening full-A_MAX slew (_linear_batch), if one fits: (ticks, speed along
        ``direction``, accumulator, steps, A_ACTUAL along it, V_TARGET, next ramp tick)."""
        nr = self.ramp_next
        period = 1 << self.ramp_div
        positioning = self.mode != MODE_VELOCITY
        w = self.v * direction
        batch = self._linear_batch(w, self.acc, d, room, (last - nr) // period + 1, plan,
                                   positioning, fixed)
        if batch is None:
            return 0, w, self.acc, 0, 0, self.v_target, nr
        ticks, w, acc, steps, mag = batch
        a_max = self.a_max
        if positioning:
            return ticks, w, acc, steps, a_max, mag * direction, nr + ticks * period
        return (ticks, w, acc, steps, a_max if fixed << 8 > w else -a_max, self.v_target,
                nr + ticks * period)

    def _fast_end(self, applied: int, w: int, direction: int, acc: int, a_step: int,
                  walked: int, nr: int, vt_reg: int) -> Stop | None:
        """Where _fast's ticks leave the motor: their state if any were applied; else, at a
        steady velocity, nothing (the closed forms take over), or one plain tick."""
        if applied:
            self.v_target = vt_reg
            return self._commit_ticks(w, direction, acc, a_step, walked, nr)
        if self._steady_steps() is not None:
            return None
        return self._slow_tick(nr)

    def _commit_ticks(self, w: int, direction: int, acc: int, a_step: int, steps: int,
                      ramp_next: int) -> Stop | None:
        """Take the state a batch of ramp ticks reached: speed ``w`` and A_ACTUAL ``a_step``
        along ``direction``, the accumulator, ``steps`` made, ``ramp_next`` the tick after the
        last one.  STOPPED (at the last tick) if it brought the motor to rest."""
        self.v = w * direction
        self.acc = acc
        a = a_step * direction
        self.a_actual = 2047 if a > 2047 else -2048 if a < -2048 else a
        self._apply_steps(steps, direction)
        self.ramp_next = ramp_next
        if w == 0 and self._ramp_target()[0] == 0:
            self.t = ramp_next - (1 << self.ramp_div)
            return Stop.STOPPED
        self.t = ramp_next - 1
        return None

    # == braking along the curve ===============================================================

    def _descend(self, w: int, d: int, acc: int, room: int, max_ticks: int,
                 plan: tuple[int, int, int]) -> Batch | None:
        """Positioning ramp ticks from ``ramp_next`` on while the speed ``w`` (along the travel,
        1/256 units) is at or above the ramp target: braking along the curve.

        The state is one number, ``D = 2048 * distance - accumulator`` (the distance still to
        go in 1/2048 steps): a pulse at speed V takes V from it, and the curve's value is at
        least c exactly while ``D > band_floors(...)[c]``, so a ramp tick costs comparisons
        and a subtraction instead of a square root.  While the speed sits on the curve, the
        rest of its band (the distances with the same curve value) goes in one step.  Stops
        before a tick whose pulses would reach ``room`` steps, after ``max_ticks`` ticks, when
        the speed is steady (on V_MIN or V_MAX), or when it is far above the curve (the
        caller's batches do that better).  Returns them as a :data:`Batch` (its work: one unit
        per DESCENT_TICKS_PER_WORK ticks), or None if no tick was taken.  One loop turn per
        ramp tick of a brake: kept in one piece for speed, and called from _fast_ticks'
        loop directly (through a helper, a move cost 1.4 % more instructions).
        """
        a = self.a_max
        lo = min(self.v_min, self.v_max)  # the clamped curve's floor (all of it if V_MIN >= V_MAX)
        hi = self.v_max
        D = (d << 11) - acc
        d_floor = (d - room) << 11  # every pulse must leave D above this (steps < room)
        per_ramp, every, ph = plan
        # the same start (relative to the target and to ``room``) brakes the same way (the
        # plan spelt out: a starred tuple measured 0.5 % of a move's instructions)
        key = (self.mode == MODE_SOFT, self.pmul, self.pdiv, a, lo, hi, per_ramp, every, ph, w, D,
               d_floor)
        known = _DESCENTS.get(key)
        if known is None or known[0] > max_ticks:  # (not ended within max_ticks)
            known = _CUT_DESCENTS.get((*key, max_ticks))  # the same start cut the same way
        if known is not None and known[0] <= max_ticks:
            n, w_before, w, D, mag = known
            d_now = -((-D) >> 11)
            return (n, w, (d_now << 11) - D, d - d_now, w - w_before, mag,
                    n // DESCENT_TICKS_PER_WORK)
        floors = band_floors(self.mode == MODE_SOFT, self.pmul, self.pdiv)
        c = self._curve(d)
        c = lo if c < lo else hi if c > hi else c
        t = c << 8
        far = a << 4
        n = 0
        w_before = w
        mag = c  # the ramp target of the last tick taken
        ended = False  # by itself or before ``room``: not for want of ticks
        while n < max_ticks:
            if floors[c] >= D and c > lo:  # the curve drops to a lower band
                c -= 1
                while c > lo and floors[c] >= D:
                    c -= 1
                t = c << 8
            nw = w - a
            if nw < t:
                nw = t
            if ph:
                ph -= 1
            else:
                nD = D - per_ramp * (nw >> 8)
                if nD <= d_floor:
                    ended = True
                    break
                D = nD
                ph = every - 1
            w_before = w
            w = nw
            mag = c
            n += 1
            if w == t:
                if c in (lo, hi):
                    ended = True
                    break  # steady: the closed-form path takes over
                if every > 1 or D - floors[c] > per_ramp * c << 1:
                    k, D, ph = self._band_rest(c, floors[c], D, d_floor, ph, plan,
                                               max_ticks - n)
                    if k:
                        n += k
                        w_before = w
            elif w - t >= far:
                ended = True
                break  # far above the curve: a linear slew, the caller's batches
        if n == 0:
            return None
        # ended by itself or before ``room``, not for want of ticks: the same from the same
        # start; cut by ``max_ticks``: the same from the same start and cut
        if ended:
            if len(_DESCENTS) >= DESCENT_CACHE_SIZE:
                _DESCENTS.clear()
            _DESCENTS[key] = (n, w_before, w, D, mag)
        elif n >= CUT_DESCENT_MIN_TICKS:
            if len(_CUT_DESCENTS) >= CUT_DESCENT_CACHE_SIZE:
                _CUT_DESCENTS.clear()
            _CUT_DESCENTS[(*key, max_ticks)] = (n, w_before, w, D, mag)
        d_now = -((-D) >> 11)
        return n, w, (d_now << 11) - D, d - d_now, w - w_before, mag, n // DESCENT_TICKS_PER_WORK

    @staticmethod
    def _band_rest(c: int, floor: int, D: int, d_floor: int, ph: int,
                   plan: tuple[int, int, int], max_ticks: int) -> tuple[int, int, int]:
        """The speed on the curve at ``c`` for the rest of its band (D down to ``floor``): q more
        pulses at speed c (fewer if ``d_floor`` comes first), each ``every`` ramp ticks apart
        from ``ph`` on, at most ``max_ticks`` ticks.  Returns (ticks, D, ph) after them."""
        per_ramp, every, _ = plan
        step = per_ramp * c
        q = (D - floor - 1) // step + 1
        q_room = (D - d_floor - 1) // step
        k = ph + (q - 1) * every + 1 if q <= q_room else ph + q_room * every
        if k > max_ticks:
            k = max_ticks
        if k <= 0:
            return 0, D, ph
        pulses = 0 if k <= ph else (k - 1 - ph) // every + 1
        return k, D - pulses * step, (ph - k) % every

    # == a flat stretch of the curve ===========================================================

    def _same_target_ticks(self, w: int, mag: int, d: int, room: int, acc: int, nr: int,
                           max_ticks: int) -> Batch | None:
        """Positioning: ramp ticks from ``nr`` on whose ramp target stays ``mag`` (the clamped
        curve is flat over the distances the motor covers meanwhile) and that stop short of
        ``room``: in one batch, the speed slews by A_MAX towards the target or holds it.
        Returns them as a :data:`Batch`, or None if fewer than 2 ticks qualify.  ``w`` is the
        speed along the travel (1/256), ``d`` the distance."""
        a_max = self.a_max
        target = mag << 8
        limit = max_ticks if w == target else min(max_ticks, abs(target - w) // a_max)
        if limit < 2:
            return None  # (most calls: a speed that tracks the curve is within 2 A_MAX of it)
        # the lowest distance with the same target (the clamp at V_MIN holds it to the end)
        low = (1 if self.v_min >= self.v_max or mag == self.v_min
               else self._distance_for(mag) or d)
        allowed = d - low  # steps that keep the curve at mag
        plan = self._pulse_plan(nr)
        after = self._hold_steps(w, acc, plan) if w == target else None

        def steps_after(k: int) -> tuple[int, int]:
            if after is not None:
                return after(k)
            return self._slew_steps(k, w, acc, w < target, plan)

        def fits(k: int) -> bool:
            return steps_after(k - 1)[0] <= allowed and steps_after(k)[0] < room

        if not fits(2):
            return None
        k = first_true(lambda k: not fits(k), limit) - 1  # fits(1) and fits(2) hold
        steps, new_acc = steps_after(k)
        a_step = a_max if w < target else -a_max if w > target else 0  # the last tick's
        return k, slew(w, target, k * a_max), new_acc, steps, a_step, mag, 0

    @staticmethod
    def _hold_steps(w: int, acc: int, plan: tuple[int, int, int]
                    ) -> Callable[[int], tuple[int, int]]:
        """(steps, accumulator) after k ramp ticks at the constant speed ``w``."""
        per_ramp, every, phase = plan
        vi = w >> 8

        def after(k: int) -> tuple[int, int]:
            pulses = 0 if k <= phase else (k - 1 - phase) // every + 1
            total = acc + pulses * per_ramp * vi
            return total >> 11, total & 2047

        return after

    # == slowing by A_MAX ======================================================================

    def _fast_brake(self, until: int, d: int | None) -> Stop | None:
        """Ramp ticks that each slow the motor by A_MAX until it is nearly stopped, in one batch:
        positioning while moving away from the target (a move reversed in flight, or one too
        fast to stop at it; ``d`` is the distance to the target), or a soft stop at an active
        stop switch ahead, outside its tolerance window (``d`` None): the ramp target is then
        0 or points the other way.  Entered with ``t == ramp_next - 1``."""
        nr = self.ramp_next
        period = 1 << self.ramp_div
        travel = 1 if self.v > 0 else -1
        room = self._brake_room(travel, d)
        last = until - period + 1
        plan = self._pulse_plan(nr)
        max_ticks = (last - nr) // period + 1
        if d == 0:
            # at the target a pulse at V_MIN or below ends the move: stay above it
            max_ticks = min(max_ticks, (abs(self.v) - (self.v_min + 1 << 8)) // self.a_max
                            if self.a_max else 0)
        batch = None
        if room > 0 and nr <= last and max_ticks > 0:
            batch = self._linear_batch(abs(self.v), self.acc, 0, room, max_ticks, plan, False, 0)
        if batch is None:
            return self._slow_tick(nr)
        ticks, w, acc, steps, _ = batch
        if self.mode < MODE_VELOCITY:
            self.v_target = self._brake_target(d, ticks, plan, travel)
        return self._commit_ticks(w, travel, acc, -self.a_max, steps, nr + ticks * period)

    def _brake_room(self, travel: int, d: int | None) -> int:
        """Steps _fast_brake may make (0: none, it takes a plain tick): to the nearest
        position of interest, the edge of a switch's tolerance window where that matters,
        and, positioning, while the target stays behind."""
        room, _ = self._stop_distance(travel)
        soft = self.ref_conf & SOFT_STOP
        window = self._window_steps(travel)
        if window == 0:  # the switch ahead blocks: only a soft stop keeps braking
            if not soft:
                return 0
            entry = self._window_entry(travel)  # inside the window the switch lets go
            if entry is not None:
                room = min(room, entry)
        elif window is not None and not soft:
            room = min(room, window)  # past the window a hard stop ends the motion
        if d is not None:
            # the ramp ticks must see the target behind: a distance of at most 2**23 - 1
            # (or the 2**23 it is at; the first step then turns the target round)
            room = min(room, max(1, HALF24 - d))
        return room

    def _brake_target(self, d: int | None, ticks: int, plan: tuple[int, int, int],
                      travel: int) -> int:
        """V_TARGET as the last of ``ticks`` braking ticks wrote it: the curve where that tick
        found the motor (``d``: the distance to the target behind it; None: a soft stop)."""
        before, _ = self._slew_steps(ticks - 1, abs(self.v), self.acc, False, plan)
        if d is None:
            return self._target_at((self.x_actual + before * travel) & MASK24)
        if not d + before:
            return 0  # still at the target at the last tick
        mag = min(max(self._curve(d + before), self.v_min), self.v_max)
        return -mag * travel

    # == readings without running ==============================================================

    def readings(self, ticks: Iterable[int]) -> tuple[list[int], list[int]]:
        """X_ACTUAL and V_ACTUAL (the 12 bits a read returns) at each of ``ticks`` (ascending,
        none before ``t``) as :meth:`run` would leave them there, for a prefix of them that
        the motor reaches with nothing notable on the way: at a standing velocity
        (:meth:`steady_readings`) or across a full-A_MAX slew (:meth:`_slew_readings`).  The
        state does not change (the caller runs the engine for the rest)."""
        if self.powered_down:
            return [], []
        steady = self._steady_steps()
        if steady is None:
            slew = self._slew_readings(ticks)
            if slew is not None:
                return slew
        xs, v_bits = self.steady_readings(ticks, steady)
        return xs, [v_bits] * len(xs)

    def _slew_readings(self, ticks: Iterable[int]) -> tuple[list[int], list[int]] | None:
        """:meth:`readings` across ramp ticks that each move the speed by A_MAX towards its
        ramp target, then hold it where it lands if the target stands (V_MAX, or a
        velocity-mode target): None, before it takes a tick, if the motor is not on such a
        slew (the caller reads a standing velocity up to the next ramp tick).

        Exact by the law's own arithmetic: the ramp tick ``j`` after ``t`` (at
        ``ramp_next + (j - 1) * 2**RAMP_DIV``) sets the speed ``u_j = w + j * A_MAX`` (down:
        ``w - j * A_MAX``) as long as that does not pass the ramp target, else the target;
        the pulse ticks between it and the next add ``u_j >> 8`` each to the accumulator
        (:meth:`_slew_sum`: floor sums), and a step is a carry out of its 11 bits.  The ramp
        target stays where it is in velocity mode (no switch ahead in play: then nothing is
        read this way); positioning, it is the clamped curve where the motor is at the tick,
        which only falls as the motor nears the target while ``u_j`` only rises: the slew
        holds up to the first tick whose target is below ``u_j`` (a search over a monotone
        test, as :meth:`_linear_batch`'s).  No tick is given past a step onto a position
        that matters (:meth:`_stop_distance`: the target, REF_MISS at 0, the compare
        position, a board mark), and a falling speed stays above zero (where a velocity-mode
        ramp stops or turns, or a move brakes along the curve, the plain path reads)."""
        aim = self._slew_aim()
        if aim is None:
            return None
        direction, w, hold, last = aim
        a = self.a_max
        rd, pd = self.ramp_div, self.pulse_div
        t, nr = self.t, self.ramp_next
        room, _ = self._stop_distance(direction)
        period = 1 << rd
        rising = hold > w
        lands = -(-abs(hold - w) // a) if hold > 0 else FAR  # the tick that reaches ``hold``
        plan = self._pulse_plan(nr)
        head = self._standing_total(nr - 1, w)  # the pulses before ramp_next
        held = hold >> 8
        held_from = 0  # once held: the accumulator's total is held_from + pulses * held
        if lands < FAR:
            held_from = (head + self._slew_sum(lands - 1, w, rising, plan)
                         - ((nr + (lands - 1) * period - 1) >> pd) * held)

        def total_at(tick: int, k: int) -> int:
            """The accumulator's total at ``tick``, ``k`` ramp ticks after ``t``."""
            if k >= lands:  # (the pulses since the landing tick at the held speed)
                return held_from + (tick >> pd) * held
            if k:
                pulses = (tick >> pd) - ((nr + (k - 1) * period - 1) >> pd)
                u = w + k * a if rising else w - k * a
                return head + self._slew_sum(k - 1, w, rising, plan) + pulses * (u >> 8)
            return self._standing_total(tick, w)

        if self.mode != MODE_VELOCITY:
            d = sdiff24(self.x_target, self.x_actual) * direction
            v_min, v_max = self.v_min, self.v_max

            def fits(j: int) -> bool:
                """Ramp tick j finds the motor short of ``room`` and its ramp target (the
                clamped curve there) at or above the speed it sets."""
                before = total_at(nr + (j - 1) * period - 1, j - 1) >> 11
                if before >= room:
                    return False
                u = hold if j >= lands else w + j * a
                return min(max(self._curve(d - before), v_min), v_max) << 8 >= u

            last = first_true(lambda j: not fits(j), 1 << 40) - 1
        xs: list[int] = []
        vs: list[int] = []
        x, base = self.x_actual, t >> rd
        for tick in ticks:
            k = (tick >> rd) - base  # ramp ticks in (t, tick]
            if k > last:
                break
            steps = total_at(tick, k) >> 11
            if steps >= room:
                break
            xs.append((x + steps * direction) & MASK24)
            u = hold if k >= lands else w + k * a if rising else w - k * a
            vs.append(((u >> 8) * direction) & 0xFFF)
        return xs, vs

    def _standing_total(self, tick: int, w: int) -> int:
        """The accumulator's total at ``tick`` (no later than the next ramp tick's eve) with
        the speed ``w`` (1/256 units) standing: each pulse tick since ``t`` adds its integer
        part (as :meth:`steady_readings`' loop, written out there for speed)."""
        pd = self.pulse_div
        return self.acc + ((tick >> pd) - (self.t >> pd)) * (w >> 8)

    def _slew_aim(self) -> tuple[int, int, int, int] | None:
        """Where a slew from now heads, if the motor may be on one (:meth:`_slew_readings`):
        (direction of travel, speed along it, the ramp target along it (1/256 units) it
        lands on and holds, the last ramp tick it may take: FAR, or short of zero), or None.
        Positioning, the target is V_MAX (the curve may end the slew sooner, or at once:
        None)."""
        a = self.a_max
        mode = self.mode
        rd = self.ramp_div
        if a == 0 or mode == MODE_HOLD or self.ramp_next != (self.t >> rd) + 1 << rd:
            return None  # (or mid-tick bookkeeping of the engine: not a state of the law)
        v = self.v
        last = FAR
        if mode == MODE_VELOCITY:
            vt = max(-self.v_max, min(self.v_max, self.v_target))
            direction = (v > 0) - (v < 0) or (vt > 0) - (vt < 0)
            if not direction:
                return None
            w = v * direction
            hold = vt * direction << 8
            if hold == w:
                return None
            if hold <= 0:  # slowing to zero, to stop or turn there: up to a speed above it
                last = (w - 1) // a
        else:
            dx = sdiff24(self.x_target, self.x_actual)
            if not dx:
                return None
            direction = 1 if dx > 0 else -1
            w = v * direction
            hold = self.v_max << 8
            if not 0 <= w < hold:
                return None  # away from the target, or above V_MAX: braking
            # the first ramp tick's target below its speed: braking along the curve (most
            # often), turned away before anything else is worked out
            before = self._standing_total(self.ramp_next - 1, w) >> 11
            d = dx * direction
            if before >= d or min(max(self._curve(d - before), self.v_min),
                                  self.v_max) << 8 < min(w + a, hold):
                return None
        if last == 0 or self._switch_in_play(direction):
            return None
        return direction, w, hold, last

    # == full-A_MAX slew =======================================================================

    def _linear_batch(self, w: int, acc: int, d: int, room: int, max_ticks: int,
                      plan: tuple[int, int, int],
                      positioning: bool, fixed_target: int
                      ) -> tuple[int, int, int, int, int] | None:
        """Many ramp ticks of full-A_MAX slew at once (floor sums instead of a loop).

        ``w`` is the speed along the direction of travel (1/256 units).  In velocity mode the
        target is fixed; in ramp/soft mode it is the curve, and the batch ends before the tick
        at which the curve would limit the acceleration.  Returns (ticks, speed, accumulator,
        steps, last target magnitude: 0 in velocity mode) or None if fewer than 16 ticks
        qualify.
        """
        a_max = self.a_max
        if a_max == 0:
            return None
        if positioning:
            cap = self.v_max << 8
            if w + a_max > cap:
                return None
            ticks = min(max_ticks, (cap - w) // a_max)
            rising = True
        else:
            target = max(0, fixed_target << 8)  # a reversal decelerates to zero first
            rising = target > w
            ticks = min(max_ticks, abs(target - w) // a_max)
        if ticks < 16:
            return None

        def after(k: int) -> tuple[int, int]:
            """(steps, accumulator) after k full-slew ticks."""
            return self._slew_steps(k, w, acc, rising, plan)

        def curve_at(k: int) -> int:
            """The clamped curve at the start of tick k (the distance its pulses left)."""
            before, _ = after(k - 1)
            return min(max(self._curve(d - before), self.v_min), self.v_max)

        def fits(k: int) -> bool:
            steps, _ = after(k)
            if steps >= room:
                return False
            if not positioning:
                return True
            before, _ = after(k - 1)  # curve_at(k), in line: the search calls this often
            return min(max(self._curve(d - before), self.v_min), self.v_max) << 8 >= w + k * a_max

        ticks = first_true(lambda k: not fits(k), ticks) - 1
        if ticks < 16:
            return None
        steps, new_acc = after(ticks)
        speed = w + ticks * a_max if rising else w - ticks * a_max
        return ticks, speed, new_acc, steps, curve_at(ticks) if positioning else 0


__all__ = ["DESCENT_CACHE_SIZE", "DESCENT_TICKS_PER_WORK", "FAR", "RampBatches", "band_floors"]
