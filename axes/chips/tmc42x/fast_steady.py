"""The fast engine's closed forms for stretches where a TMC42x motor's velocity stands still.

Each method here stands for many ticks of :class:`axes.chips.tmc42x.law.MotorLaw` and must
equal them: after it, the state is the one the law's ticks reach at the same clk32 tick, and
it stops at the tick where the law's :meth:`~MotorLaw.tick` returns a ``Stop``.

* :meth:`MotorSteady._pulses`: the pulse ticks in ``(t, t_end]`` at the present velocity
  (:meth:`MotorLaw.pulse_tick` each): the steps are ``(acc + V * ticks) >> 11``, computed at
  once up to the nearest position where a step matters (the target, X_ACTUAL 0 with REF_MISS
  armed, the compare position, a board mark; :meth:`MotorSteady._stop_distance`);
* :meth:`MotorSteady._steady_steps`: for how many steps ramp ticks (:meth:`MotorLaw.ramp_tick`)
  cannot change the velocity (cruise, velocity mode at speed, V_MIN or V_MAX on a flat stretch
  of the curve, A_MAX = 0, the tolerance window of a switch ahead): the engine then runs
  ``_pulses`` over the whole stretch and writes what its last ramp tick would have written;
* :meth:`MotorSteady._slew_steps`: the steps of ``k`` ramp ticks of full-A_MAX slew (floor
  sums), the building block of :mod:`axes.chips.tmc42x.fast_ramps`;
* :meth:`MotorSteady.steady_readings`: X_ACTUAL at given ticks of a steady stretch without
  running it (a recorder's samples, :meth:`RampBatches.readings`).
"""

from __future__ import annotations

from collections.abc import Iterable

from axes.chips.tmc42x.law import MotorLaw
from axes.chips.tmc42x.registers import (
    DISTANCE_LIMIT,
    HALF24,
    IRQ_REF_MISS,
    MASK24,
    MODE_HOLD,
    MODE_RAMP,
    MODE_VELOCITY,
    Irq,
    sdiff24,
    signed,
)
from axes.core import Stop

#: "No limit" for a distance in steps (larger than any a run can cover).
FAR = 1 << 62


def floor_sum(n: int, m: int, a: int, b: int) -> int:
    """Sum of (a*i + b) // m for i in 0..n-1 (a, b >= 0), in O(log) steps."""
    total = 0
    while True:
        if a >= m:
            total += (n - 1) * n // 2 * (a // m)
            a %= m
        if b >= m:
            total += n * (b // m)
            b %= m
        y_max = a * n + b
        if y_max < m:
            return total
        n, b, m, a = y_max // m, y_max % m, a, m


def _nearer(steady: int | None, window: int | None) -> int | None:
    """A steady stretch (``_steady_steps``' answer) cut at the tolerance window's edge."""
    if window is None or steady is None:
        return steady
    return window if steady == -1 else min(steady, window)


class MotorSteady(MotorLaw):
    """The law's state and ticks, plus the closed forms for a velocity that stands still."""

    # == pulses ================================================================================

    def _stop_distance(self, direction: int) -> tuple[int, int]:
        """Steps to the nearest position where the pulse generator must look closer (FAR:
        none), and the distance to the next board mark (0: none)."""
        best = FAR
        x = self.x_actual
        if self.mode < MODE_VELOCITY:
            # sdiff24(x_target, x) in line: this runs at every position read of a moving axis
            d = (((self.x_target - x + HALF24) & MASK24) - HALF24) * direction
            if d > 0:
                best = d
        if self.int_mask >> IRQ_REF_MISS & 1:
            d = sdiff24(0, x) * direction
            if 0 < d < best:
                best = d
        if self.pos_comp_on:
            d = sdiff24(self.pos_comp, x) * direction
            if 0 < d < best:
                best = d
        mark_distance = 0
        board = self.board
        if board is not None and self.steps_out:
            mark = board.next_mark(self.motor_position, direction)
            if mark is not None:
                mark_distance = (mark - self.motor_position) * direction
                if 0 < mark_distance < best:
                    best = mark_distance
        return best, mark_distance

    def _pulses(self, t_end: int, max_steps: int = FAR) -> Stop | None:
        """The pulse ticks in (t, t_end] at the present velocity: :meth:`MotorLaw.pulse_tick`
        each, in closed form between the positions where a step matters.

        Returns early (with ``self.t`` at the pulse tick concerned) when the motor arrives at
        its target or reaches a board mark, as the law's tick would, or when it has made
        ``max_steps`` steps (then None, with ``self.t`` short of ``t_end``).
        """
        pulse_div = self.pulse_div
        first = (self.t >> pulse_div) + 1 << pulse_div  # the first pulse tick after t
        if first > t_end:
            self.t = t_end
            return None
        ticks = (t_end - first >> pulse_div) + 1
        used = 0
        positioning = self.mode < MODE_VELOCITY
        while True:  # (used < ticks here; this runs at every position read of a moving axis)
            v = self.v
            vi = (v if v > 0 else -v) >> 8
            if positioning and vi <= self.v_min and self.x_actual == self.x_target:
                if v:  # the law's abrupt stop at the target
                    self.v = 0
                    self.t = first + (used << pulse_div)
                    self._raise(Irq.POS_END)
                    return Stop.ARRIVED
                self.t = t_end
                return None
            if vi == 0:
                self.t = t_end
                return None
            direction = 1 if v > 0 else -1
            remaining = ticks - used
            acc = self.acc
            total = (acc + vi * remaining) >> 11
            limit, mark_distance = self._stop_distance(direction)
            if max_steps < limit:
                limit = max_steps
            if limit > total:
                self._apply_steps(total, direction)
                self.acc = acc + vi * remaining - (total << 11)
                self.t = t_end
                return None
            k = ((limit << 11) - acc + vi - 1) // vi  # pulse ticks until step number `limit`
            self._apply_steps(limit, direction)
            self.acc = acc + vi * k - (limit << 11)
            used += k
            self.t = first + (used - 1 << pulse_div)
            self._arrived_here()
            if limit == mark_distance and self.board is not None:
                self.set_pins(*self.board.pins(self.motor_position))
                return Stop.MARK
            max_steps -= limit
            if max_steps == 0:
                return None
            if used >= ticks:
                self.t = t_end
                return None

    def steady_readings(self, ticks: Iterable[int], steady: int | None
                        ) -> tuple[list[int], int]:
        """X_ACTUAL at each of ``ticks`` (ascending, none before ``t``) as :meth:`run` would
        leave it there, and V_ACTUAL (the 12 bits a read returns), for the first of them
        that the motor reaches at its present velocity without a notable step: a prefix,
        perhaps empty; the state does not change (the caller runs the engine for the rest).
        ``steady`` is :meth:`_steady_steps`' answer now; the chip is powered.

        Exact by :meth:`_pulses`' closed form: the pulse ticks in ``(t, T]`` are
        ``(T >> PULSE_DIV) - (t >> PULSE_DIV)`` and make ``(acc + |V| * pulses) >> 11``
        steps, as long as the velocity stands: before the next ramp tick, or while fewer
        steps than ``steady`` promises are made; and short of the nearest step that matters
        (:meth:`_stop_distance`: the target, REF_MISS at 0, the compare position, a board
        mark).  A motor at rest (whose readings its caller keeps anyway) gives nothing."""
        v = self.v
        vi = (v if v > 0 else -v) >> 8
        if vi == 0:
            return [], 0
        if self.mode < MODE_VELOCITY and vi <= self.v_min and self.x_actual == self.x_target:
            return [], 0  # the law's abrupt stop at the target comes at the next pulse tick
        last_tick = FAR
        if steady is None:
            last_tick = self.ramp_next - 1  # the next ramp tick may change the velocity
            bound = FAR
        else:
            bound = FAR if steady < 0 else steady
        direction = 1 if v > 0 else -1
        limit = self._stop_distance(direction)[0]
        if limit < bound:
            bound = limit
        pulse_div, t, acc, x = self.pulse_div, self.t, self.acc, self.x_actual
        before = t >> pulse_div
        positions = []
        for tick in ticks:
            steps = (acc + vi * ((tick >> pulse_div) - before)) >> 11
            if tick > last_tick or steps >= bound:
                break
            positions.append((x + steps * direction) & MASK24)
        return positions, self.v_actual & 0xFFF

    # == steady stretches ======================================================================

    def _steady_steps(self) -> int | None:
        """If ramp ticks cannot change the velocity for a while, how many steps that lasts.

        Returns None if not steady, -1 for "as long as nothing else changes", else the number of
        further steps after which the ramp generator must be consulted again.
        """
        vt, hard, _ = self._ramp_target()
        v = self.v
        if hard and v:
            return None
        if self.mode == MODE_HOLD or self.a_max == 0 or (v == 0 and vt == 0):
            # Ramp ticks cannot change the velocity: hold mode; no acceleration; or at rest
            # with a target speed of zero (V_MAX 0, a curve value of 0, a blocking switch),
            # which stays zero while the motor does not move.  Inside the tolerance window
            # of a switch ahead, leaving it may stop the motor; outside it a switch ahead
            # would stop the motor hard (handled above), or softly, which a_max = 0 cannot
            # do: the velocity stays.
            return (self._window_steps(1 if v > 0 else -1) or -1) if v else -1
        if v != vt << 8:
            return None
        if not v:
            return self._steady_positioning(v, vt)
        window = self._window_steps(1 if v > 0 else -1)
        if window == 0:
            return None  # outside the window with a switch ahead: not steady
        return _nearer(self._steady_positioning(v, vt), window)

    def _steady_positioning(self, v: int, vt: int) -> int | None:
        """_steady_steps for a velocity at its ramp target (see there)."""
        if self.mode == MODE_VELOCITY:
            return -1
        dx = sdiff24(self.x_target, self.x_actual)
        if dx == 0:
            return -1 if v == 0 else None
        if (dx > 0) != (v > 0):
            return None
        low = self._steady_low(abs(dx), abs(vt))
        if low is None:
            return None
        d = abs(dx)
        return d - low + 1 if d >= low else None

    def _steady_low(self, d: int, mag: int) -> int | None:
        """The lowest distance down to which the clamped curve stays at ``mag`` (the motor at
        ``d``, the speed on its target ``mag``), or None if it may change sooner."""
        if mag == self.v_max and self.v_min >= self.v_max:
            return 1  # V_MIN >= V_MAX: the clamped curve is V_MAX all the way to the target
        if mag == self.v_max:
            return self._distance_for(self.v_max)
        if mag == self.v_min:
            return 1  # the curve only falls as the distance shrinks: V_MIN holds to the target
        return DISTANCE_LIMIT if d >= DISTANCE_LIMIT else None

    def _distance_for(self, speed: int) -> int | None:
        """Smallest distance whose curve value reaches ``speed`` (None if none below the limit)."""
        if self.mode == MODE_RAMP:
            low = -(-(speed * speed << self.pdiv) // (self.pmul << 8))
        else:
            low = -(-(speed << (3 + self.pdiv)) // self.pmul)
        low = max(low, 1)
        return low if low <= DISTANCE_LIMIT else None

    def _window_steps(self, direction: int) -> int | None:
        """Steps until the motor leaves the switch tolerance window while a switch ahead is in
        play (None: no such limit); 0 when outside it already."""
        if not self._switch_in_play(direction):
            return None
        if not self.dx_ref_tolerance:
            return 0
        x = signed(self.x_actual, 24)
        if abs(x) >= self.dx_ref_tolerance:
            return 0
        return (self.dx_ref_tolerance - x) if direction > 0 else (x + self.dx_ref_tolerance)

    def _window_entry(self, travel: int) -> int | None:
        """Steps (moving in ``travel``) until the motor enters the switch tolerance window from
        outside it (None: a window of 0 is never entered)."""
        tol = self.dx_ref_tolerance
        if not tol:
            return None
        x = signed(self.x_actual, 24)
        edge = 1 - tol if travel > 0 else tol - 1
        return ((edge - x) * travel) & MASK24

    def _steady_stretch(self, until: int, steady: int) -> Stop | None:
        """The pulses of a stretch ``_steady_steps`` found steady (``steady`` steps, -1: to
        ``until``), and what its ramp ticks wrote: A_ACTUAL 0, and V_TARGET the curve's value
        at the last of them (it moves on with the motor when A_MAX is 0)."""
        moving = self.v != 0
        vt_steady = self._ramp_target()[2]  # what each ramp tick writes, constant while steady
        velocity = self.v
        stop = self._pulses(until) if steady < 0 else self._pulses(until, steady)
        ramp = 1 << self.ramp_div
        if self.ramp_next <= self.t:
            self.a_actual = 0
            if self.mode < MODE_VELOCITY:
                self.v_target = (self._skipped_target(velocity, stop is Stop.ARRIVED)
                                 if self.a_max == 0 else vt_steady)
        self.ramp_next = (self.t // ramp + 1) * ramp
        if stop is None and moving and self.v == 0:
            return Stop.STOPPED
        return stop

    def _skipped_target(self, velocity: int, arrived: bool) -> int:
        """V_TARGET as the last ramp tick up to ``t`` wrote it, after pulses at a constant
        ``velocity`` (A_MAX 0): the curve where the motor was at that tick.  The accumulator
        says how many steps the pulses since then made (the pulse that ends a move at its
        target adds nothing)."""
        tick = self.t >> self.ramp_div << self.ramp_div
        pulses = (self.t >> self.pulse_div) - ((tick - 1) >> self.pulse_div) - arrived
        speed = abs(velocity) >> 8
        since = -((self.acc - pulses * speed) >> 11)  # ceil((pulses * speed - acc) / 2048)
        back = since if velocity > 0 else -since
        return self._target_at((self.x_actual - back) & MASK24)

    # == single ramp ticks and the pulse grid ==================================================

    def _slow_tick(self, nr: int) -> Stop | None:
        """The ramp tick at ``nr`` by the law (:meth:`MotorLaw.ramp_tick`); its pulses follow in
        the caller's next round (``t`` stays at ``nr - 1`` unless it stops the motor)."""
        moving = self.v != 0
        self.ramp_tick()
        self.ramp_next = nr + (1 << self.ramp_div)
        if moving and not self.v and self._ramp_target()[0] == 0:
            self.t = nr
            return Stop.STOPPED
        return None

    def _pulse_plan(self, nr: int) -> tuple[int, int, int]:
        """How pulse ticks fall on the ramp ticks from ``nr`` on: (pulses per ramp tick,
        ramp ticks per pulse, index of the first ramp tick with a pulse).  With
        PULSE_DIV <= RAMP_DIV every ramp period has 2**(RAMP_DIV-PULSE_DIV) pulses, all at the
        speed its ramp tick set; with PULSE_DIV > RAMP_DIV a pulse tick falls on every
        2**(PULSE_DIV-RAMP_DIV)-th ramp tick (after it, at the same clk32 tick)."""
        rd, pd = self.ramp_div, self.pulse_div
        if rd >= pd:
            return 1 << (rd - pd), 1, 0
        return 1, 1 << (pd - rd), ((-nr) & ((1 << pd) - 1)) >> rd

    def _slew_steps(self, k: int, w: int, acc: int, rising: bool,
                    plan: tuple[int, int, int]) -> tuple[int, int]:
        """(steps, accumulator) after ``k`` ramp ticks that each change the speed ``w`` by
        A_MAX (up if ``rising``), pulses as ``plan`` says (floor sums, not a loop)."""
        total = acc + self._slew_sum(k, w, rising, plan)
        return total >> 11, total & 2047

    def _slew_sum(self, k: int, w: int, rising: bool, plan: tuple[int, int, int]) -> int:
        """What the pulses of ``k`` ramp periods of full-A_MAX slew from the speed ``w`` add
        to the accumulator (each pulse the integer part of the speed its period's ramp tick
        set; the speeds stay >= 0): a floor sum over the pulses ``plan`` places."""
        per_ramp, every, phase = plan
        pulses = 0 if k <= phase else (k - 1 - phase) // every + 1
        if pulses == 0:
            return 0
        a = self.a_max
        if rising:
            return per_ramp * floor_sum(pulses, 256, every * a, w + (phase + 1) * a)
        return per_ramp * floor_sum(pulses, 256, every * a,
                                    w - (phase + 1 + (pulses - 1) * every) * a)
