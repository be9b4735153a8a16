"""A literal, one-clk32-tick-at-a-time transcription of the digest's reference model (§4.8).

Slow on purpose: it is the yardstick the fast engine in axes/chips/tmc42x/tmc4210.py is tested against
(tests/test_tmc4210.py), not part of the simulator.
Stop switches are modelled as levels that stay put (``left`` / ``right`` active, the soft-stop
bit, the disable bits and the tolerance window of REF_CONF): what the ramp generator does with
them.  Edges, the latch and interrupts are checked separately, except where the levels follow
the motor's position (``switches``): then an edge that activates the switch ahead of a moving
motor stops it at once, as the engine documents (a hard stop acts on the pulse generator).
``run_until`` ticks the same way but skips the clk32 ticks at which nothing can happen (neither
a ramp nor a pulse tick): long moves in the tests.
"""

from __future__ import annotations

from collections.abc import Callable
from math import isqrt

from axes.chips.tmc42x.tmc4210 import DISTANCE_LIMIT, RampMode, sdiff24


class ReferenceChip:
    def __init__(self, *, v_min: int, v_max: int, a_max: int, pmul: int, pdiv: int,
                 pulse_div: int, ramp_div: int, mode: RampMode = RampMode.RAMP) -> None:
        self.v_min, self.v_max, self.a_max = v_min, v_max, a_max
        self.pmul, self.pdiv = pmul | 0x80, pdiv
        self.pulse_div, self.ramp_div, self.mode = pulse_div, ramp_div, mode
        self.x_target = self.x_actual = 0
        self.v_target = 0
        self.v = 0
        self.acc = 0
        self.t = 0
        self.left = self.right = False  # stop switch levels (active), constant
        self.soft_stop = self.disable_left = self.disable_right = False
        self.tolerance = 0
        self.arrivals: list[int] = []
        #: Steps made, unwrapped (the motor's position).
        self.position = 0
        #: (left, right) switch levels as a function of the position, or None: they stay put.
        self.switches: Callable[[int], tuple[bool, bool]] | None = None

    def run_until(self, until: int) -> None:
        """``tick()`` until ``t == until``, visiting only ticks that are multiples of the finer
        divider (every ramp and pulse tick is one of them; the others change nothing)."""
        step = 1 << min(self.ramp_div, self.pulse_div)
        while self.t < until:
            following = (self.t // step + 1) * step
            if following > until:
                self.t = until
                return
            self.t = following - 1
            self.tick()

    def tick(self) -> None:
        self.t += 1
        if self.t % (1 << self.ramp_div) == 0:
            self.ramp_tick()
        if self.t % (1 << self.pulse_div) == 0:
            self.pulse_tick()

    def ramp_tick(self) -> None:
        if self.mode in (RampMode.RAMP, RampMode.SOFT):
            dx = sdiff24(self.x_target, self.x_actual)
            if dx == 0:
                vt = 0
            else:
                d = min(abs(dx), DISTANCE_LIMIT)
                if self.mode == RampMode.RAMP:
                    mag = isqrt((256 * self.pmul * d) >> self.pdiv)
                else:
                    mag = (self.pmul * d) >> (3 + self.pdiv)
                mag = min(max(mag, self.v_min), self.v_max)
                vt = mag if dx > 0 else -mag
            self.v_target = vt
        elif self.mode == RampMode.VELOCITY:
            vt = max(-self.v_max, min(self.v_max, self.v_target))
        else:
            vt = 0
        direction = (self.v > 0) - (self.v < 0) or (vt > 0) - (vt < 0)
        x = self.x_actual - (1 << 24) if self.x_actual & 1 << 23 else self.x_actual
        outside = abs(x) >= self.tolerance
        if direction < 0 and self.left and not self.disable_left and outside:
            vt = max(vt, 0)
            if self.mode == RampMode.HOLD or not self.soft_stop:
                self.v = 0
        elif direction > 0 and self.right and not self.disable_right and outside:
            vt = min(vt, 0)
            if self.mode == RampMode.HOLD or not self.soft_stop:
                self.v = 0
        if self.mode == RampMode.HOLD:
            return
        target = vt * 256
        if self.v < target:
            self.v = min(self.v + self.a_max, target)
        elif self.v > target:
            self.v = max(self.v - self.a_max, target)

    def pulse_tick(self) -> None:
        if (self.mode in (RampMode.RAMP, RampMode.SOFT) and self.x_actual == self.x_target
                and abs(self.v) >> 8 <= self.v_min):
            if self.v != 0:
                self.v = 0
                self.arrivals.append(self.t)
            return
        self.acc += abs(self.v) >> 8
        if self.acc >= 2048:
            self.acc -= 2048
            direction = 1 if self.v > 0 else -1
            self.x_actual = (self.x_actual + direction) & 0xFFFFFF
            self.position += direction
            if self.switches is not None:
                self.switch_edges(direction)

    def switch_edges(self, direction: int) -> None:
        """The levels at the new position; a switch ahead that turns active stops a hard-stopping
        motor at once (outside the tolerance window, not disabled)."""
        assert self.switches is not None
        left, right = self.switches(self.position)
        rising = ((direction < 0 and left and not self.left and not self.disable_left)
                  or (direction > 0 and right and not self.right and not self.disable_right))
        self.left, self.right = left, right
        x = self.x_actual - (1 << 24) if self.x_actual & 1 << 23 else self.x_actual
        if rising and abs(x) >= self.tolerance and not self.soft_stop:
            self.v = 0
