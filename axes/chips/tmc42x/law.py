"""The motion law of one TMC42x motor, one clk32 tick at a time (TMC4210, TMC429).

This is ``shared/spec/tmc4210.md`` §4.8 (the digest's reference model) by the letter, on the
motor's own state: a clk32 counter drives a *ramp tick* every ``2**RAMP_DIV`` and a *pulse
tick* every ``2**PULSE_DIV`` clk32 periods (the ramp tick first when both fall on one);
the velocity has 8 hidden fraction bits, and an 11-bit phase accumulator turns its integer
part into steps.  With it, the stop switches (§6.1: levels, the tolerance window, hard and
soft stops, edges), the latch and the interrupt flags (§6.3, §7), the position compare and the
microstep counter.

:meth:`MotorLaw.tick` is one clk32 tick and :meth:`MotorLaw.step` ticks until a given tick or
the first notable instant.  They are the definition the fast engine
(:class:`axes.chips.tmc42x.engine.MotorEngine`, whose ``run`` jumps over whole stretches in
closed form) must equal: the same state after any number of ticks, the same ``Stop`` at the
same tick.  ``tests/axes/test_tmc42x_law.py`` holds the two equal on random states.  The
simulator itself never ticks (a tick per Python call would take minutes per simulated
second); the engine takes single ramp ticks with :meth:`MotorLaw.ramp_tick`, the same law.

The law lives here, in the product, because the engine uses its ramp tick and its switch
logic; ``tests/axes/reference_tmc4210.py`` stays an independent transcription of the digest
(written apart, without the switch edges, latch or interrupts), against which the tests
check the engine's positions, velocities and arrivals: two readings of the datasheet that
must agree.
"""

from __future__ import annotations

from math import isqrt

from axes.chips.tmc42x.registers import (
    DEFAULT_CLOCK_HZ,
    DISABLE_STOP_L,
    DISABLE_STOP_R,
    DISTANCE_LIMIT,
    HALF24,
    MASK24,
    MODE_HOLD,
    MODE_RAMP,
    MODE_VELOCITY,
    REF_RNL,
    SOFT_STOP,
    Irq,
    RampMode,
    signed,
)
from axes.core import Board, Stop


def slew(v: int, target: int, step: int) -> int:
    """``v`` moved towards ``target`` by at most ``step`` (a ramp tick's A_MAX)."""
    if v < target:
        return v + step if v + step < target else target
    if v > target:
        return v - step if v - step > target else target
    return v


class MotorLaw:
    """One motor's state (axis registers, pins, wiring) and the law that moves it.

    Wiring: the chip that owns the motor sets these plain attributes whenever its global
    registers change them (they are read on the engine's hot paths):

    * ``steps_out``: steps reach the motor (and ``motor_position``): the TMC4210 with
      ``en_sd = 1``; the TMC429 in Step/Dir mode, or in SPI mode for a motor in the chain.
    * ``inv_ref``: the chip inverts all switch inputs.
    * ``left_wired`` / ``right_wired``: the chip's switch layout gives this motor a left /
      right stop switch (an unwired switch is never active).
    * ``pos_comp_on``: the chip compares this motor's X_ACTUAL with ``pos_comp`` and sets
      ``pos_comp_flag`` on a match (position-compare mask set and this motor selected).
    * ``powered_down``: the chip's clocks stand still until the next SPI frame.
    """

    #: Steps that reached the motor, unwrapped (a plain attribute: the motion moves it).
    motor_position: int

    def __init__(self, clock_hz: int = DEFAULT_CLOCK_HZ, board: Board | None = None) -> None:
        if clock_hz <= 0:
            raise ValueError("clock frequency must be positive")
        self.clock_hz = clock_hz
        self.board = board
        self.t = 0  # clk32 ticks fully processed
        self.motor_position = 0  # steps that reached the motor, unwrapped
        self.steps_out = False
        self.inv_ref = False
        self.left_wired = True
        self.right_wired = False
        self.pos_comp_on = False
        self.pos_comp = 0
        self.pos_comp_flag = False
        self.powered_down = False
        self.reset_motor()

    def reset_motor(self) -> None:
        """The axis registers' power-on values (all 0) and an idle ramp generator."""
        self.x_target = 0
        self.x_actual = 0
        self.v_min = 0
        self.v_max = 0
        self.v_target = 0  # signed 12-bit register
        self.v = 0  # signed internal velocity in 1/256 velocity units
        self.a_max = 0
        self.a_actual = 0
        self.a_threshold = 0
        self.pmul = 128
        self.pdiv = 0
        self.ref_conf = 0  # bits 11..8 of the register, as stored (mode kept apart)
        self.mode = RampMode.RAMP
        self.latch_pending = False
        self.int_mask = 0
        self.int_flags = 0
        self.pulse_div = 0
        self.ramp_div = 0
        self.usrs = 0
        self.dx_ref_tolerance = 0
        self.x_latched = 0
        self.ustep_count = 0
        self.acc = 0
        #: The next ramp tick (the engine keeps it; the law's ticks fall on multiples of
        #: 2**RAMP_DIV, and it follows them).
        self.ramp_next = self.t + 1
        self.ref_l = self.ref_r = self.gp_in = False  # electrical pin levels
        self._refresh_pins()

    # == derived state =========================================================================

    @property
    def v_actual(self) -> int:
        """V_ACTUAL: the integer part of the velocity, truncated toward zero."""
        return (self.v >> 8) if self.v >= 0 else -((-self.v) >> 8)

    def _active(self, level: bool) -> bool:
        return level != self.inv_ref

    @property
    def left_active(self) -> bool:
        return self.left_wired and self._active(self.ref_l)

    @property
    def right_active(self) -> bool:
        return self.right_wired and self._active(self.ref_r)

    @property
    def at_target(self) -> bool:
        """xEQt: X_ACTUAL == X_TARGET."""
        return self.x_actual == self.x_target

    # == one clk32 tick ========================================================================

    def tick(self) -> Stop | None:
        """One clk32 tick: the ramp tick if one falls on it, then the pulse tick if one does.

        Returns the notable instant it is, if any: STOPPED when the ramp tick brought a
        moving motor to rest (a ramp target of 0), ARRIVED when the pulse tick ended a move at
        its target, MARK when its step reached a position the board named (the pins are
        driven first).  A powered-down chip's clocks stand still: nothing happens.
        """
        t = self.t = self.t + 1
        rd = self.ramp_div
        self.ramp_next = (t >> rd) + 1 << rd
        if self.powered_down:
            return None
        stop = None
        if not t & ((1 << rd) - 1):
            moving = self.v != 0
            self.ramp_tick()
            if moving and not self.v and self._ramp_target()[0] == 0:
                stop = Stop.STOPPED
        if not t & ((1 << self.pulse_div) - 1):
            return self.pulse_tick() or stop
        return stop

    def step(self, until: int) -> Stop | None:
        """Tick until clk32 tick ``until`` or the first notable instant (then ``t`` is its
        tick, as :meth:`tick` says which).  What ``MotorEngine.run(until)`` must equal.

        The clk32 ticks that are neither ramp nor pulse ticks do nothing by the law; they are
        passed over (a test would otherwise spend most of its time on them)."""
        while self.t < until:
            grain = 1 << min(self.ramp_div, self.pulse_div)
            following = (self.t // grain + 1) * grain  # the next tick that may do anything
            if following > until:
                self.t = until
                self.ramp_next = (until >> self.ramp_div) + 1 << self.ramp_div
                return None
            self.t = following - 1
            stop = self.tick()
            if stop is not None:
                return stop
        return None

    # == ramp generator ========================================================================

    def _curve(self, distance: int) -> int:
        """Target speed magnitude from the remaining distance (ramp: sqrt law, soft: linear)."""
        d = distance if distance < DISTANCE_LIMIT else DISTANCE_LIMIT
        if self.mode == MODE_RAMP:
            return isqrt((self.pmul * d << 8) >> self.pdiv)
        return (self.pmul * d) >> (3 + self.pdiv)

    def _target_at(self, x: int) -> int:
        """The positioning curve's target velocity (V_TARGET) with X_ACTUAL at ``x``: the curve
        floored by V_MIN and capped by V_MAX (V_MAX wins)."""
        dx = ((self.x_target - x + HALF24) & MASK24) - HALF24  # sdiff24, in line
        if dx == 0:
            return 0
        mag = self._curve(dx if dx > 0 else -dx)
        if mag < self.v_min:
            mag = self.v_min
        if mag > self.v_max:
            mag = self.v_max
        return mag if dx > 0 else -mag

    def _ramp_target(self) -> tuple[int, bool, int]:
        """(target velocity, hard switch stop, target velocity before the stop switches) that
        a ramp tick would use now.  In ramp and soft mode the last is what the tick writes to
        V_TARGET: the curve's value (the digest's model writes it before the switches act)."""
        mode = self.mode
        # (comparisons rather than min/max, and _target_at in line: this runs at every ramp
        # tick and every look at a moving motor; a call to _target_at measured 3-5 % of a
        # TMC4210 move in bench_tmc4361a)
        if mode < MODE_VELOCITY:
            dx = ((self.x_target - self.x_actual + HALF24) & MASK24) - HALF24  # sdiff24
            if dx == 0:
                vt = 0
            else:
                mag = self._curve(dx if dx > 0 else -dx)
                if mag < self.v_min:
                    mag = self.v_min
                if mag > self.v_max:
                    mag = self.v_max
                vt = mag if dx > 0 else -mag
        elif mode == MODE_VELOCITY:
            v_max = self.v_max
            vt = self.v_target
            if vt > v_max:
                vt = v_max
            elif vt < -v_max:
                vt = -v_max
        else:
            vt = 0
        v = self.v
        direction = (v > 0) - (v < 0) or (vt > 0) - (vt < 0)
        if direction and self._switch_in_play(direction) and self._outside_window():
            stopped = max(vt, 0) if direction < 0 else min(vt, 0)
            return stopped, mode == MODE_HOLD or not self.ref_conf & SOFT_STOP, vt
        return vt, False, vt

    def ramp_tick(self) -> None:
        """One ramp tick: the velocity steps towards the ramp target by up to A_MAX (a switch
        ahead may stop it at once, or make the target 0 towards it)."""
        vt, hard, curve = self._ramp_target()
        mode = self.mode
        if mode < MODE_VELOCITY:
            self.v_target = curve
        v_old = v = self.v
        if hard:
            if v:
                self._raise(Irq.STOP)
            v = 0
        if mode != MODE_HOLD:  # slew towards the target (in line: every plain ramp tick)
            target = vt << 8
            if v < target:
                v = v + self.a_max if v + self.a_max < target else target
            elif v > target:
                v = v - self.a_max if v - self.a_max > target else target
        self.v = v
        a = v - v_old  # (comparisons, not min/max: a call each measured 0.5 % of a move)
        self.a_actual = 2047 if a > 2047 else -2048 if a < -2048 else a

    def _switch_in_play(self, direction: int) -> bool:
        """True if the stop switch ahead (in ``direction``) is active and enabled: the ramp
        tick may then stop the motor (or will once it leaves the tolerance window).  A switch
        behind the motor, or one that is off or disabled, leaves the ramp alone: its pin only
        changes at a board mark, where the pulse generator stops anyway."""
        # left_active / right_active spelled out: this runs at every ramp tick
        if direction < 0:
            return (self.left_wired and self.ref_l != self.inv_ref
                    and not self.ref_conf & DISABLE_STOP_L)
        return (self.right_wired and self.ref_r != self.inv_ref
                and not self.ref_conf & DISABLE_STOP_R)

    def _outside_window(self) -> bool:
        """Outside the switch tolerance window: a stop switch in play stops the motor here."""
        return abs(signed(self.x_actual, 24)) >= self.dx_ref_tolerance

    # == pulse generator =======================================================================

    def pulse_tick(self) -> Stop | None:
        """One pulse tick: the abrupt stop at the target (positioning, |V| <= V_MIN), or the
        accumulator takes the speed's integer part and a carry out of its 11 bits is a step."""
        v = self.v
        vi = (v if v > 0 else -v) >> 8
        if self.mode < MODE_VELOCITY and vi <= self.v_min and self.x_actual == self.x_target:
            if not v:
                return None
            self.v = 0
            self._raise(Irq.POS_END)
            return Stop.ARRIVED
        acc = self.acc + vi
        self.acc = acc & 2047
        return self._step(1 if v > 0 else -1) if acc >= 2048 else None

    def _step(self, direction: int) -> Stop | None:
        """One step: the counters move, the checks of the new position; MARK if it is the next
        position the board named (its pins are driven first)."""
        board = self.board
        if board is None or not self.steps_out:
            self._apply_steps(1, direction)
            self._arrived_here()
            return None
        mark = board.next_mark(self.motor_position, direction)
        self._apply_steps(1, direction)
        self._arrived_here()
        if self.motor_position != mark:
            return None
        self.set_pins(*board.pins(self.motor_position))
        return Stop.MARK

    def _apply_steps(self, count: int, direction: int) -> None:
        delta = count * direction
        self.x_actual = (self.x_actual + delta) & MASK24
        if self.steps_out:
            self.motor_position += delta
        usrs = self.usrs
        self.ustep_count = (self.ustep_count + (delta << (6 - usrs if usrs < 6 else 0))) & 0xFF

    def _arrived_here(self) -> None:
        """The checks of a step onto this position: REF_MISS at X_ACTUAL 0 without the
        reference switch, the position compare."""
        if self.x_actual == 0 and not (self.right_active if self.ref_conf & REF_RNL
                                        else self.left_active):
            self._raise(Irq.REF_MISS)
        if self.pos_comp_on and self.x_actual == self.pos_comp:
            self.pos_comp_flag = True

    # == pins, switches, interrupts ============================================================

    def _raise(self, irq: Irq) -> None:
        if self.int_mask >> irq & 1:
            self.int_flags |= 1 << irq

    def _levels(self) -> tuple[bool, bool]:
        return self.left_active, self.right_active

    def _refresh_pins(self) -> None:
        if self.board is not None:
            self.ref_l, self.ref_r, self.gp_in = self.board.pins(self.motor_position)

    def set_pins(self, ref_l: bool, ref_r: bool, gp_in: bool) -> None:
        """Drive the input pins (electrical levels); edges act at once."""
        before = self._levels()
        self.ref_l, self.ref_r, self.gp_in = ref_l, ref_r, gp_in
        self._level_changes(before)

    def rewire(self, **wiring: bool) -> None:
        """Change wiring attributes (see the class docstring); level changes act at once."""
        before = self._levels()
        for name, value in wiring.items():
            setattr(self, name, value)
        self._level_changes(before)

    def _level_changes(self, before: tuple[bool, bool]) -> None:
        """What the switch levels' changes from ``before`` do: edge interrupts, the latch and
        REF_WRONG on an edge of the reference switch, a hard stop at the switch ahead."""
        left, right = self._levels()
        ref_is_right = bool(self.ref_conf & REF_RNL)
        if self._edge_interrupts(before, left, right) & (2 if ref_is_right else 1):
            self._reference_edge(right if ref_is_right else left)
        # A hard switch stop acts on the pulse generator at once.
        direction = (self.v > 0) - (self.v < 0)
        if (direction and self._switch_in_play(direction) and self._outside_window()
                and not self.ref_conf & SOFT_STOP):
            self.v = 0
            self._raise(Irq.STOP)

    def _edge_interrupts(self, before: tuple[bool, bool], left: bool, right: bool) -> int:
        """Raise the edge interrupts of the switches that changed; which did (bit 0 left,
        bit 1 right)."""
        changed = 0
        if left != before[0]:
            self._raise(Irq.STOP_LEFT_HIGH if left else Irq.STOP_LEFT_LOW)
            changed |= 1
        if right != before[1]:
            self._raise(Irq.STOP_RIGHT_HIGH if right else Irq.STOP_RIGHT_LOW)
            changed |= 2
        return changed

    def _reference_edge(self, active: bool) -> None:
        """An edge of the reference switch (``active``: its level now): the latch fires while
        V_ACTUAL != 0; turning active outside DX_REF_TOLERANCE raises REF_WRONG."""
        if self.latch_pending and self.v_actual != 0:
            self.x_latched = self.x_actual
            self.latch_pending = False
        if active and abs(signed(self.x_actual, 24)) >= self.dx_ref_tolerance:
            self._raise(Irq.REF_WRONG)
