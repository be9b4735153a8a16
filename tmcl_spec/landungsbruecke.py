"""Trinamic's Landungsbruecke with a TMC4361A-EVAL: the evaluation setup as a module type.

The Landungsbruecke is the base board of Trinamic's evaluation system; it runs the
TMC-EvalSystem firmware and speaks TMCL on its USB port (and RS-232 / WLAN), with the
motion-controller evaluation board on channel 1 and a driver board on channel 2.  This
profile presents it with a TMC4361A-EVAL on channel 1 and no driver board, as the TMCL-IDE
and pytrinamic's ``Landungsbruecke`` / ``TMC4361_eval`` classes see it.  Sources: the public
TMC-EvalSystem firmware (v3.11, ``tmc/TMCL.c``, ``tmc/BoardAssignment.*``,
``boards/TMC4361A_eval.c``) and pytrinamic 0.2.26; what could not be confirmed is listed in
docs/tmc4361a.md ("The evaluation board").
"""

from __future__ import annotations

import dataclasses
from enum import IntEnum

from tmcl_spec.commands import Opcode, Status
from tmcl_spec.eval_boards import BoardId, EvalBoards, EvalFirmware, id_eeprom
from tmcl_spec.family import BANK0_PARAMETERS, BAUD_RATES
from tmcl_spec.modules import ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN
from tmcl_spec.parameters import AXIS, GP, SETTING, EvalGP, Motion, ParamSpec


class EvalOpcode(IntEnum):
    """Commands of the evaluation firmware that the TMCL modules do not have (or use
    otherwise: 147 reads a motion-controller register on the TMCM-6212)."""

    DRIVERS_ENABLE = 64  # UF0: all drivers on (value != 0) or off
    READ_ID_EEPROM = 65  # UF1: 4 bytes of a board's ID EEPROM (type = channel 1 or 2)
    WRITE_ID_EEPROM = 66  # UF2: 1 byte (motor field) to a board's ID EEPROM
    ASSIGNMENT = 143  # detect the boards (type 0) and report their ids
    UF_CH1 = 144  # the motion-controller board's user function (TMC4361A: switches, ...)
    WRITE_DRV = 147  # write a register of the driver board (channel 2)
    READ_MC = 148  # read a register of the motion controller (channel 1)
    READ_DRV = 149  # read a register of the driver board
    GET_INFO = 157  # firmware facts by number (module id, version, capabilities, ...)


#: TMC-EvalSystem 3.11.7 (tag 3.11.7, commit 9220279...): the release the profile answers as.
FIRMWARE_3_11_7 = EvalFirmware(patch=7, build=3117, git_info=0x0922_0279, release_type=0)

TMC4361A_EVAL = EvalBoards(
    mc_id=BoardId.TMC4361A, drv_id=BoardId.NONE,
    id_eeproms={1: id_eeprom("TMC4361A-EVAL", BoardId.TMC4361A, (1, 3))},
    hardware_id=2, firmware=FIRMWARE_3_11_7)


# -- axis parameters: the TMC4361A-EVAL firmware's (boards/TMC4361A_eval.c) -----------------

#: Accelerations (and DSTOP) are refused outside 22 bits: ``value & ~0x3FFFFF`` -> status 4.
_ACCELERATION = (0, 0x3F_FFFF)


def _p(number: int, name: str, access: str = "RW",
       limits: tuple[int, int] = (INT32_MIN, INT32_MAX), motion: Motion = SETTING) -> ParamSpec:
    """A row (``motion``: SETTING unless it reads a register the chip moves)."""
    return ParamSpec(number, name, access, limits[0], limits[1], 0, motion=motion)


#: The evaluation firmware's axis parameters (pytrinamic's ``TMC4361_eval._MotorTypeA.AP``
#: lists 0-5, 8, 14-27, 214); each is a thin view of a TMC4361A register (docs/tmc4361a.md).
AXIS_PARAMETERS: dict[int, ParamSpec] = {
    spec.number: spec
    for spec in (
        _p(0, "Target position"),  # XTARGET
        _p(1, "Actual position", motion=AXIS),  # XACTUAL
        _p(2, "Target velocity"),  # VMAX (pps, clamped to +-8 000 000)
        _p(3, "Actual velocity", "R", motion=AXIS),  # VACTUAL
        _p(4, "Maximum velocity"),  # the VMAX a move uses
        _p(5, "Maximum acceleration", limits=_ACCELERATION),  # AMAX
        _p(8, "Position reached flag", "R", motion=AXIS),  # STATUS bit 0
        _p(14, "Ramp type"),  # RAMPMODE profile: 0 trapezoid, else S-shaped
        _p(15, "Velocity VSTART"),  # VSTART (register = value / 256)
        _p(16, "Acceleration AStart", limits=_ACCELERATION),  # ASTART
        _p(17, "Maximum deceleration", limits=_ACCELERATION),  # DMAX
        _p(18, "Velocity VBreak"),  # VBREAK (register = value / 256)
        _p(19, "Deceleration DFinal", limits=_ACCELERATION),  # DFINAL
        _p(20, "Velocity VSTOP"),  # VSTOP (register = value / 256)
        _p(21, "Deceleration DStop", limits=_ACCELERATION),  # DSTOP (register = value / 4)
        _p(22, "Bow 1"),
        _p(23, "Bow 2"),
        _p(24, "Bow 3"),
        _p(25, "Bow 4"),
        _p(26, "Virtual stop left"),
        _p(27, "Virtual stop right"),
        _p(209, "Encoder position", motion=AXIS),  # ENC_POS
        _p(214, "Power down delay"),  # STDBY_DELAY (register = value * 160 000)
        _p(225, "Maximum encoder deviation"),  # ENC_POS_DEV_TOL
    )
}


# -- global parameters (tmc/TMCL.c, Get/SetGlobalParameter) ---------------------------------

def _g(number: int, name: str, access: str, lo: int = INT32_MIN, hi: int = INT32_MAX,
       default: int = 0) -> ParamSpec:
    return ParamSpec(number, name, access, lo, hi, default, motion=SETTING)


#: The housekeeping parameters the module model keeps for every module type (addresses,
#: reply delay, heartbeats, ...): fixed, and invisible on the wire (access "").  The
#: Landungsbruecke answers as module 1 to host 2 and has no such settings.
_HIDDEN = {n: dataclasses.replace(spec, access="") for n, spec in BANK0_PARAMETERS.items()}
_HIDDEN[GP.BAUD_RATE] = dataclasses.replace(_HIDDEN[GP.BAUD_RATE], default=7)  # 115 200 bps

BANK0_PARAMETERS_EVAL: dict[int, ParamSpec] = {
    **_HIDDEN,
    **{s.number: s for s in (
        _g(EvalGP.ERROR_MASK, "Vital signs error mask", "RW"),
        _g(EvalGP.DRIVERS_ENABLE, "Drivers enable", "RW", 0, 1, 1),
        _g(EvalGP.DEBUG_MODE, "Debug mode", "RW", 0, 1, 0),
        _g(EvalGP.BOARD_ASSIGNMENT, "Board assignment", "R", default=TMC4361A_EVAL.supported),
        _g(EvalGP.HARDWARE_ID, "Hardware id", "R", default=TMC4361A_EVAL.hardware_id),
    )},
}


# -- the profile -------------------------------------------------------------------------------

#: Opcodes the firmware serves (tmc/TMCL.c); the others answer status 2, as on the board.
COMMANDS = frozenset({
    Opcode.ROR, Opcode.ROL, Opcode.MST, Opcode.MVP, Opcode.SAP, Opcode.GAP, Opcode.SGP,
    Opcode.GGP, Opcode.SIO, Opcode.GIO, Opcode.GET_FIRMWARE_VERSION, Opcode.WRITE_MC,
    *EvalOpcode,
})

#: GIO types 0..4 read the Landungsbruecke's ADC inputs AIN0, AIN1, AIN2, DIO4, DIO5 (the
#: world's analogue inputs 0..4, 16 bit); 5 the supply in 0.1 V, 6 its raw ADC value.
ANALOG_INPUTS = 5

LANDUNGSBRUECKE_TMC4361A = ModuleType(
    key="landungsbruecke-tmc4361a",
    name="Landungsbruecke + TMC4361A-EVAL",
    module_number=12,  # the Landungsbruecke's MODULE_ID: version string "0012V311"
    firmware=(3, 11),
    number_of_axes=1,
    axis_parameters=AXIS_PARAMETERS,
    global_parameters={0: BANK0_PARAMETERS_EVAL},
    storable_axis_parameters=frozenset(),
    storable_user_variables=0,
    digital_inputs=0,
    analog_inputs=ANALOG_INPUTS,
    outputs=0,
    coordinates=0,
    program_memory=0,
    chip_core="tmc4361a-eval",
    commands=COMMANDS,
    baud_rates=BAUD_RATES,  # GP 65 as on the TMCL modules (inferred); no CAN
    handlers={
        # the firmware ignores the motor byte of motion commands (motor 0 moves) and answers
        # 3 for a parameter of another motor; GIO/SIO, 136 and 146/148 are its own
        Opcode.ROR: "ror_eval",
        Opcode.ROL: "rol_eval",
        Opcode.MST: "mst_eval",
        Opcode.MVP: "mvp_eval",
        Opcode.SAP: "sap_eval",
        Opcode.GAP: "gap_eval",
        Opcode.SIO: "sio_eval",
        Opcode.GIO: "gio_eval",
        Opcode.GET_FIRMWARE_VERSION: "get_version_eval",
        Opcode.WRITE_MC: "write_mc_eval",
        EvalOpcode.READ_MC: "read_mc_eval",
        EvalOpcode.UF_CH1: "user_function_ch1",
        EvalOpcode.GET_INFO: "get_info",
        EvalOpcode.DRIVERS_ENABLE: "drivers_enable",
        EvalOpcode.READ_ID_EEPROM: "read_id_eeprom",
        EvalOpcode.WRITE_ID_EEPROM: "write_id_eeprom",
        EvalOpcode.ASSIGNMENT: "board_assignment",
        EvalOpcode.WRITE_DRV: "write_drv",
        EvalOpcode.READ_DRV: "read_drv",
    },
    unknown_parameter_status=Status.INVALID_COMMAND,
    has_can=False,
    eval_boards=TMC4361A_EVAL,
)
