"""The module model: parameters, I/O, coordinates, EEPROM, and command dispatch.

A :class:`TMCLModule` is built from a module type (:mod:`tmcl_spec.modules`): the profile
names its tables, its I/O and the chip core of its axes; :class:`TMCM6212` is the default.
Its state and what every command shares are :class:`~tmcl_server.module.core.ModuleCore`;
the command handlers, ``_cmd_<mnemonic>``, live in files by concern (``motion.py``,
``parameters.py``, ``io.py`` for I/O and coordinates, ``control.py``, ``evaluation.py``, and
``program.py`` for standalone mode: 128-135 and program commands sent in direct mode).
:attr:`TMCLModule.COMMANDS` below is the whole opcode table in one place.  Handlers return
the reply value or raise :class:`CommandError` (tmcl_server/dispatch.py).  Motion is
delegated to the axes (axes/), programs to the interpreter (interpreter/).
"""

from __future__ import annotations

from typing import ClassVar

from axes.world import World
from tmcl_server.eeprom import Eeprom
from tmcl_server.module.control import ControlCommands
from tmcl_server.module.core import AxisFactory, HandlerFunction, ModuleCore, ModuleEvent
from tmcl_server.module.evaluation import EvaluationCommands
from tmcl_server.module.io import IOCommands
from tmcl_server.module.motion import MotionCommands
from tmcl_server.module.parameters import ParameterCommands
from tmcl_spec.commands import READ_ONLY_OPCODES, USER_FUNCTIONS, Opcode

__all__ = ["READ_ONLY_OPCODES", "TMCM6212", "ModuleCore", "ModuleEvent", "TMCLModule"]


class TMCLModule(MotionCommands, ParameterCommands, IOCommands, ControlCommands,
                 EvaluationCommands):
    """One simulated module.  Not thread-safe: the server calls it from one event loop."""

    #: The evaluation firmware's commands, by the name a profile gives them
    #: (``ModuleType.handlers``): their numbers mean other things on the TMCL modules.
    VARIANT_COMMANDS: ClassVar[dict[str, HandlerFunction]] = {
        "ror_eval": EvaluationCommands._cmd_ror_eval,
        "rol_eval": EvaluationCommands._cmd_rol_eval,
        "mst_eval": EvaluationCommands._cmd_mst_eval,
        "mvp_eval": EvaluationCommands._cmd_mvp_eval,
        "sap_eval": EvaluationCommands._cmd_sap_eval,
        "gap_eval": EvaluationCommands._cmd_gap_eval,
        "write_mc_eval": EvaluationCommands._cmd_write_mc_eval,
        "read_mc_eval": EvaluationCommands._cmd_read_mc_eval,
        "gio_eval": EvaluationCommands._cmd_gio_eval,
        "sio_eval": EvaluationCommands._cmd_sio_eval,
        "get_version_eval": EvaluationCommands._cmd_get_version_eval,
        "get_info": EvaluationCommands._cmd_get_info,
        "user_function_ch1": EvaluationCommands._cmd_user_function_ch1,
        "drivers_enable": EvaluationCommands._cmd_drivers_enable,
        "read_id_eeprom": EvaluationCommands._cmd_read_id_eeprom,
        "write_id_eeprom": EvaluationCommands._cmd_write_id_eeprom,
        "board_assignment": EvaluationCommands._cmd_board_assignment,
        "write_drv": EvaluationCommands._cmd_write_drv,
        "read_drv": EvaluationCommands._cmd_read_drv,
    }

    #: Opcode -> handler of every command the module serves itself (standalone mode's are in
    #: ProgramSupport.COMMANDS); a module type answers status 2 for opcodes it does not list.
    COMMANDS: ClassVar[dict[int, HandlerFunction]] = {
        Opcode.ROR: MotionCommands._cmd_ror,
        Opcode.ROL: MotionCommands._cmd_rol,
        Opcode.MST: MotionCommands._cmd_mst,
        Opcode.MVP: MotionCommands._cmd_mvp,
        Opcode.SAP: ParameterCommands._cmd_sap,
        Opcode.GAP: ParameterCommands._cmd_gap,
        Opcode.STAP: ParameterCommands._cmd_stap,
        Opcode.RSAP: ParameterCommands._cmd_rsap,
        Opcode.SGP: ParameterCommands._cmd_sgp,
        Opcode.GGP: ParameterCommands._cmd_ggp,
        Opcode.STGP: ParameterCommands._cmd_stgp,
        Opcode.RSGP: ParameterCommands._cmd_rsgp,
        Opcode.RFS: MotionCommands._cmd_rfs,
        Opcode.SIO: IOCommands._cmd_sio,
        Opcode.GIO: IOCommands._cmd_gio,
        Opcode.SCO: IOCommands._cmd_sco,
        Opcode.GCO: IOCommands._cmd_gco,
        Opcode.CCO: IOCommands._cmd_cco,
        Opcode.ACO: IOCommands._cmd_aco,
        **dict.fromkeys(USER_FUNCTIONS, ControlCommands._cmd_user_function),
        Opcode.GET_FIRMWARE_VERSION: ControlCommands._cmd_get_firmware_version,
        Opcode.RESTORE_FACTORY_SETTINGS: ControlCommands._cmd_restore_factory_settings,
        Opcode.TARGET_REACHED_EVENT: MotionCommands._cmd_target_reached_event,
        Opcode.WRITE_MC: ControlCommands._cmd_write_mc,
        Opcode.READ_MC: ControlCommands._cmd_read_mc,
        Opcode.READ_MC_PYTRINAMIC: ControlCommands._cmd_read_mc,  # what pytrinamic's read_mc sends
    }


class TMCM6212(TMCLModule):
    """The default module: a TMCM-6212 (firmware V1.05) on TMC4210 cores."""

    def __init__(self, slot: int = 1, eeprom: Eeprom | None = None,
                 axis_factory: AxisFactory | None = None, start_ns: int = 0,
                 world: World | None = None) -> None:
        super().__init__(slot, eeprom, axis_factory, start_ns, world, "tmcm-6212")
