"""The interpreter's hook into its module: :class:`ModulePort`.

A Protocol of the interpreter's own layer (the module implements it), apart from
``machine.py`` so that each part of the interpreter (``machine.py``, ``waits.py``,
``timer_cycles.py``) can name it without importing another.
"""

from __future__ import annotations

from typing import Protocol


class ModulePort(Protocol):
    """What the interpreter needs from the module it runs on.

    Every call carries the simulated time of the instruction; the module first brings its
    motion state up to that time.  Nothing it does may call back into the interpreter
    except :meth:`Interpreter.raise_interrupt` and the other event entry points.
    """

    def execute(self, time_ns: int, opcode: int, type_: int, motor: int,
                value: int) -> tuple[int, int, bool]:
        """Run one command as a program does: (status, value) as a reply would have them, and
        whether the command may have created or moved a module event (the caller re-plans)."""
        ...

    def axis_parameter(self, time_ns: int, motor: int, number: int) -> int:
        """The value of an axis parameter (WAIT uses 8, 9, 10 and 11)."""
        ...

    def reference_search_active(self, time_ns: int, motor: int) -> bool:
        """RFS STATUS: True while a reference search runs on ``motor``."""
        ...

    def steady_until(self, time_ns: int, opcode: int, type_: int, motor: int) -> int:
        """How long a read just made at ``time_ns`` (GAP ``type_`` of ``motor`` through
        :meth:`axis_parameter`, or RFS STATUS) keeps its answer, nothing intervening: as
        :meth:`probe`'s ``steady_until`` (a WAIT's condition, skipping.py I3)."""
        ...

    def program_event(self, time_ns: int, kind: str, **data: int) -> None:
        """Something observers may want to know: ``program_started``, ``program_stopped``
        (with ``pc``) or ``interrupt_taken`` (with ``vector`` and ``address``)."""
        ...

    def program_events(self, time_ns: int, period_ns: int, repeat: int, kind: str,
                       **data: int) -> None:
        """:meth:`program_event` ``repeat`` times, ``period_ns`` apart from ``time_ns`` on (a
        timer's dispatches left out by loop skipping): observers that take such a run as one
        event pay for one, not for each (skipping.py I12)."""
        ...

    def probe(self, time_ns: int, opcode: int, type_: int, motor: int,
              value: int) -> tuple[int, int, bool, int]:
        """:meth:`execute` for a loop being analysed: (status, value, changed, steady_until).

        ``changed``: the command changed the module (a write of a new value, a move, a store);
        a refused command and a write of what already is change nothing.  ``steady_until``
        (for an unchanged command): executed again at any time before it, with nothing
        intervening, the command answers the same and changes nothing (FOREVER: until
        something intervenes; the present or less: no such promise)."""
        ...

    def first_time_at(self, time_ns: int, opcode: int, type_: int, motor: int,
                      values: tuple[int, ...]) -> int:
        """For a read :meth:`probe` made at ``time_ns`` that was not steady (a moving
        position): the first time it compares otherwise with one of ``values`` than it did
        then, or a time before which it surely does not (0: cannot tell)."""
        ...

    def epoch(self) -> int:
        """Counts what may have changed the module's answers from outside the program's loop
        (host requests, commands that changed something, events, world changes), but not a
        program's write of a user variable: while it holds, an analysed pass holds
        (skipping.py I10)."""
        ...

    def user_variable(self, number: int) -> int | None:
        """User variable ``number`` (bank 2) as GGP would read it, if it is plain RAM (None
        otherwise): an analysed pass that read it holds while it has the same value (I10)."""
        ...
