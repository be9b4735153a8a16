"""The evaluation system's own commands (tmcl_spec/landungsbruecke.py, docs/tmc4361a.md): its
MVP, UF0..UF2, board assignment (143) and the driver-board registers (147, 149).  A module type
assigns them to opcodes by name in its profile (``ModuleType.handlers``)."""

from __future__ import annotations

from tmcl_server.dispatch import CommandError, Interface, ReplySink
from tmcl_server.module.core import ModuleCore
from tmcl_server.protocol import Request
from tmcl_spec.commands import MoveType, Status
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP, EvalGP


class EvaluationCommands(ModuleCore):
    """Handlers whose opcodes mean something else on the TMCL modules."""

    def _cmd_mvp_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> int | None:
        """MVP on the evaluation firmware: ABS, or REL from XACTUAL (the reply carries the
        absolute target); it has no coordinates (type 2: status 2)."""
        axis = self._axis(req.motor)
        if req.type == MoveType.ABS:
            axis.move_to(req.value)
            return None
        if req.type == MoveType.REL:
            target = to_int32(axis.get_parameter(AP.ACTUAL_POSITION) + req.value)
            axis.move_to(target)
            return target
        if req.type == MoveType.COORD:
            raise CommandError(Status.INVALID_COMMAND)
        raise CommandError(Status.WRONG_TYPE)

    def _cmd_drivers_enable(self, req: Request, sink: ReplySink | None,
                            interface: Interface) -> None:
        """UF0: all drivers on or off (GP 2 reads it back)."""
        self.globals[0][EvalGP.DRIVERS_ENABLE] = int(req.value != 0)

    def _eeprom_channel(self, req: Request) -> bytearray | None:
        if req.type not in (1, 2):
            raise CommandError(Status.WRONG_TYPE)
        return self.id_eeproms.get(req.type)

    def _cmd_read_id_eeprom(self, req: Request, sink: ReplySink | None,
                            interface: Interface) -> int:
        """UF1: four bytes of a board's ID EEPROM from address ``value``, little endian (a
        channel without an EEPROM reads 0)."""
        image = self._eeprom_channel(req)
        if image is None:
            return 0
        data = bytes(image[(req.value + i) % len(image)] for i in range(4))
        return to_int32(int.from_bytes(data, "little"))

    def _cmd_write_id_eeprom(self, req: Request, sink: ReplySink | None,
                             interface: Interface) -> None:
        """UF2: the motor field is the byte written to address ``value``."""
        image = self._eeprom_channel(req)
        if image is None:
            raise CommandError(Status.EEPROM_LOCKED)  # no EEPROM answers on that channel
        image[req.value % len(image)] = req.motor

    def _cmd_board_assignment(self, req: Request, sink: ReplySink | None,
                              interface: Interface) -> int | None:
        """Command 143: type 0 detects the boards again (the motion controller is reset and
        configured anew) and answers what was found; 4 asks which ids are supported; 5
        re-checks board types (nothing to do for these boards)."""
        boards = self.type.eval_boards
        if boards is None:  # a profile that assigns 143 here names its boards
            raise CommandError(Status.INVALID_COMMAND)
        if req.type == 0:
            for index in range(len(self.axes)):
                self.axis(index).reset_board()
            return boards.detected
        if req.type == 4:
            return boards.supported
        if req.type == 5:
            return None
        if req.type in (1, 2, 3):  # assigning ids by hand: the boards stay what they are
            return boards.supported
        raise CommandError(Status.WRONG_TYPE)

    def _cmd_write_drv(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        """147 on the evaluation firmware: a register of the driver board (none here)."""

    def _cmd_read_drv(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        """149: no driver board answers; the reply carries the request's value back."""

