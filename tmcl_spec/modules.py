"""Module types: what distinguishes one TMCL module from another, as data.

A :class:`ModuleType` (a *profile*) names a module's tables, its I/O, its firmware identity
and the motion-controller core its axes run on.  The module model (``tmcl_server.module``)
is built from a profile, so a new module type is a new profile file, not a copy of the model.

Profiles are found by name (``tmcm-6212``); each lives in its own file and is imported only
when asked for.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from tmcl_spec.eval_boards import EvalBoards
from tmcl_spec.parameters import ParamSpec
from tmcl_spec.registry import resolve


@dataclass(frozen=True)
class FirmwareClock:
    """What a module's firmware does on its own clock besides serving commands: the pass its
    main loop makes over the axes (``SystemControl`` in Trinamic's open TMCL firmware,
    TMCL-LITE-1110 and TMCL-LITE-1111 ``SysControl.c``), which ``axes/tasks.py`` runs.  The
    evidence for every field is in docs/motion.md, "The firmware's own clock"."""

    #: The pass runs once more than 10 ticks of the 1 ms system timer went by since the last
    #: one (TMCL-LITE-1110 SysControl.c line 57, ``abs(GetSysTimer()-Delay)>10``): every 11 ms.
    pass_ms: int = 11
    #: Each pass serves one axis, the next one in turn (SysControl.c lines 133-135): an axis
    #: of a module with n axes has its pass every n x ``pass_ms``.
    one_axis_per_pass: bool = True
    #: The pass switches the motor current: AP 7 after AP 214 at rest, AP 183 below the
    #: AP 182 speed, else AP 6 (SysControl.c lines 61-81).  False: the motion controller
    #: switches it (the TMC4361's STDBY_DELAY, TMCL-LITE-1111 Commands.c lines 1048-1050):
    #: exactly AP 214 after the motor stopped, and back at once when it moves.
    current_in_pass: bool = True
    #: The pass switches coolStep on at or above the AP 182 speed and off below it
    #: (SysControl.c lines 83-101).  False: coolStep is on whenever AP 172 > 0 (TMCL-LITE-1111
    #: stores AP 182 and leaves the driver alone).
    coolstep_by_speed: bool = True
    #: The pass checks the motor driver's stall output (SysControl.c lines 106-114).  False:
    #: the firmware samples stallGuard every millisecond, and stops at once where the load
    #: under the motor reads 0.
    stall_in_pass: bool = False


@dataclass(frozen=True)
class ModuleType:
    key: str  # the name users choose it by, e.g. "tmcm-6212"
    name: str  # as printed on the module, e.g. "TMCM-6212"
    module_number: int  # command 136 type 1, high 16 bits
    firmware: tuple[int, int]  # (major, minor)
    number_of_axes: int
    axis_parameters: Mapping[int, ParamSpec]
    #: bank -> number -> row (banks 0, 2, 3 on the TMCM-6212).
    global_parameters: Mapping[int, Mapping[int, ParamSpec]]
    #: Axis parameters STAP/RSAP store and restore.
    storable_axis_parameters: frozenset[int]
    #: User variables 0..n-1 can be stored with STGP.
    storable_user_variables: int
    digital_inputs: int
    analog_inputs: int
    outputs: int
    coordinates: int
    program_memory: int  # TMCL commands the program memory holds
    #: The motion-controller core that drives the axes (a name from ``axes.cores``).
    chip_core: str
    #: The opcodes the firmware knows; others answer status 2.
    commands: frozenset[int]
    #: Input lines whose analogue value ``GIO n, 1`` reads (None: every input line).
    analog_channels: frozenset[int] | None = None
    #: The GIO port of each input line, in order (None: line n is port n).  The world file,
    #: the run-time API, WAIT and the input interrupts number the lines; GIO the ports.
    input_ports: tuple[int, ...] | None = None
    #: ``SIO n, 0, 0|1`` switches pull-up resistors n = 0..pullup_ports-1 (0: no such bank).
    pullup_ports: int = 0
    #: Full scale of an analogue input reading, and where its digital reading switches.
    analog_full_scale: int = 65535
    digital_threshold: int = 32768
    #: Analogue (bank 1) channel of the supply-voltage monitor, None if the module has none.
    supply_voltage_channel: int | None = None
    #: Readings of that channel per volt (10: units of 0.1 V).
    supply_voltage_per_volt: int = 10
    #: The supply voltage (V) when the world file does not say.
    nominal_supply_voltage: float = 24.0
    #: Counts per motor revolution of the encoder behind AP 209 when the world file does not
    #: say: a built-in one (the sensOstep's 1024), or what the firmware expects by default;
    #: None: the world file's default (51200).
    encoder_counts_per_rev: int | None = None
    #: Opcodes this module type serves with a handler of its own instead of the standard
    #: one (opcode -> a name in ``TMCLModule.VARIANT_COMMANDS``): commands whose number
    #: means something else on other modules (the evaluation firmware's 147, UF0..UF2).
    handlers: Mapping[int, str] = dataclasses.field(default_factory=dict)
    #: Reply status for an axis parameter the firmware does not serve (unknown, or written
    #: while read-only): 3 on the TMCL modules, 2 on the evaluation firmware.
    unknown_parameter_status: int = 3
    #: Whether the module has a CAN interface (it ignores the CAN bus if not).
    has_can: bool = True
    #: GP 65 (serial baud rate): value -> bits per second.
    baud_rates: Mapping[int, int] = dataclasses.field(default_factory=dict)
    #: GP 69 (CAN bit rate): value -> bits per second.
    can_bit_rates: Mapping[int, int] = dataclasses.field(default_factory=dict)
    #: Evaluation system only: the boards on the base board (tmcl_spec/landungsbruecke.py).
    eval_boards: EvalBoards | None = None
    #: The periodic pass of the firmware's main loop over the axes (:class:`FirmwareClock`).
    firmware_clock: FirmwareClock = FirmwareClock()

    def __post_init__(self) -> None:
        """Every row says how its value moves (ParamSpec.motion): loop skipping reads it, and
        a row that does not say is an error here, at import, never taken as steady."""
        tables = {"axis parameter": self.axis_parameters,
                  **{f"bank {bank} parameter": rows
                     for bank, rows in self.global_parameters.items()}}
        for kind, rows in tables.items():
            unsaid = sorted(n for n, spec in rows.items() if spec.motion is None)
            if unsaid:
                raise ValueError(f"module type {self.key}: {kind}s {unsaid} say nothing of how "
                                 f"their values move (ParamSpec.motion)")

    @property
    def version_string(self) -> bytes:
        """Command 136 type 0: e.g. ``6212V105``."""
        major, minor = self.firmware
        return f"{self.module_number:04d}V{major}{minor:02d}".encode()

    @property
    def version_number(self) -> int:
        """Command 136 type 1: module number, major and minor version in one value."""
        major, minor = self.firmware
        return self.module_number << 16 | major << 8 | minor


#: Profile name -> "module:attribute" where it is defined (imported on first use).
MODULE_TYPES: dict[str, str] = {
    "tmcm-6212": "tmcl_spec.tmcm6212:TMCM_6212",
    "tmcm-1110": "tmcl_spec.tmc429_modules:TMCM_1110",
    "tmcm-3110": "tmcl_spec.tmc429_modules:TMCM_3110",
    "tmcm-6110": "tmcl_spec.tmc429_modules:TMCM_6110",
    "tmcm-1140": "tmcl_spec.tmc429_modules:TMCM_1140",
    "tmcm-1141": "tmcl_spec.tmc429_modules:TMCM_1141",
    "tmcm-1160": "tmcl_spec.tmc429_modules:TMCM_1160",
    "tmcm-1161": "tmcl_spec.tmc429_modules:TMCM_1161",
    "tmcm-1111": "tmcl_spec.tmcm1111:TMCM_1111",
    "landungsbruecke-tmc4361a": "tmcl_spec.landungsbruecke:LANDUNGSBRUECKE_TMC4361A",
}
DEFAULT_MODULE_TYPE = "tmcm-6212"


def module_type(key: str = DEFAULT_MODULE_TYPE) -> ModuleType:
    """The profile called ``key``; ValueError naming the known ones if there is none."""
    return resolve(MODULE_TYPES, key, "module type")
