"""Checks of a module type against pytrinamic's class for it, shared by the module tests."""

from __future__ import annotations

from typing import Any

from tmcl_spec.commands import Opcode
from tmcl_spec.modules import ModuleType
from tmcl_spec.parameters import AP

#: Rows a class lists that the check does not write: positions, speeds being commanded.
_NOT_WRITTEN = (AP.TARGET_POSITION, AP.ACTUAL_POSITION, AP.TARGET_SPEED, AP.ENCODER_POSITION)


def names(cls: type) -> dict[str, int]:
    """A pytrinamic parameter class's names -> numbers."""
    return {name: value for name, value in vars(cls).items() if not name.startswith("_")}


def writable_value(spec: Any) -> int:
    """A value a row takes that differs from most defaults: its largest."""
    return max(spec.allowed) if spec.allowed else spec.maximum


def check_identity_and_parameters(iface: Any, module: Any, profile: ModuleType,
                                  version: str) -> None:
    """The version string and number, one motor per axis, every axis parameter the class
    names read within its range (and the settings written and read back), every bank 0
    parameter it names readable and every bank 3 one 0."""
    assert iface.get_version_string() == version
    assert iface.send(Opcode.GET_FIRMWARE_VERSION, 1, 0, 0).value == profile.version_number
    assert len(module.motors) == profile.number_of_axes
    for motor in module.motors:
        for name, number in names(motor.AP).items():
            value = motor.get_axis_parameter(number, signed=True)
            spec = profile.axis_parameters[number]
            assert spec.readable and spec.minimum <= value <= spec.maximum, name
            if spec.writable and number not in _NOT_WRITTEN:
                motor.set_axis_parameter(number, writable_value(spec))
                assert motor.get_axis_parameter(number, signed=True) == writable_value(spec), name
                motor.set_axis_parameter(number, value)
    for number in names(module.GP0).values():
        iface.get_global_parameter(number, 0)  # raises unless the firmware has it
    for name, number in names(module.GP3).items():
        assert iface.get_global_parameter(number, 3) == 0, name
