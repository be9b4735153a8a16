"""stallGuard2 and coolStep as the TMCL firmware presents them (manual §6.3-6.4, AP 168-182, 206).

The motor driver measures the load once per full step (stallGuard2) and, with coolStep on,
raises or lowers the motor current to keep that reading between two thresholds.  The model
(docs/motion.md, "stallGuard2 and coolStep"):

* The world's load value (``axes.world``, 0..1023) is the reading at threshold 0, unfiltered.
  AP 174 (threshold, -64..63) shifts it by :data:`THRESHOLD_STEP` per unit, clamped to
  0..1023: a lower value is more sensitive (reads 0, a stall, at a lighter load), a higher
  one needs more torque.
* A blocked motor (a hard stop, a load beyond the motor's torque: the world's
  ``blocked``, or a load of 0) is past the point where the reading reaches 0: its load value
  is ``axes.world.BLOCKED_LOAD`` (-512), so it reads 0 at every threshold up to
  :data:`BLOCKED_STALL_THRESHOLD` (the positive thresholds users tune stall on it) and only
  an implausibly insensitive threshold reads above 0 there.
* AP 173 = 1 (filter): the reading is the mean over the last :data:`FILTER_FULL_STEPS` full
  steps travelled, and the driver measures once per four full steps instead of every one.
* coolStep (AP 172 > 0, moving at or above AP 182, and below AP 22 if that is set) regulates
  the current scale (AP 180, 0..31) between AP 6's scale and half or a quarter of it
  (AP 168): every reading at or above the upper threshold ``(AP172 + AP170 + 1) * 32`` counts
  towards a decrement (one per 32, 8, 2 or 1 readings, AP 169); every reading below the lower
  threshold ``AP172 * 32`` raises the scale by 1, 2, 4 or 8 (AP 171).

Everything here is arithmetic on counts of full steps: the firmware feeds it at its own
instants (its periodic pass, axes/tasks.py, and the world's load-zone edges, which are
events), every measurement since the last feed reading the load there, which is exact
between the edges (unfiltered; the filtered mean settles over four full steps after one).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from axes.world import BLOCKED_LOAD, LOAD_MAX
from tmcl_spec.parameters import AP

#: Change of the reading per unit of AP 174 [MODEL]: the threshold's range -64..63 then
#: spans the whole 0..1023 scale, as on the TMC2130/5130 drivers.
THRESHOLD_STEP = 16
#: The highest threshold at which a blocked motor still reads 0 (a stall) [MODEL].
BLOCKED_STALL_THRESHOLD = -BLOCKED_LOAD // THRESHOLD_STEP
#: World units (1/256 microsteps) per full step of the motor.
FULL_STEP = 256
#: The filtered reading (AP 173 = 1) is measured once per this many full steps.
FILTER_FULL_STEPS = 4
#: AP 169 -> readings above the upper threshold per decrement of the current scale.
READINGS_PER_DECREMENT = (32, 8, 2, 1)
#: AP 171 -> increment of the current scale per reading below the lower threshold.
INCREMENT_PER_READING = (1, 2, 4, 8)
#: Thresholds are in units of 32 readings (AP 170, AP 172).
THRESHOLD_UNIT = 32
#: AP 6 (0..255) -> current scale (0..31): the driver's CS.
CURRENT_SCALE_SHIFT = 3


def reading(load: int, threshold: int) -> int:
    """AP 206 unfiltered: the world's load value shifted by the threshold (AP 174), on the
    driver's scale 0..1023 (a blocked motor's load value lies below it)."""
    return max(0, min(LOAD_MAX, load + THRESHOLD_STEP * threshold))


def filtered_reading(load_at: Callable[[int], int], position: int, direction: int,
                     threshold: int) -> int:
    """AP 206 with the filter (AP 173 = 1): the mean over the last four full steps travelled."""
    samples = [reading(load_at(position - k * FULL_STEP * direction), threshold)
               for k in range(FILTER_FULL_STEPS)]
    return sum(samples) // FILTER_FULL_STEPS


def load_reading(params: Mapping[int, int], load_at: Callable[[int], int], position: int,
                 direction: int) -> int:
    """AP 206 without a modelled driver: the reading at ``position`` (world units) after the
    threshold (AP 174) and the filter (AP 173), the motor last travelling ``direction`` (at
    rest the driver holds what it measured over the last full steps it travelled)."""
    threshold = params[AP.STALLGUARD_THRESHOLD]
    if not params[AP.STALLGUARD_FILTER]:
        return reading(load_at(position), threshold)
    return filtered_reading(load_at, position, direction, threshold)


def run_current(run: int, scale: int | None) -> int:
    """The current while running (0..255): AP 6 (``run``), lowered to coolStep's ``scale``
    (0..31) where it regulates (None: it does not)."""
    if scale is None:
        return run
    return run * (scale + 1) // ((run >> CURRENT_SCALE_SHIFT) + 1)


def minimum_scale(full_scale: int, quarter: bool) -> int:
    """The lowest scale coolStep goes to: half (AP 168 = 0) or a quarter (1) of the current."""
    return max(0, (full_scale + 1) // (4 if quarter else 2) - 1)


def regulate(scale: int, above: int, measurements: int, sg_reading: int, semin: int, semax: int,
             seup: int, sedn: int, full: int, lowest: int) -> tuple[int, int]:
    """coolStep's law (the TMC26x's SMARTEN fields): (scale, readings above) after
    ``measurements`` stallGuard2 measurements that all read ``sg_reading``.

    Below ``SEMIN * 32`` every measurement raises the scale by 1, 2, 4 or 8 (SEUP); at or
    above ``(SEMIN + SEMAX + 1) * 32`` every 32, 8, 2 or 1 measurements (SEDN) lower it by 1;
    in between it stays.  It never leaves ``lowest..full``.  The firmware's model
    (:class:`CoolStep`) and the TMC262 model (axes/chips/tmc42x/tmc262.py) both regulate with this.
    """
    if not measurements:
        return scale, above
    if sg_reading < semin * THRESHOLD_UNIT:
        return min(full, scale + measurements * INCREMENT_PER_READING[seup]), 0
    if sg_reading >= (semin + semax + 1) * THRESHOLD_UNIT:
        steps, above = divmod(above + measurements, READINGS_PER_DECREMENT[sedn])
        return max(lowest, scale - steps), above
    return scale, 0


def switched_on(params: Mapping[int, int], speed: int) -> bool:
    """The firmware's coolStep switch at the speed ``speed`` (a magnitude): on (SEMIN = AP 172)
    unless the motor runs slower than AP 182, or (where the table has it) at or above AP 22;
    off with AP 172 = 0 (TMCL-LITE-1110 SysControl.c lines 83-101: ``abs(Velocity) <
    ThresholdSpeed`` switches it off, so with AP 182 = 0 it is on even at rest)."""
    high = params[AP.COOLSTEP_THRESHOLD_SPEED]
    return (params[AP.SMARTENERGY_HYSTERESIS_START] > 0
            and not speed < params[AP.SMARTENERGY_THRESHOLD_SPEED] and (not high or speed < high))


class CoolStep:
    """The current scale coolStep keeps (AP 180), fed with the full steps the motor travels.

    The motor driver regulates at every stallGuard2 measurement while coolStep is on; the
    firmware only switches it on and off (axes/tasks.py).  ``scale`` is None while it is off
    (the driver then uses AP 6 as it is).  Feeding is additive: the full steps since the last
    feed all read the reading given, so feeding at any instants between two changes of the
    reading (the world's load edges, the firmware's passes) gives the same scale.
    """

    def __init__(self) -> None:
        self.scale: int | None = None
        self._since = 0  # mechanical position of the last feed
        self._pending = 0  # full steps travelled that no measurement has used yet
        self._above = 0  # readings above the upper threshold not yet turned into a decrement

    def feed(self, params: Mapping[int, int], position: int, sg_reading: int, on: bool,
             full: int = 31) -> None:
        """The driver's regulation up to the motor at ``position`` (world units), every
        measurement on the way reading ``sg_reading``, with coolStep switched ``on`` or off,
        between ``full`` (the scale of the current in use, CS) and half or a quarter of it."""
        travelled, part = divmod(abs(position - self._since), FULL_STEP)
        self._since = position - part if position >= self._since else position + part
        if not on:
            self.scale, self._pending, self._above = None, 0, 0
            return
        lowest = minimum_scale(full, bool(params[AP.SMARTENERGY_CURRENT_MINIMUM]))
        scale = full if self.scale is None else max(lowest, min(full, self.scale))
        every = FILTER_FULL_STEPS if params[AP.STALLGUARD_FILTER] else 1
        self._pending += travelled
        measurements, self._pending = divmod(self._pending, every)
        self.scale, self._above = regulate(
            scale, self._above, measurements, sg_reading, params[AP.SMARTENERGY_HYSTERESIS_START],
            params[AP.SMARTENERGY_HYSTERESIS], params[AP.SMARTENERGY_CURRENT_UP_STEP],
            params[AP.SMARTENERGY_CURRENT_DOWN_STEP], full, lowest)
