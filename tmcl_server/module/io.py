"""I/O and coordinates: SIO, GIO, and SCO, GCO, CCO, ACO with their EEPROM forms."""

from __future__ import annotations

from tmcl_server.dispatch import CommandError, Interface, ReplySink
from tmcl_server.module.core import ModuleCore
from tmcl_server.protocol import Request
from tmcl_spec.commands import MOTOR_ALL, IOBank, Status
from tmcl_spec.parameters import AP, GP


class IOCommands(ModuleCore):
    """Handlers of the I/O ports and the coordinate table."""

    def _cmd_sio(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if req.motor == IOBank.DIGITAL_INPUTS and self.type.pullup_ports:
            self._set_pullup(req)
            return
        if req.motor != IOBank.OUTPUTS:
            raise CommandError(Status.INVALID_VALUE)
        if not 0 <= req.type < self.type.outputs:
            raise CommandError(Status.WRONG_TYPE)
        if req.value not in (0, 1):
            raise CommandError(Status.INVALID_VALUE)
        if self.outputs[req.type] != req.value:
            self.outputs[req.type] = req.value
            self.emit("output_changed", None, port=req.type, level=req.value)
        else:
            self.changed = False

    def _set_pullup(self, req: Request) -> None:
        """``SIO n, 0, 0|1`` (TMC429 modules): pull-up resistors on or off.  The world gives
        switch and input levels directly, so they only are remembered (docs/modules.md)."""
        if not 0 <= req.type < self.type.pullup_ports:
            raise CommandError(Status.WRONG_TYPE)
        if req.value not in (0, 1):
            raise CommandError(Status.INVALID_VALUE)
        self.changed = self.pullups[req.type] != req.value
        self.pullups[req.type] = req.value

    def _input_count(self, bank: int) -> int:
        return (self.type.digital_inputs, self.type.analog_inputs, self.type.outputs)[bank]

    def _cmd_gio(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        if req.motor not in tuple(IOBank):
            raise CommandError(Status.INVALID_VALUE)
        if req.motor == IOBank.ANALOG_INPUTS:
            if req.type == self.type.supply_voltage_channel:
                return self.supply_voltage_reading()
            channels = self.type.analog_channels
            if channels is not None and req.type not in channels:
                raise CommandError(Status.WRONG_TYPE)
        line = req.type
        ports = self.type.input_ports
        if ports is not None and req.motor != IOBank.OUTPUTS:  # GIO numbers ports, not lines
            if line not in ports:
                raise CommandError(Status.WRONG_TYPE)
            line = ports.index(line)
        if not 0 <= line < self._input_count(req.motor):
            raise CommandError(Status.WRONG_TYPE)
        return self.read_input(line, req.motor)

    # == coordinates ===========================================================================

    def _coordinate_request(self, req: Request) -> tuple[int, int | None]:
        """Validate (coordinate, motor); motor None means the motor-255 EEPROM form."""
        if not 0 <= req.type < self.type.coordinates:
            raise CommandError(Status.WRONG_TYPE)
        if req.motor == MOTOR_ALL:
            return req.type, None
        return req.type, self._axis_index(req.motor)

    def _set_coordinate(self, number: int, motor: int, value: int) -> None:
        self.coordinates[motor][number] = value
        if number and self.globals[0][GP.COORDINATE_STORAGE] == 1:
            self._copy_coordinates_to_eeprom([number], [motor])

    def _eeprom_coordinate_range(self, number: int) -> range:
        """Motor-255 forms: 0 means all of 1..20, otherwise the one coordinate."""
        return range(1, self.type.coordinates) if number == 0 else range(number, number + 1)

    def _cmd_sco(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        number, motor = self._coordinate_request(req)
        if motor is None:
            self._copy_coordinates_to_eeprom(self._eeprom_coordinate_range(number))
        elif (self.coordinates[motor][number] == req.value
              and not (number and self.globals[0][GP.COORDINATE_STORAGE] == 1)):
            self.changed = False  # a RAM coordinate written with the value it has
        else:
            self._set_coordinate(number, motor, req.value)

    def _cmd_gco(self, req: Request, sink: ReplySink | None, interface: Interface) -> int | None:
        number, motor = self._coordinate_request(req)
        if motor is None:
            self._copy_coordinates_from_eeprom(self._eeprom_coordinate_range(number))
            return None
        self.changed = False  # a read
        return self.coordinates[motor][number]

    def _cmd_cco(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        number, motor = self._coordinate_request(req)
        if motor is None:
            raise CommandError(Status.INVALID_VALUE)
        position = self.axis(motor).get_parameter(AP.ACTUAL_POSITION)
        self._set_coordinate(number, motor, position)
        return position

    def _cmd_aco(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        number, motor = self._coordinate_request(req)
        if motor is None:
            raise CommandError(Status.INVALID_VALUE)
        self._set_coordinate(number, motor, self.accumulator)

