"""The encoder behind AP 209, as the TMCL firmware reads it, and its deviation from AP 1.

The world's encoder sits on the mechanics (:class:`axes.board.AxisBoard`): it counts
``encoder_counts_per_rev`` per motor turn, misses a share of the motion while it slips, and
stands still with stuck mechanics.  The firmware scales its counts to AP 209's unit (AP 210
counts per AP 202 full steps at the microstep setting, or, on modules without AP 202, a
prescaler: AP 209 = counts * AP 210 / 512), and compares AP 209 with AP 1 against AP 212
(encoder counts on the TMCM-6212, microsteps on the TMC429 and TMC4361 modules).  The
choices are explained in docs/motion.md ("Encoder").
"""

from __future__ import annotations

from collections.abc import Mapping

from axes.board import AxisBoard
from axes.interface import DEFAULT_ENCODER_COUNTS_PER_REV
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP

#: An encoder prescaler's (AP 210 on modules without AP 202) unit: AP 209 = counts * p / 512;
#: its low five bits select special encoder functions (not modelled).
PRESCALER_UNIT = 512
PRESCALER_FUNCTION_BITS = 0x1F


class Encoder:
    """One axis's encoder reading, kept continuous when slip or the mechanics' mapping change."""

    def __init__(self, board: AxisBoard, params: Mapping[int, int], *, prescaler: bool,
                 deviation_in_microsteps: bool) -> None:
        self._board = board
        #: The firmware's parameter values (read live: AP 140, 202, 210, 212).
        self._params = params
        #: AP 210 is a prescaler (the table has no AP 202, motor full steps).
        self._prescaler = prescaler
        #: AP 212 counts microsteps, not encoder counts.
        self._deviation_in_microsteps = deviation_in_microsteps
        #: The module's own encoder, where the world names none (the sensOstep's 1024).
        self.builtin_counts = DEFAULT_ENCODER_COUNTS_PER_REV
        self._offset = 0  # encoder counts added to what the mechanics give
        self._mech_base = 0  # mechanical position at which slip was last rebased

    def counts_per_rev(self) -> int:
        """The world's encoder, or the module's own where the world names none."""
        return self._board.world.encoder_counts_per_rev or self.builtin_counts

    def _mechanical_per_count(self) -> float:
        """World units (1/256 of a full step) per encoder count."""
        return self._board.world.motor_fullsteps_per_rev * 256 / self.counts_per_rev()

    def counts(self, motor_position: int) -> int:
        world = self._board.world
        mech = self._board.mechanical(motor_position)
        seen = (mech - self._mech_base) * (1.0 - world.encoder_slip)
        return self._offset + int(seen // self._mechanical_per_count())

    def absolute(self, motor_position: int) -> int:
        """AP 215 (sensOstep modules): the rotor's angle within one turn, in encoder counts
        (0..counts per revolution - 1), whatever AP 209 was set to."""
        return (int(self._board.mechanical(motor_position) // self._mechanical_per_count())
                % self.counts_per_rev())

    def counts_per_microstep(self) -> float:
        """Encoder counts per unit of AP 209: AP 210 counts per revolution of AP 202 full
        steps, or (modules without AP 202) AP 209 = counts * AP 210 / 512, a prescaler."""
        params = self._params
        if self._prescaler:
            prescaler = params[AP.ENCODER_RESOLUTION] & ~PRESCALER_FUNCTION_BITS
            return PRESCALER_UNIT / prescaler if prescaler > 0 else 0.0
        resolution = params[AP.ENCODER_RESOLUTION]
        microsteps = params[AP.FULLSTEPS] << params[AP.MICROSTEPS]
        return resolution / microsteps if microsteps else 0.0

    def position(self, motor_position: int) -> int:
        """AP 209."""
        ratio = self.counts_per_microstep()
        return to_int32(round(self.counts(motor_position) / ratio)) if ratio else 0

    def set(self, microsteps: int, motor_position: int) -> None:
        """AP 209 written (or zeroed by a reference search)."""
        counts = round(microsteps * self.counts_per_microstep())
        self._offset += counts - self.counts(motor_position)

    def rebase(self, motor_position: int) -> None:
        """Keep the reading continuous when slip or the mechanics mapping change."""
        self._offset = self.counts(motor_position)
        self._mech_base = self._board.mechanical(motor_position)

    def placed(self, mechanical: int) -> None:
        """The mechanics were placed at ``mechanical`` and the counters start from 0."""
        self._mech_base = mechanical
        self._offset = 0

    def deviation(self, position: int, motor_position: int) -> float:
        """|AP 1 - AP 209| in the unit of AP 212: encoder counts, or microsteps (the TMC429
        and TMC4361 modules)."""
        gap = abs(position - self.position(motor_position))
        return gap if self._deviation_in_microsteps else gap * self.counts_per_microstep()

    def _limit_steps(self, limit: int) -> float:
        """AP 212 in microsteps of AP 1."""
        return limit if self._deviation_in_microsteps else limit / self.counts_per_microstep()

    def deviation_mark(self, position: int, motor_position: int, direction: int) -> int | None:
        """Motor position where the deviation will first exceed AP 212 (slip > 0, or stuck).

        The estimate is refined at the mark itself: if the limit is not yet exceeded there, a
        new mark at least one step further is set, so the event lands on the exact step.
        """
        limit = self._params[AP.MAX_DEVIATION]
        ratio = self.counts_per_microstep()
        board = self._board
        slip = 1.0 if board.stuck else board.world.encoder_slip  # stuck: the encoder sees nothing
        if not limit or not ratio or slip <= 0:
            return None
        encoder_per_step = (1.0 - slip) * board.scale / self._mechanical_per_count() / ratio
        rate = direction * (1.0 - encoder_per_step)  # change of AP1 - AP209 per step
        if rate == 0:
            return None
        deviation = position - self.position(motor_position)
        steps = self._limit_steps(limit)
        room = (steps - deviation) / rate if rate > 0 else (steps + deviation) / -rate
        return motor_position + direction * max(1, int(room))
