"""The symbolic names of the TMCL-IDE's own include file ``TMCLParam.tmc``, as data.

A program written in the TMCL-IDE says ``#include TMCLParam.tmc`` and uses the IDE's names
(``SAP APMaxPositioningSpeed, Motor2, 1000``).  The names and their numbers are an interface
fact: Trinamic's file (public copy: ``trinamic/TMCL-IDE-Nightly``, ``TMCLParam.tmc``, added
2020-11-11, 4988 bytes) defines exactly the symbols below.  Its advanced section is headed
"for TMCM-3xx/110/61x modules"; the comments here are ours, in short.

``scripts/gen_includes.py`` writes every one of them into the include file we ship
(``interpreter/include/TMCLParam.tmc``) beside our own names (from the parameter tables),
so a program written against either file assembles; ``tests/interpreter/test_assembler.py``
assembles a program using every name here and checks each number (docs/interpreter.md).
"""

from __future__ import annotations

#: Axis numbers.
MOTORS: dict[str, int] = {f"Motor{n}": n for n in range(6)}

#: Axis parameter numbers (SAP, GAP, STAP, RSAP, AAP), in the file's order.
AXIS_PARAMETERS: dict[str, int] = {
    "APNextPosition": 0,  # target position
    "APActualPosition": 1,
    "APNextVelocity": 2,  # target speed (velocity mode)
    "APActualVelocity": 3,
    "APMaxPositioningSpeed": 4,
    "APMaxAcceleration": 5,
    "APMaxCurrent": 6,
    "APStandbyCurrent": 7,
    "APTargetPosReached": 8,
    "APRefSwitchStatus": 9,  # the reference (left) switch
    "APRightLimitSwitchStatus": 10,
    "APLeftLimitSwitchStatus": 11,  # the left switch in three-switch mode
    "APRightLimitSwitchDisable": 12,
    "APLeftLimitSwitchDisable": 13,
    "APActualAcceleration": 135,
    "APRampMode": 138,
    "APMicrostepResolution": 140,
    "APRefSwitchTolerance": 141,
    "APSnapshotPosition": 142,
    "APSoftStopFlag": 149,
    "APPositionLatchFlag": 151,
    "APRampDivisor": 153,
    "APPulseDivisor": 154,
    "APRefSearchMode": 193,
    "APRefSearchSpeed": 194,
    "APRefSwitchSpeed": 195,
    "APMixedDecay": 203,
    "APFreeWheeling": 204,
    "APStallguardThresholdLevel": 205,
    "APActualStallguardValue": 206,
    "APDriverErrorFlags": 208,
    "APEncoderPosition": 209,
    "APEncoderPredivAndFlags": 210,
    "APFullStepThreshold": 211,
    "APMaxEncoderDeviation": 212,
    "APGroupIndex": 213,
}

#: Values of some axis parameters (the file's "APV" names).
PARAMETER_VALUES: dict[str, int] = {
    "APVRefSearchOneSwitch": 1,  # APRefSearchMode
    "APVRefSearchTwoSwitches": 2,
    "APVMixedDecayPermanent": -1,  # APMixedDecay
    "APVMixedDecayOff": 2048,
    "APVRampModePosition": 0,  # APRampMode
    "APVRampModeVelocity": 2,
    "APVEncoderAddOnCCW": 1,  # flags of APEncoderPredivAndFlags
    "APVEncoderAlwaysTriggerNull": 2,
    "APVEncoderClearEncoderOnNull": 4,
    "APVEncoderHoldValueOnNull": 8,
    "APVEncoderNullActiveHigh": 16,
}

#: Every symbol of the IDE's file and its number.
SYMBOLS: dict[str, int] = {**MOTORS, **AXIS_PARAMETERS, **PARAMETER_VALUES}
