"""The TMC4361A's home reference: HOME_REF edges latch X_HOME, and the home window's check.

REFERENCE_CONF's home_event (bits 19..16, digest §9.3) says what a HOME_REF edge means: a
side type (the level differs on the two sides of home), or a home switch active high or low
whose left edge, right edge or centre is home.  With START_HOME_TRACKING the first such edge
latches X_HOME (XLATCH_DONE); the expected levels below and above the window
X_HOME ± HOME_SAFETY_MARGIN feed HOME_ERROR_F (:meth:`TMC4361A._checked_flags`).  Choices are
in ``docs/tmc4361a.md``, "Switches, virtual stops, events".
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from axes.chips.tmc4361a.registers import MASK32, Event, RefConf, Reg, signed32

if TYPE_CHECKING:
    from axes.chips.tmc4361a.ramp import Ramp

#: home_event values (REFERENCE_CONF 19..16), digest §9.3
HOME_SIDE_TYPES = {3: False, 12: True}  # value: the level on the negative side
HOME_HIGH_ACTIVE = {2: "left", 4: "right", 6: "centre"}
HOME_LOW_ACTIVE = {13: "left", 11: "right", 9: "centre"}


class HomeTracking:
    """HOME_REF edges and expectations of a TMC4361A (a base of the chip's class)."""

    regs: dict[int, int]
    _ramp: Ramp
    _setup: tuple | None
    _home_latched: bool
    _home_entry: tuple[int, int] | None

    if TYPE_CHECKING:
        @property
        def xactual(self) -> int: ...

        def _raise(self, events: int) -> None: ...

    def _home_kind(self) -> int:
        return (self.regs.get(Reg.REFERENCE_CONF, 0) & RefConf.HOME_EVENT) >> 16

    def _home_expectation(self) -> tuple[bool, bool] | None:
        """Expected HOME_REF level (below, above) the X_HOME window; None: not checked."""
        kind = self._home_kind()
        if kind in HOME_SIDE_TYPES:
            below = HOME_SIDE_TYPES[kind]
            return below, not below
        if kind in HOME_HIGH_ACTIVE:
            return False, False
        if kind in HOME_LOW_ACTIVE:
            return True, True
        return None

    def _home_edge(self, old: bool, new: bool) -> None:
        """A HOME_REF edge: the home event of the selected type, with the present direction."""
        kind = self._home_kind()
        position = self._home_position(kind, new) if kind else None
        conf = self.regs.get(Reg.REFERENCE_CONF, 0)
        if position is not None and conf & RefConf.START_HOME_TRACKING and not self._home_latched:
            self.regs[Reg.X_HOME] = position & MASK32
            self._setup = None
            self._home_latched = True
            self._raise(Event.XLATCH_DONE)

    def _home_position(self, kind: int, level: bool) -> int | None:
        """Where a HOME_REF edge to ``level`` puts the home position for home event ``kind``
        (digest §9.3), None if it does not: a side type at the edge; an active-high or -low
        home switch at the edge of its named side, passing in the present direction; a
        centred one half-way between entering it and leaving it the same way."""
        if kind in HOME_SIDE_TYPES:
            return self.xactual
        side = HOME_HIGH_ACTIVE.get(kind) or HOME_LOW_ACTIVE.get(kind)
        if side is None:
            return None
        direction = self._ramp.s
        entering = level == (kind in HOME_HIGH_ACTIVE)
        if side != "centre":
            return self.xactual if (side == "left") == (entering == (direction > 0)) else None
        if entering:
            self._home_entry = (self.xactual, direction)
            return None
        if self._home_entry is None:
            return None
        entry, entry_direction = self._home_entry
        self._home_entry = None
        if entry_direction != direction:
            return None  # turned back inside, not passed through
        return (signed32(entry) + signed32(self.xactual - direction)) // 2
