"""The rig around an axis: the world and the faults of its mechanics and wiring, written once.

Every axis kind (the TMCL firmware's :class:`axes.firmware.AxisFirmware`, the evaluation
board's :class:`axes.chips.tmc4361a.eval_board.TMC4361AEvalAxis`) stands on an
:class:`axes.board.AxisBoard`: the world file, the run-time API (tmcl_server/module) and the
injected faults (tmcl_server/faults.py, docs/faults.md) change that board, and the axis hears
of it through a few hooks: it is brought to the present first, told when the switch lines may
have changed, and may keep an encoder that must not jump.
"""

from __future__ import annotations

from abc import abstractmethod

from axes.board import AxisBoard
from axes.interface import Axis
from axes.world import AxisWorld, LoadZone, Switch


class RiggedAxis(Axis):
    """An axis whose world is an :class:`AxisBoard` (``board``) under a chip."""

    board: AxisBoard

    @abstractmethod
    def _motor_position(self) -> int:
        """The chip's motor position (the board maps it to the mechanics)."""

    @abstractmethod
    def _rig_begin(self) -> None:
        """Bring the axis to the present before its world changes."""

    def _rig_end(self) -> None:
        """After the world changed: whatever the axis re-checks (stall, marks).  Default
        nothing."""
        return

    @abstractmethod
    def _pins_changed(self) -> None:
        """The switch lines may have changed: the chip's pins follow the board."""

    def _rebase_encoder(self) -> None:
        """The mapping from steps to mechanics is about to change or just did: an encoder
        keeps its reading continuous.  Default: no encoder."""
        return

    def _encoder_placed(self, mechanical: int) -> None:
        """The mechanics were placed at ``mechanical`` with fresh counters.  Default: no
        encoder."""
        return

    @property
    def world(self) -> AxisWorld:
        return self.board.world

    def set_world(self, world: AxisWorld) -> None:
        """Replace the whole world of this axis (switch edges happen now)."""
        self._rig_begin()
        self._rebase_encoder()
        self.board.set_world(world)
        self.board.set_stuck(world.stuck, self._motor_position())
        self._rebase_encoder()
        self._pins_changed()
        self._rig_end()

    def set_switch(self, name: str, switch: Switch | None) -> None:
        self._rig_begin()
        self.board.set_switch(name, switch)
        self._pins_changed()
        self._rig_end()

    def set_load(self, zones: list[LoadZone], free_load: int | None = None) -> None:
        self._rig_begin()
        world = self.board.world
        world.load_zones = list(zones)
        if free_load is not None:  # a value of its own: blocked if it is 0 (axes/world.py)
            world.free_load, world.free_blocked = free_load, None
        self.board.world_changed()
        self._rig_end()

    def set_encoder_slip(self, slip: float) -> None:
        if not 0.0 <= slip <= 1.0:
            raise ValueError("slip must be between 0 and 1")
        self._rig_begin()
        self._rebase_encoder()
        self.board.world.encoder_slip = slip
        self._rig_end()

    # == faults of the mechanics and the wiring (tmcl_server/faults.py) ==========================

    def set_stuck(self, stuck: bool, load: int | None = None) -> None:
        """A fault of the mechanics: from now on the motor no longer follows its steps (or
        follows them again).  The chip keeps counting; the mechanics, the switches they actuate
        and an encoder on them stay where they stopped, so an encoder deviates (AP 212 catches
        it).  ``load``: what stallGuard2 reads meanwhile (0 for a blocked rotor; None: the
        world's)."""
        self._rig_begin()
        world = self.board.world
        world.stuck = stuck
        world.stuck_load = load if stuck else None
        self.board.set_stuck(stuck, self._motor_position())
        self.board.world_changed()
        self._pins_changed()
        self._rig_end()

    def break_switch(self, name: str, level: bool | None) -> None:
        """A broken switch: its input stays at the electrical ``level`` wherever the axis is
        (before the input stage: swap and polarity, AP 14/24/25, or the board's pull-ups);
        None repairs it."""
        self._rig_begin()
        if level is None:
            self.board.world.broken_switches.pop(name, None)
        else:
            self.board.world.broken_switches[name] = level
        self.board.world_changed()
        self._pins_changed()
        self._rig_end()

    def place_mechanics(self, mechanical: int) -> None:
        """After a module restart: the mechanics stand at ``mechanical`` (world units) while
        the fresh counters (AP 1, an encoder) start from 0, so the world's switches and load
        zones stay where they are."""
        self._rig_begin()
        self.board.place(mechanical, self._motor_position())
        self._encoder_placed(mechanical)
        self._pins_changed()
        self._rig_end()
