"""Control commands: firmware version (136), factory reset (137), user functions UF0..UF7, and
raw motion-controller registers (146/147, 148 as pytrinamic's read_mc sends it)."""

from __future__ import annotations

from axes.interface import Axis
from tmcl_server.dispatch import NO_REPLY, CommandError, Interface, ReplySink
from tmcl_server.eeprom import EepromWriteError
from tmcl_server.module.core import ModuleCore
from tmcl_server.protocol import RawReply, Request
from tmcl_spec.commands import FACTORY_RESET_KEY, Status


class ControlCommands(ModuleCore):
    """Handlers of the module-wide control commands and raw register access."""

    def _register_request(self, req: Request) -> tuple[Axis, int]:
        if not 0 <= req.type <= 0x7F:  # a 7-bit register address
            raise CommandError(Status.WRONG_TYPE)
        return self._axis(req.motor), req.type

    def _cmd_write_mc(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        axis, address = self._register_request(req)
        axis.register_access(address, req.value)

    def _cmd_read_mc(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        axis, address = self._register_request(req)
        return axis.register_access(address)

    # == control commands ======================================================================

    def _cmd_get_firmware_version(self, req: Request, sink: ReplySink | None,
                                  interface: Interface) -> RawReply | int:
        if req.type == 0:
            version = self.type.version_string
            return RawReply(bytes((self.host_address,)) + version, version)
        if req.type == 1:
            return self.type.version_number
        raise CommandError(Status.WRONG_TYPE)

    def _cmd_restore_factory_settings(self, req: Request, sink: ReplySink | None,
                                      interface: Interface) -> object:
        if req.value != FACTORY_RESET_KEY:
            raise CommandError(Status.INVALID_VALUE)
        try:
            self.factory_reset()
        except EepromWriteError:  # restarted on factory settings, but the file still holds
            self.power_up()       # the old ones: say so with status 5
            self.emit("factory_reset", None)
            raise
        self.emit("factory_reset", None)
        return NO_REPLY

    def _cmd_user_function(self, req: Request, sink: ReplySink | None,
                           interface: Interface) -> None:
        """UF0..UF7 (§3.6.34): this firmware has no customer extension; "100 - OK"."""

