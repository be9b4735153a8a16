"""The board around one axis: the module's input stage and the mechanics, as the chip sees them.

The chip's switch pins are driven from here (:class:`axes.core.Board`), and the firmware asks
it where the mechanics are (mechanical position, load, encoder) and at which motor positions
something changes, so the motion engine can stop exactly there.
"""

from __future__ import annotations

from axes.world import AxisWorld, Switch


class AxisBoard:
    """What the chip's pins and STEP output are connected to, for one axis.

    Mechanical position (world units, 1/256 microsteps) = ``mech_base`` + (motor steps -
    ``steps_base``) * 2**(8 - microstep setting), or ``mech_base`` alone while the axis is
    stuck (the motor no longer follows its steps: the mechanics, the switches they actuate
    and the encoder stay where they are).  Switch levels are the world's electrical
    levels, swapped (AP 14) and XOR-ed with the polarity parameters (AP 24/25) by the
    module's input stage before they reach REF_L/REF_R; the home switch drives GP_IN.
    """

    def __init__(self, world: AxisWorld | None = None) -> None:
        self.world = world or AxisWorld()
        self.swap = False
        self.invert_left = False
        self.invert_right = False
        self.scale = 1
        self.mech_base = 0
        self.steps_base = 0
        #: Extra motor positions the firmware wants to be woken at (deviation, rolling target).
        self.firmware_marks: list[int] = []
        #: The motor stops following its steps (a fault: AxisWorld.stuck, docs/faults.md).
        self.stuck = False
        self._edges = self.world.edges()

    def set_world(self, world: AxisWorld) -> None:
        self.world = world
        self._edges = world.edges()

    def set_switch(self, name: str, switch: Switch | None) -> None:
        """Place (or with None remove) the "left", "right" or "home" switch in the world."""
        if switch is None:
            self.world.switches.pop(name, None)
        else:
            self.world.switches[name] = switch
        self.world_changed()

    def world_changed(self) -> None:
        self._edges = self.world.edges()

    def rescale(self, motor_position: int, microstep_setting: int) -> None:
        """A new microstep resolution: later steps move 2**(8 - setting) world units each."""
        self.mech_base = self.mechanical(motor_position)
        self.steps_base = motor_position
        self.scale = 1 << (8 - microstep_setting)

    def mechanical(self, motor_position: int) -> int:
        if self.stuck:
            return self.mech_base
        return self.mech_base + (motor_position - self.steps_base) * self.scale

    def set_stuck(self, stuck: bool, motor_position: int) -> None:
        """From ``motor_position`` on the mechanics stop following the motor (or follow it again
        from where they stopped)."""
        if stuck != self.stuck:
            self.mech_base = self.mechanical(motor_position)
            self.steps_base = motor_position
            self.stuck = stuck

    def place(self, mechanical: int, motor_position: int) -> None:
        """The mechanics stand at ``mechanical`` with the motor at ``motor_position`` (after a
        module restart the counters start again, the mechanics stay where they are)."""
        self.mech_base = mechanical
        self.steps_base = motor_position

    def load(self, motor_position: int) -> int:
        """The world's load value with the motor at ``motor_position`` (what a modelled
        driver's stallGuard2 measures, axes/chips/tmc42x/tmc262.py)."""
        return self.world.load_at(self.mechanical(motor_position))

    def pins(self, motor_position: int) -> tuple[bool, bool, bool]:
        mech = self.mechanical(motor_position)
        left = self.world.level("left", mech)
        right = self.world.level("right", mech)
        if self.swap:
            left, right = right, left
        return left != self.invert_left, right != self.invert_right, self.world.level("home", mech)

    def next_mark(self, motor_position: int, direction: int) -> int | None:
        edges = () if self.stuck else self._edges  # stuck mechanics never reach an edge
        if not edges and not self.firmware_marks:
            return None  # the usual case, asked at every position read of a moving axis
        mech = self.mechanical(motor_position)
        best: int | None = None
        if direction > 0:
            for edge in edges:  # levels at p and p - 1 differ: first step with mech >= edge
                if edge > mech:
                    best = self.steps_base + -(-(edge - self.mech_base) // self.scale)
                    break
        else:
            for edge in reversed(edges):  # last step with mech <= edge - 1
                if edge - 1 < mech:
                    best = self.steps_base + (edge - 1 - self.mech_base) // self.scale
                    break
        for mark in self.firmware_marks:
            if (mark - motor_position) * direction > 0 and (
                    best is None or (mark - best) * direction < 0):
                best = mark
        return best
