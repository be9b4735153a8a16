"""Is a loaded EEPROM image something this module type could have written?

``eeprom.json`` is edited by hand, copied between module types and damaged by disks; a value
the firmware would never store (an address of 0, a parameter that is a string, an instruction
past the end of program memory) must not reach the module at power-up, where it would crash
start-up or make the module unreachable.  :func:`first_problem` names the first field that
fails, the module then runs on factory defaults (docs/eeprom.md).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from tmcl_spec.modules import ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN, UINT32_MAX
from tmcl_spec.parameters import ParamSpec


class _Problem(Exception):
    """The field (dotted path) and what is wrong with it."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"field {field!r}: {reason}")


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _key(field: str, key: Any, allowed: range | Mapping[int, Any] | frozenset[int] | set[int],
         what: str) -> int:
    """A decimal string key naming one of ``allowed``."""
    if not isinstance(key, str) or not key.isascii() or not key.isdigit() or len(key) > 10:
        raise _Problem(field, f"key {key!r} is not a decimal {what}")
    number = int(key)
    if number not in allowed:
        raise _Problem(field, f"{what} {number} does not exist on this module")
    return number


def _object(field: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise _Problem(field, f"expected an object, found {type(value).__name__} {_short(value)}")
    return value


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _int32(field: str, value: Any) -> int:
    if not _is_int(value):
        raise _Problem(field, f"expected an integer, found {type(value).__name__} {_short(value)}")
    if not INT32_MIN <= value <= INT32_MAX:
        raise _Problem(field, f"{_short(value)} is not a 32-bit value")
    return value


def _parameter(field: str, value: Any, spec: ParamSpec) -> None:
    if not _is_int(value):
        raise _Problem(field, f"expected an integer, found {type(value).__name__} {_short(value)}")
    if not INT32_MIN <= value <= (UINT32_MAX if spec.unsigned else INT32_MAX):
        raise _Problem(field, f"{_short(value)} is not a 32-bit value")
    if not spec.accepts(value):
        bounds = (f"one of {sorted(spec.allowed)}" if spec.allowed is not None
                  else f"{spec.minimum}..{spec.maximum}")
        raise _Problem(field, f"{value} is outside {spec.name!r} ({bounds})")


def _check(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> None:
    """Each section in turn, in the order a problem is reported in."""
    for section in (_check_globals, _check_user_variables, _check_coordinates,
                    _check_axis_parameters, _check_program):
        section(data, kind)


def _check_globals(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> None:
    bank0 = kind.global_parameters[0]
    stored_globals = {n: spec for bank, table in kind.global_parameters.items() if bank != 2
                      for n, spec in table.items() if spec.storable or spec.auto_stored}
    for key, value in _object("globals", data.get("globals", {})).items():
        field = f"globals.{key}"
        number = _key(field, key, stored_globals, "stored global parameter")
        _parameter(field, value, bank0.get(number, stored_globals[number]))


def _check_user_variables(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> None:
    user = range(kind.storable_user_variables)
    for key, value in _object("user_variables", data.get("user_variables", {})).items():
        field = f"user_variables.{key}"
        _key(field, key, user, "storable user variable")
        _int32(field, value)


def _check_coordinates(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> None:
    axes = range(kind.number_of_axes)
    coordinates = range(1, kind.coordinates)
    for axis, row in _object("coordinates", data.get("coordinates", {})).items():
        _key(f"coordinates.{axis}", axis, axes, "axis")
        for key, value in _object(f"coordinates.{axis}", row).items():
            field = f"coordinates.{axis}.{key}"
            _key(field, key, coordinates, "coordinate")
            _int32(field, value)


def _check_axis_parameters(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> None:
    axes = range(kind.number_of_axes)
    for axis, row in _object("axis_parameters", data.get("axis_parameters", {})).items():
        _key(f"axis_parameters.{axis}", axis, axes, "axis")
        for key, value in _object(f"axis_parameters.{axis}", row).items():
            field = f"axis_parameters.{axis}.{key}"
            number = _key(field, key, kind.storable_axis_parameters, "storable axis parameter")
            _parameter(field, value, kind.axis_parameters[number])


def _check_program(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> None:
    """Each stored record: an address in program memory, [opcode, type, motor, value] with
    three bytes (the opcode not 0) and a 32-bit value."""
    memory = range(kind.program_memory)
    byte = range(256)
    for key, fields in _object("program", data.get("program", {})).items():
        field = f"program.{key}"
        _key(field, key, memory, "program memory address")
        if not isinstance(fields, list) or len(fields) != 4:
            raise _Problem(field, f"expected [opcode, type, motor, value], found {_short(fields)}")
        opcode, type_, motor, value = fields
        for name, item in (("opcode", opcode), ("type", type_), ("motor", motor)):
            if not _is_int(item) or item not in byte or (name == "opcode" and item == 0):
                raise _Problem(field, f"{name} {_short(item)} is not a byte"
                               + (" other than 0" if name == "opcode" else ""))
        _int32(field, value)


def first_problem(data: Mapping[str, Mapping[str, Any]], kind: ModuleType) -> str | None:
    """The first field of an EEPROM image this module type would never have stored, or None."""
    try:
        _check(data, kind)
    except _Problem as problem:
        return str(problem)
    return None
