"""Parameter commands: axis parameters (SAP, GAP, STAP, RSAP) and global parameters (SGP, GGP,
STGP, RSGP); the RAM copy of the global parameters is the core's (read_global, write_global)."""

from __future__ import annotations

from axes.interface import NotAvailable
from tmcl_server.dispatch import CommandError, Interface, ReplySink
from tmcl_server.module.core import ModuleCore
from tmcl_server.protocol import Request
from tmcl_spec.commands import Status
from tmcl_spec.parameters import ParamSpec


class ParameterCommands(ModuleCore):
    """Handlers of the axis and global parameter commands."""

    def _cmd_sap(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        spec = self._axis_spec(req.type)
        axis = self._axis(req.motor)
        if not spec.writable:
            raise CommandError(Status(self.type.unknown_parameter_status))
        if not spec.accepts(req.value):
            raise CommandError(Status.INVALID_VALUE)
        if req.type == 0:
            self._arm_reach_watch(axis.index)
        try:
            self.changed = axis.set_parameter(req.type, spec.normalise(req.value))
        except NotAvailable as exc:  # refused in the firmware's present state
            raise CommandError(Status.COMMAND_NOT_AVAILABLE) from exc
        except ValueError as exc:
            raise CommandError(Status.INVALID_VALUE) from exc

    def _cmd_gap(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        if not self._axis_spec(req.type).readable:  # a fixed setting the module does not show
            raise CommandError(Status.WRONG_TYPE)
        return self._axis(req.motor).get_parameter(req.type)

    def _cmd_stap(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        axis = self._axis(req.motor)
        if req.type not in self.type.storable_axis_parameters:
            raise CommandError(Status.WRONG_TYPE)
        stored = dict(self.eeprom.get("axis_parameters", axis.index) or {})
        stored[str(req.type)] = axis.get_parameter(req.type)
        self.eeprom.put("axis_parameters", axis.index, stored)

    def _cmd_rsap(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        axis = self._axis(req.motor)
        if req.type not in self.type.storable_axis_parameters:
            raise CommandError(Status.WRONG_TYPE)
        stored = self.eeprom.get("axis_parameters", axis.index) or {}
        value = stored.get(str(req.type), self.type.axis_parameters[req.type].default)
        axis.set_parameter(req.type, value)

    def _cmd_sgp(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        spec = self._global_spec(req.type, req.motor)
        if not spec.writable:
            raise CommandError(Status.WRONG_TYPE)
        if not spec.accepts(req.value):
            raise CommandError(Status.INVALID_VALUE)
        value = spec.normalise(req.value)
        if req.motor == 2 and self.globals[2][req.type] == value:
            self.changed = False  # a user variable written with the value it has
            return
        self.write_global(req.type, req.motor, value)

    def _cmd_ggp(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        if not self._global_spec(req.type, req.motor).readable:
            raise CommandError(Status.WRONG_TYPE)  # a setting the module keeps to itself
        return self.read_global(req.type, req.motor)

    def _storable_global(self, req: Request) -> ParamSpec:
        spec = self._global_spec(req.type, req.motor)
        if not (spec.storable or spec.auto_stored):
            raise CommandError(Status.WRONG_TYPE)
        if req.motor == 2 and req.type >= self.type.storable_user_variables:
            raise CommandError(Status.WRONG_TYPE)
        return spec

    def _cmd_stgp(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self._storable_global(req)
        section = "user_variables" if req.motor == 2 else "globals"
        self.eeprom.put(section, req.type, self.globals[req.motor][req.type])

    def _cmd_rsgp(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        spec = self._storable_global(req)
        section = "user_variables" if req.motor == 2 else "globals"
        default = 0 if req.motor == 2 else spec.default
        self.globals[req.motor][req.type] = self.eeprom.get(section, req.type, default)

