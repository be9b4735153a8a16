"""The evaluation system's own commands (tmcl_spec/landungsbruecke.py, docs/tmc4361a.md): its
motion commands and parameters (the motor byte handled as the firmware does), GIO/SIO, 136,
GetInfo (157), the board's user function (144), UF0..UF2, board assignment (143) and the
registers (146/148, 147/149).  A module type assigns them to opcodes by name in its profile
(``ModuleType.handlers``).  Sources: TMC-EvalSystem 3.11.7, ``tmc/TMCL.c`` and
``boards/TMC4361A_eval.c``."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from axes.interface import Axis
from tmcl_server.dispatch import CommandError, Interface, ReplySink
from tmcl_server.module.control import ControlCommands
from tmcl_server.module.core import ModuleCore
from tmcl_server.module.parameters import ParameterCommands
from tmcl_server.protocol import RawReply, Request
from tmcl_spec.commands import MoveType, Status
from tmcl_spec.eval_boards import EvalBoards, EvalError, reply_status
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import AP, EvalGP

#: GIO: the supply voltage in 0.1 V (VitalSignsMonitor.VM) and its raw ADC value.
GIO_SUPPLY = 5
GIO_SUPPLY_RAW = 6
#: GIO 7 reads AIN_EXT, an input of the LandungsbrueckeV3 only (docs/tmc4361a.md).
GIO_AIN_EXT = 7
#: Command 136 types beyond the version (``tmc/TMCL.h``).
VERSION_BOARD_DETECT_SRC = 4
VERSION_BUILD = 5
NUMBER_OF_MOTORS = 6


@runtime_checkable
class BoardUserFunction(Protocol):
    """An axis whose board has the firmware's user function (command 144)."""

    def user_function(self, type_: int, value: int) -> tuple[int, int]:
        """(the board's error bits, the reply value)."""
        ...


class EvaluationCommands(ModuleCore):
    """Handlers whose opcodes mean something else on the TMCL modules."""

    def _eval_boards(self) -> EvalBoards:
        boards = self.type.eval_boards
        if boards is None:  # a profile that assigns these handlers names its boards
            raise CommandError(Status.INVALID_COMMAND)
        return boards

    def _board_axis(self) -> Axis:
        """The motion-controller board's motor: the firmware's functions ignore the motor
        byte (``UNUSED(motor)``), so every motor number means motor 0."""
        return self.axis(0)

    # == motion and parameters: the motor byte ==================================================

    def _cmd_ror_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        """ROR/ROL/MST: ``rotate()`` ignores the motor: any motor byte moves motor 0."""
        self._board_axis().rotate(req.value)

    def _cmd_rol_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self._board_axis().rotate(to_int32(-req.value))

    def _cmd_mst_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self._board_axis().stop()

    def _cmd_mvp_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> int | None:
        """MVP on the evaluation firmware: ABS, or REL from XACTUAL (the reply carries the
        absolute target), motor byte ignored; no coordinates (type 2: the dummy channels'
        status 2) and nothing else (3)."""
        if req.type == MoveType.COORD:
            raise CommandError(Status.INVALID_COMMAND)
        if req.type not in (MoveType.ABS, MoveType.REL):
            raise CommandError(Status.WRONG_TYPE)
        axis = self._board_axis()
        if req.type == MoveType.ABS:
            axis.move_to(req.value)
            return None
        target = to_int32(axis.get_parameter(AP.ACTUAL_POSITION) + req.value)
        axis.move_to(target)
        return target

    def _board_motor(self, req: Request) -> None:
        """GAP/SAP check the motor before the type: one beyond the board's answers 3 (the
        firmware maps its motor error to REPLY_INVALID_TYPE)."""
        if not 0 <= req.motor < len(self.axes):
            raise CommandError(reply_status(EvalError.MOTOR))

    def _cmd_sap_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self._board_motor(req)
        ParameterCommands._cmd_sap(self, req, sink, interface)  # type: ignore[arg-type]

    def _cmd_gap_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        self._board_motor(req)
        return ParameterCommands._cmd_gap(self, req, sink, interface)  # type: ignore[arg-type]

    # == registers (146 / 148) ===================================================================

    def _cmd_write_mc_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        """146: ``writeRegister(motor & 0x0F, (motor >> 4) << 8 | type)``; the board drops the
        motor and cuts the address to 8 bits, and the SPI frame to 7: register ``type & 0x7F``."""
        self._board_axis().register_access(req.type & 0x7F, req.value)

    def _cmd_read_mc_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        """148: the register ``type & 0x7F``, whatever the motor byte (as 146)."""
        return self._board_axis().register_access(req.type & 0x7F)

    # == I/O: the Landungsbruecke's own ===========================================================

    def _cmd_gio_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        """GIO by type, bank ignored (no board on either channel serves GIO): 0..4 the ADC
        inputs AIN0..AIN2, DIO4, DIO5, 5 the supply in 0.1 V, 6 its raw ADC value, 7 AIN_EXT."""
        firmware = self._eval_boards().firmware
        if req.type < self.type.analog_inputs:
            return self.analog_inputs[req.type]
        raw = self._supply_adc()
        if req.type == GIO_SUPPLY:
            return raw * firmware.vm_factor // firmware.adc_full_scale
        if req.type == GIO_SUPPLY_RAW:
            return raw
        if req.type == GIO_AIN_EXT:
            return 0  # not an input of this base board (docs/tmc4361a.md)
        raise CommandError(Status.WRONG_TYPE)

    def _supply_adc(self) -> int:
        """The VM divider's ADC count: the lowest count the firmware's scaling (``checkVM``:
        count * 713 / 65535, truncated) turns into the supply's 0.1 V value, so GIO 5 reads
        the voltage, rounded to 0.1 V (up to 71.3 V, the ADC's limit)."""
        firmware = self._eval_boards().firmware
        tenths = round(self.supply_voltage * 10)
        count = -(-tenths * firmware.adc_full_scale // firmware.vm_factor)
        return min(count, firmware.adc_full_scale)

    def _cmd_sio_eval(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        """SIO: the firmware passes it to the boards, none of which has outputs: nothing
        happens, status 100 (the TMCL-IDE sets Landungsbruecke pins with SGP 6 instead)."""

    # == identity ================================================================================

    def _cmd_get_version_eval(self, req: Request, sink: ReplySink | None,
                              interface: Interface) -> RawReply | int | None:
        """136: 0 the string, 1 the binary version (as every module); 4 how the boards were
        found (bytes 2..3 keep the request's); 5 the build number; 6 the number of motors;
        other types have no branch: status 100 and the request's value."""
        boards = self._eval_boards()
        if req.type in (0, 1):
            return ControlCommands._cmd_get_firmware_version(self, req, sink, interface)  # type: ignore[arg-type]
        if req.type == VERSION_BOARD_DETECT_SRC:
            return to_int32(req.value & 0xFFFF_0000 | boards.detected_by(2) << 8
                            | boards.detected_by(1))
        if req.type == VERSION_BUILD:
            return boards.firmware.build
        if req.type == NUMBER_OF_MOTORS:
            return len(self.axes)
        return None

    def _cmd_get_info(self, req: Request, sink: ReplySink | None, interface: Interface) -> int:
        """157 (GetInfo), motor ignored: 0 module id, 1 version (bytes 3 and 1 keep the
        request's), 2 capabilities, 3 release type, 20/21 parameter and register address
        widths, 30 git version, 200 patch, 201 the boards' ids, 202 their hardware versions."""
        boards = self._eval_boards()
        firmware = boards.firmware
        major, minor = self.type.firmware
        match req.type:
            case 0:
                return self.type.module_number
            case 1:
                return to_int32(req.value & 0xFF00_FF00 | major << 16 | minor)
            case 2:
                return firmware.capabilities
            case 3:
                return firmware.release_type
            case 20:
                return 8  # axis parameter numbers: 8 bits
            case 21:
                return 12  # register addresses: 12 bits (146/148's extended address)
            case 30:
                return firmware.git_info
            case 200:
                return firmware.patch
            case 201:
                return boards.mc_id << 16 | boards.drv_id
            case 202:
                (mc_major, mc_minor), (drv_major, drv_minor) = (boards.hardware_version(1),
                                                                boards.hardware_version(2))
                return to_int32(mc_major << 24 | mc_minor << 16 | drv_major << 8 | drv_minor)
        raise CommandError(Status.WRONG_TYPE)

    # == the motion-controller board's user function (144) =======================================

    def _cmd_user_function_ch1(self, req: Request, sink: ReplySink | None,
                               interface: Interface) -> int:
        """144 (TMCL_UF_CH1): the board's user function, the motor byte ignored; on the
        TMC4361A-EVAL the simulated STOP_R/STOP_L/HOME_REF/FREEZE lines, the closed-loop
        calibration and the boards' reset (axes/chips/tmc4361a/eval_board.py)."""
        axis = self._board_axis()
        if not isinstance(axis, BoardUserFunction):  # a channel without one: the dummy's
            raise CommandError(reply_status(EvalError.FUNCTION))
        errors, value = axis.user_function(req.type, req.value)
        status = reply_status(errors)
        if status != Status.OK:
            raise CommandError(status, value)
        return value

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

