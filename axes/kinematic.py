"""A closed-form trapezoidal axis in pps units.

This is the stand-in motion engine behind the :class:`~axes.interface.Axis` contract until
the TMC4210 emulation replaces it.  It is honest: positions move along real
constant-acceleration segments over simulated time, moves end exactly on their target, and
the target-reached event fires at the instant the ramp ends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from axes.interface import AxisEvent, AxisEventKind, AxisStatus
from axes.parameters import AXIS_PARAMETERS

NS = 1_000_000_000

AP_TARGET_POSITION = 0
AP_ACTUAL_POSITION = 1
AP_TARGET_SPEED = 2
AP_ACTUAL_SPEED = 3
AP_MAX_SPEED = 4
AP_MAX_ACCELERATION = 5
AP_POSITION_REACHED = 8


@dataclass(slots=True)
class _Segment:
    start_ns: int
    duration_ns: int  # -1: lasts forever
    x: float
    v: float
    a: float

    def at(self, t_ns: int) -> tuple[float, float]:
        dt = (t_ns - self.start_ns) / NS
        return self.x + self.v * dt + 0.5 * self.a * dt * dt, self.v + self.a * dt

    @property
    def end_ns(self) -> int | None:
        return None if self.duration_ns < 0 else self.start_ns + self.duration_ns


class KinematicAxis:
    """Trapezoidal ramps computed in closed form; switches, encoder and load are absent."""

    def __init__(self, index: int) -> None:
        self.index = index
        self._params = {n: spec.default for n, spec in AXIS_PARAMETERS.items()}
        self._now_ns = 0
        self._positioning = False
        self._target = 0
        self._target_speed = 0
        self._plan: list[_Segment] = [_Segment(0, -1, 0.0, 0.0, 0.0)]
        self._arrival_pending = False

    # -- time ---------------------------------------------------------------------------------

    def _segment(self, t_ns: int) -> _Segment:
        for seg in self._plan:
            end = seg.end_ns
            if end is None or t_ns < end:
                return seg
        return self._plan[-1]

    def _state(self, t_ns: int) -> tuple[float, float]:
        seg = self._segment(t_ns)
        end = seg.end_ns
        if end is not None and t_ns >= end:
            return seg.at(end)
        return seg.at(t_ns)

    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        events: list[AxisEvent] = []
        arrival = self._plan[-1].start_ns
        if self._arrival_pending and t_ns >= arrival:
            self._arrival_pending = False
            events.append(AxisEvent(arrival, self.index, AxisEventKind.TARGET_REACHED))
        self._now_ns = max(self._now_ns, t_ns)
        # Drop finished segments so the plan stays short.
        while len(self._plan) > 1 and (self._plan[0].end_ns or 0) <= self._now_ns:
            self._plan.pop(0)
        return events

    def next_event_ns(self) -> int | None:
        return self._plan[-1].start_ns if self._arrival_pending else None

    # -- planning -----------------------------------------------------------------------------

    @property
    def _amax(self) -> float:
        return float(self._params[AP_MAX_ACCELERATION])

    def _replan(self) -> None:
        now = self._now_ns
        x, v = self._state(now)
        self._plan = []
        a = self._amax
        if not self._positioning:
            self._plan_velocity(now, x, v, float(self._target_speed), a)
            return
        self._arrival_pending = True
        self._plan_position(now, x, v, float(self._target), float(self._params[AP_MAX_SPEED]), a)

    def _add(self, start: int, seconds: float, x: float, v: float, a: float) -> tuple[int, float, float]:
        duration = max(0, round(seconds * NS))
        seg = _Segment(start, duration, x, v, a)
        self._plan.append(seg)
        x2, v2 = seg.at(start + duration)
        return start + duration, x2, v2

    def _plan_velocity(self, t: int, x: float, v: float, vt: float, a: float) -> None:
        if v != vt and a > 0:
            t, x, _ = self._add(t, abs(vt - v) / a, x, v, math.copysign(a, vt - v))
            v = vt
        self._plan.append(_Segment(t, -1, x, v, 0.0))

    def _plan_position(self, t: int, x: float, v: float, target: float, vmax: float, a: float) -> None:
        if a <= 0 or (vmax <= 0 and v == 0):
            # Cannot accelerate (or may not move): coast at the current speed, never arrive.
            self._arrival_pending = v == 0 and x == target
            self._plan.append(_Segment(t, -1, x, v, 0.0))
            return
        d = target - x
        direction = math.copysign(1.0, d) if d else math.copysign(1.0, v or 1.0)
        stopping = v * v / (2 * a)
        if v * direction < 0 or stopping > abs(d):
            # Moving away from the target or too fast to stop in time: stop first.
            t, x, _ = self._add(t, abs(v) / a, x, v, -math.copysign(a, v))
            v = 0.0
            d = target - x
            direction = math.copysign(1.0, d) if d else 1.0
        s, u = abs(d), abs(v)
        peak = min(vmax, math.sqrt(a * s + u * u / 2)) if u <= vmax else vmax
        ramp_in = abs(peak * peak - u * u) / (2 * a)
        ramp_out = peak * peak / (2 * a)
        cruise = max(0.0, s - ramp_in - ramp_out)
        sign_in = 1.0 if peak >= u else -1.0
        t, x, v = self._add(t, abs(peak - u) / a, x, v, direction * sign_in * a)
        if peak > 0:
            t, x, v = self._add(t, cruise / peak, x, direction * peak, 0.0)
        t, x, v = self._add(t, peak / a, x, direction * peak, -direction * a)
        self._plan.append(_Segment(t, -1, target, 0.0, 0.0))

    # -- commands -----------------------------------------------------------------------------

    def rotate(self, velocity: int) -> None:
        self._positioning = False
        self._arrival_pending = False
        self._target_speed = velocity
        self._replan()

    def stop(self) -> None:
        self.rotate(0)

    def emergency_stop(self) -> None:
        x, _ = self._state(self._now_ns)
        self._positioning = False
        self._arrival_pending = False
        self._target_speed = 0
        self._plan = [_Segment(self._now_ns, -1, x, 0.0, 0.0)]

    def move_to(self, target: int) -> None:
        self._positioning = True
        self._target = target
        self._replan()

    def reference_search(self, action: int) -> int:
        return 0

    def status(self) -> AxisStatus:
        x, v = self._state(self._now_ns)
        return AxisStatus(position=round(x), target=self._target, velocity=round(v),
                          mode="position" if self._positioning else "velocity",
                          position_reached=bool(self.get_parameter(AP_POSITION_REACHED)))

    # -- parameters ---------------------------------------------------------------------------

    def get_parameter(self, number: int) -> int:
        if number == AP_TARGET_POSITION:
            return self._target
        if number == AP_ACTUAL_POSITION:
            return round(self._state(self._now_ns)[0])
        if number == AP_TARGET_SPEED:
            return self._target_speed
        if number == AP_ACTUAL_SPEED:
            return round(self._state(self._now_ns)[1])
        if number == AP_POSITION_REACHED:
            return int(self.get_parameter(AP_ACTUAL_POSITION) == self._target)
        return self._params[number]

    def set_parameter(self, number: int, value: int) -> None:
        if number == AP_TARGET_POSITION:
            self.move_to(value)
        elif number == AP_ACTUAL_POSITION:
            _, v = self._state(self._now_ns)
            self._plan = [_Segment(self._now_ns, -1, float(value), v, 0.0)]
            if self._positioning:
                self._target = value
                self._arrival_pending = False
        elif number == AP_TARGET_SPEED:
            self.rotate(value)
        else:
            self._params[number] = value
            if number in (AP_MAX_SPEED, AP_MAX_ACCELERATION) and self._positioning:
                self._replan()
