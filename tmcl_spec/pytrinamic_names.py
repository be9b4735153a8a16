"""pytrinamic's parameter names, accepted wherever a parameter name is (``tmcl send``,
``tmcl watch``, a fault's ``type=``): ``tmcl send GAP MaxVelocity 0`` is AP 4.

pytrinamic's users know a parameter by the attribute its module class gives it
(``TMCM6212._MotorTypeA.AP.MaxVelocity``, ``TMCM6212.GP0.SerialBaudRate``), not by the
manual's wording the tables keep and the traces print (``MaxPositioningSpeed``).  The tables
here list, by parameter number, the names pytrinamic uses where they are not already ours;
the lookup (:class:`tmcl_spec.names.ParameterNames`) is case-insensitive, so one spelling of
each is enough, and a module accepts a name only for a number its own tables have.  Our own
names win where both exist.  These are kept apart from the parameter tables on purpose: the
tables' rows are the manual's, these are one library's vocabulary.

Evidence (pytrinamic 0.2.26, github.com/analogdevicesinc/PyTrinamic): the ``AP``, ``GP0`` and
``GP3`` classes of ``pytrinamic/modules/TMCM6212.py``, ``TMCM1110.py``, ``TMCM3110.py``,
``TMCM6110.py``, ``TMCM1140.py``, ``TMCM1141.py``, ``TMCM1160.py``, ``TMCM1161.py`` (the TMCM-6212
and the TMC429 modules: one family, whose classes agree wherever they share a name),
``TMCM1111.py`` (its own numbering: ``StartVelocity`` is AP 15 there), and for the TMC4361A
evaluation board ``pytrinamic/evalboards/TMC4361_eval.py`` (``AP``) with
``pytrinamic/modules/Landungsbruecke.py`` (``GP``).  ``RunCurrent``: the newer classes' name for
AP 6 (``TMCM6214.py``: ``RunCurrent = MaxCurrent``; ``features/current_module.py`` sets the run
current through it).  tests/tmcl_server/test_pytrinamic_names.py checks every name of the
installed pytrinamic's classes against these tables.  Names for numbers a module does not
have (the TMCM6212 class's ``PWMScale``, AP 189, which firmware V1.05 lacks) stay unknown.
One name is left out on purpose: ``TMCM1111.py`` calls AP 176 ``SlopeControlHighSide`` and has
no low side, where the family (and its own ``TMCM1140.py``) has 175 high and 176 low, as our
TMCM-1111 table does; the table's ``SlopeControlHighSide`` (175) stands.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

Names = Mapping[int, tuple[str, ...]]

_FAMILY_AXIS: Names = {
    2: ("TargetVelocity",), 3: ("ActualVelocity",), 4: ("MaxVelocity",),
    6: ("MaxCurrent", "RunCurrent"), 8: ("PositionReachedFlag",), 9: ("HomeSwitch",),
    10: ("RightEndstop",), 11: ("LeftEndstop",), 15: ("A1",), 16: ("V1",), 18: ("D1",),
    19: ("StartVelocity",), 20: ("StopVelocity",), 22: ("HighSpeedThreshold",),
    23: ("MinDcStepSpeed",), 26: ("SoftStop",), 130: ("MinimumSpeed",), 138: ("RampType",),
    141: ("Ref_SwitchTolerance",), 150: ("EndSwitchPowerDown",), 160: ("Intpol",),
    161: ("DoubleEdgeSteps",), 163: ("ConstantTOffMode",), 164: ("DisableFastDecayComparator",),
    167: ("TOff",), 168: ("SEIMIN",), 169: ("SECDS",), 171: ("SECUS",),
    173: ("SG2FilterEnable",), 174: ("SG2Threshold",), 177: ("ShortToGroundProtection",),
    178: ("ShortDetectionTime",), 181: ("SmartEnergyStallVelocity",), 187: ("PWMGrad",),
    196: ("ReferenceSwitchDistance",), 197: ("LastReferenceSwitchPosition",),
    202: ("FullstepResolution",), 206: ("LoadValue",), 207: ("ErrorFlags",),
    208: ("StatusFlags", "DrvStatusFlags"), 210: ("EncoderResolution", "EncoderClearOnNull"),
    212: ("max_EncoderDeviation",), 218: ("ExternalEncoderMax_Deviation",),
    254: ("Step_DirectionMode",),
}
_FAMILY_BANK_0: Names = {
    65: ("SerialBaudRate",), 68: ("SerialHearbeat",), 70: ("CANSendId",), 71: ("CANReceiveId",),
    79: ("limitSwitchPolarity",), 81: ("protectionMode",), 84: ("eepromCoordinateStore",),
    85: ("zeroUserVariables",), 128: ("ApplicationStatus",), 130: ("ProgramCounter",),
    132: ("TickTimer",),
}
#: Bank 3, the interrupt vectors: timer_0..2, stopLeft_/stopRight_ of each axis, input_0..7.
_FAMILY_BANK_3: Names = {
    **{n: (f"timer_{n}",) for n in range(3)},
    **{27 + 2 * axis: (f"stopLeft_{axis}",) for axis in range(6)},
    **{28 + 2 * axis: (f"stopRight_{axis}",) for axis in range(6)},
    **{39 + n: (f"input_{n}",) for n in range(8)},
}
_TMCM_1111_AXIS: Names = {
    2: ("TargetVelocity",), 3: ("ActualVelocity",), 9: ("HomeSwitch",), 10: ("RightEndstop",),
    11: ("LeftEndstop",), 12: ("RightLimit",), 13: ("LeftLimit",), 34: ("EnableSoftStop",),
    50: ("TorqueMode",), 108: ("CLgammaVmin",), 109: ("CLgammaVmax",), 110: ("CLmaximumGamma",),
    111: ("CLbeta",), 112: ("CLoffset",), 113: ("CLcurrentMin",), 114: ("CLcurrentMax",),
    115: ("CLcorrectionVelocityP",), 116: ("CLcorrectionVelocityI",),
    117: ("CLcorrectionVelocityIClipping",), 118: ("CLcorrectionVelocityDVClock",),
    119: ("CLcorrectionVelocityDVClipping",), 120: ("CLupscaleDelay",),
    121: ("CLdownscaleDelay",), 124: ("CLcorrectionPositionP",),
    125: ("CLmaxCorrectionTolerance",), 126: ("CLstartUp",), 136: ("EncMeanWait",),
    137: ("EncMeanFilter",), 138: ("EncMeanInt",), 163: ("ConstantTOffMode",),
    164: ("DisableFastDecayComparator",), 167: ("TOff",), 168: ("SEIMIN",), 169: ("SECDS",),
    171: ("SECUS",), 173: ("SG2FilterEnable",), 174: ("SG2Threshold",),
    177: ("ShortToGroundProtection",),
    178: ("ShortDetectionTime",), 181: ("SmartEnergyStallVelocity",), 195: ("RefSwitchSpeed",),
    196: ("RightLimitSwitchPosition",), 206: ("LoadValue",), 208: ("StatusFlags",),
}
_TMCM_1111_BANK_0: Names = {
    **{n: names for n, names in _FAMILY_BANK_0.items() if n in (65, 68, 70, 71, 84, 85, 128, 130, 132)},
    78: ("IOMask",),
}
_TMCM_1111_BANK_3: Names = {n: names for n, names in _FAMILY_BANK_3.items() if n <= 28 or 39 <= n <= 45}
_EVALUATION_AXIS: Names = {
    15: ("StartVelocity",), 16: ("AStart",), 18: ("VBreak",), 19: ("DFinal",),
    20: ("StopVelocity",), 21: ("DSTOP",),
}
_EVALUATION_BANK_0: Names = {5: ("HWID",)}


@dataclass(frozen=True)
class PytrinamicNames:
    """One module type's pytrinamic names: its axis parameters, and its global ones by bank."""

    axis: Names
    banks: Mapping[int, Names]


_FAMILY = PytrinamicNames(_FAMILY_AXIS, {0: _FAMILY_BANK_0, 3: _FAMILY_BANK_3})
_NONE = PytrinamicNames({}, {})

#: Module type key (tmcl_spec.modules.MODULE_TYPES) -> pytrinamic's names for it.
PYTRINAMIC_NAMES: dict[str, PytrinamicNames] = {
    **dict.fromkeys(("tmcm-6212", "tmcm-1110", "tmcm-3110", "tmcm-6110", "tmcm-1140", "tmcm-1141",
                     "tmcm-1160", "tmcm-1161"), _FAMILY),
    "tmcm-1111": PytrinamicNames(_TMCM_1111_AXIS, {0: _TMCM_1111_BANK_0, 3: _TMCM_1111_BANK_3}),
    "landungsbruecke-tmc4361a": PytrinamicNames(_EVALUATION_AXIS, {0: _EVALUATION_BANK_0}),
}


def pytrinamic_names(key: str) -> PytrinamicNames:
    """pytrinamic's names for the module type ``key`` (none for a type it has no class for)."""
    return PYTRINAMIC_NAMES.get(key, _NONE)
