"""The seam between the TMCL firmware layer and an emulated motion-controller chip.

A *chip model* is the silicon: a register file behind SPI datagrams and the motion it makes.
It counts time in its own clock ticks and never reads a clock; the firmware layer above it
asks it to run up to a tick and is told when something notable happens on the way, so that
the simulator can jump from event to event.  ``axes/tmc4210.py`` is the first chip model;
every other chip (TMC4361A, TMC429) implements the same contract.

The pins a chip reads (reference switches, home, encoder) are driven by a :class:`Board`:
the module's input stage and the mechanics of the world (``axes/board.py``).
"""

from __future__ import annotations

from enum import IntEnum
from typing import Protocol, Self


class Stop(IntEnum):
    """Why :meth:`ChipModel.run` returned before its end tick."""

    ARRIVED = 1  # positioning ended at the target
    STOPPED = 2  # the velocity became zero some other way
    MARK = 3  # the motor reached a position the board asked to be told about
    EVENT = 4  # a chip event the firmware reacts to (switch, latch, velocity reached, ...)


class Board(Protocol):
    """What a chip's inputs are wired to: the module's input stage and the mechanics."""

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        """Electrical levels of (left stop, right stop, home) with the motor at ``motor_position``."""
        ...

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        """The nearest motor position beyond ``motor_position`` in ``direction`` that matters."""
        ...


class ChipModel(Protocol):
    """One emulated motion controller (or one motor of a multi-motor chip).

    Host access is :meth:`spi` only, as on the real board; the other members serve the
    simulator's time keeping and the world's pins.
    """

    clock_hz: int
    #: Chip clock ticks fully processed (the chip's own unit of time).
    t: int
    #: Steps that reached the motor, as an unwrapped integer (what the mechanics follow).
    motor_position: int

    def spi(self, frame: int) -> int:
        """Exchange one datagram (its width is the chip's: 32 bits TMC4210/TMC429, 40 TMC4361A)."""
        ...

    def clone(self) -> Self:
        """An independent copy, to look ahead without disturbing this chip."""
        ...

    def run(self, until: int) -> Stop | None:
        """Advance to tick ``until``; return early (``t < until``) at a notable instant."""
        ...

    def at_rest(self) -> bool:
        """True if nothing will change by itself until a datagram or a pin changes it."""
        ...

    def ticks_at(self, t_ns: int) -> int:
        """Ticks that have happened by simulated time ``t_ns``."""
        ...

    def ns_at(self, ticks: int) -> int:
        """Simulated time (ns, rounded up) of tick ``ticks``."""
        ...

    def set_pins(self, left: bool, right: bool, home: bool) -> None:
        """Drive the switch inputs (electrical levels); edges act at once."""
        ...
