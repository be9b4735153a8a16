"""Motion commands: ROR, ROL, MST, MVP (ABS, REL, COORD), RFS, and the target-reached event
(138) that MVP arms."""

from __future__ import annotations

from tmcl_server.dispatch import CommandError, Interface, ReplySink
from tmcl_server.module.core import ModuleCore
from tmcl_server.protocol import Request
from tmcl_spec.commands import COORD_MOTOR_MASK_FLAG, MoveType, Status
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP

#: MVP REL counts from: AP 127 value -> axis parameter.
_RELATIVE_ORIGIN = {0: AP.TARGET_POSITION, 1: AP.ACTUAL_POSITION, 2: AP.ENCODER_POSITION}


class MotionCommands(ModuleCore):
    """Handlers that start, stop and watch motion."""

    def _cmd_ror(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.changed = self._axis(req.motor).rotate(req.value)

    def _cmd_rol(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.changed = self._axis(req.motor).rotate(to_int32(-req.value))

    def _cmd_mst(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.changed = self._axis(req.motor).stop()

    def _cmd_mvp(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if req.type == MoveType.COORD:
            self._move_to_coordinate(req.motor, req.value)
            return
        axis = self._axis(req.motor)
        if req.type == MoveType.ABS:
            target = req.value
            if not self.type.axis_parameters[AP.TARGET_POSITION].accepts(target):
                raise CommandError(Status.INVALID_VALUE)  # beyond the module's position range
        elif req.type == MoveType.REL:
            origin = _RELATIVE_ORIGIN[axis.get_parameter(AP.RELATIVE_POSITIONING_OPTION)]
            target = to_int32(axis.get_parameter(origin) + req.value)
        else:
            raise CommandError(Status.WRONG_TYPE)
        self._arm_reach_watch(axis.index)
        axis.move_to(target)

    def _move_to_coordinate(self, motor: int, number: int) -> None:
        """MVP COORD: motor 0..5, or (motor field 0..255, §3.6.4) bit 7 set and a motor mask.

        The motors of a mask start together, each to its own coordinate ``number``
        (docs/protocol.md).
        """
        if motor & COORD_MOTOR_MASK_FLAG:
            indices = [i for i in range(len(self.axes)) if motor >> i & 1]
        else:
            indices = [self._axis_index(motor)]
        if not indices or not 0 <= number < self.type.coordinates:
            raise CommandError(Status.INVALID_VALUE)
        self._arm_reach_watch(*indices)
        for index in indices:
            self.axis(index).move_to(self.coordinates[index][number])

    def _cmd_rfs(self, req: Request, sink: ReplySink | None, interface: Interface) -> int | None:
        axis = self._axis(req.motor)
        if req.type not in (0, 1, 2):
            raise CommandError(Status.WRONG_TYPE)
        result = axis.reference_search(req.type)
        if req.type == 2:
            self.changed = False  # a status read
            return result
        return None

    def _cmd_target_reached_event(self, req: Request, sink: ReplySink | None,
                                  interface: Interface) -> None:
        if req.type not in (0, 1):
            raise CommandError(Status.WRONG_TYPE)
        mask = req.value & ((1 << len(self.axes)) - 1)
        if sink is None or mask == 0:
            self._reach_request = None
            return
        self._reach_request = (mask, req.type == 1, sink, interface)

