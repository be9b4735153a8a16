"""Turn ``sim/...`` messages (MQTT) into changes of the simulated world.

    sim/input/<n>                 1/0/true/false (digital) or {"analog": 0..65535}
    sim/switch/<axis>/<name>      name = left | right | home
                                  1/0/true/false: hold the switch at that level wherever the
                                  axis is; {"position": p, "width": w, "side": s,
                                  "normally_closed": b}: place it; null: remove it
    sim/load/<axis>               0..1023 (the load value everywhere), or
                                  {"free": v, "zones": [[from, to, load], ...]}
    sim/encoder_slip/<axis>       0.0..1.0
    sim/supply                    the supply voltage in volts (GIO 8, 1 reads it in 0.1 V)

docs/mqtt.md and docs/world.md describe the units (positions are mechanical positions).
"""

from __future__ import annotations

from typing import Any

from axes.world import LOAD_MAX, SWITCH_NAMES
from tmcl_server.module import TMCLModule
from tmcl_server.transports.mqtt.payload import PayloadError, decode_text, parse_json

#: Positions are mechanical microsteps; this bounds them far beyond any travel.
POSITION_LIMIT = 2**62

_SWITCH_FIELDS = {"position", "width", "side", "normally_closed"}


class WorldTopicError(ValueError):
    """A ``sim/`` message that names nothing the simulator has, or carries a bad value."""


def _parse(payload: bytes) -> Any:
    try:
        text = decode_text(payload)
    except PayloadError as exc:
        raise WorldTopicError(str(exc)) from None
    lowered = text.lower()
    if lowered in ("on", "high", "active"):
        return True
    if lowered in ("off", "low", "inactive"):
        return False
    try:
        return parse_json(text)
    except PayloadError as exc:
        raise WorldTopicError(f"cannot read value {_short(text)}: {exc}") from None


def _short(text: str) -> str:
    return repr(text) if len(text) <= 40 else repr(text[:37] + "...")


def _index(text: str, what: str, count: int) -> int:
    if not text.isdigit() or not 0 <= int(text) < count:
        raise WorldTopicError(f"{what} must be 0..{count - 1}, got {text!r}")
    return int(text)


def _level(value: Any) -> bool:
    if isinstance(value, bool) or value in (0, 1):
        return bool(value)
    raise WorldTopicError(f"expected 0/1 or true/false, got {value!r}")


def _integer(value: Any, what: str, lo: int, hi: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise WorldTopicError(f"{what} must be an integer {lo}..{hi}, got {value!r}")
    return value


def _input(module: TMCLModule, port: int, value: Any) -> None:
    if isinstance(value, dict) and set(value) == {"analog"}:
        module.set_analog_input(port, _integer(value["analog"], "analog value", 0,
                                                       module.type.analog_full_scale))
    else:
        module.set_digital_input(port, _level(value))


def _switch(module: TMCLModule, axis: int, name: str, value: Any) -> None:
    if name not in SWITCH_NAMES:
        raise WorldTopicError(f"switch must be one of {', '.join(SWITCH_NAMES)}, got {name!r}")
    if value is None:
        module.set_switch(axis, name, None)
    elif isinstance(value, dict):
        unknown = set(value) - _SWITCH_FIELDS
        if unknown or "position" not in value:
            raise WorldTopicError(f"a switch placement needs position (and may have width, "
                                  f"side, normally_closed); got {sorted(value)}")
        width = value.get("width")
        side = value.get("side")
        if side is not None and not isinstance(side, str):
            raise WorldTopicError(f"side must be a string, got {side!r}")
        module.set_switch(axis, name,
                          _integer(value["position"], "position", -POSITION_LIMIT, POSITION_LIMIT),
                          None if width is None else _integer(width, "width", 0, POSITION_LIMIT),
                          side, _level(value.get("normally_closed", False)))
    else:
        module.force_switch(axis, name, _level(value))


def _load(module: TMCLModule, axis: int, value: Any) -> None:
    if isinstance(value, dict):
        zones = value.get("zones", [])
        if not isinstance(zones, list) or not all(
                isinstance(z, list) and len(z) == 3 for z in zones):
            raise WorldTopicError("zones must be a list of [from, to, load]")
        free = value.get("free")
        module.set_load(axis, [(_integer(a, "zone start", -POSITION_LIMIT, POSITION_LIMIT),
                                _integer(b, "zone end", -POSITION_LIMIT, POSITION_LIMIT),
                                _integer(c, "load", 0, LOAD_MAX)) for a, b, c in zones],
                        None if free is None else _integer(free, "load", 0, LOAD_MAX))
    else:
        module.set_load(axis, [], _integer(value, "load", 0, LOAD_MAX))


def _slip(module: TMCLModule, axis: int, value: Any) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 <= value <= 1:
        raise WorldTopicError(f"encoder slip must be a number 0..1, got {value!r}")
    module.set_encoder_slip(axis, float(value))


def apply_sim_message(module: TMCLModule, path: list[str], payload: bytes) -> None:
    value = _parse(payload)
    try:
        match path:
            case ["input", port]:
                _input(module, _index(port, "input", len(module.analog_inputs)), value)
            case ["switch", axis, name]:
                _switch(module, _index(axis, "axis", len(module.axes)), name, value)
            case ["load", axis]:
                _load(module, _index(axis, "axis", len(module.axes)), value)
            case ["encoder_slip", axis]:
                _slip(module, _index(axis, "axis", len(module.axes)), value)
            case ["supply"]:
                if isinstance(value, bool) or not isinstance(value, int | float):
                    raise WorldTopicError(f"supply voltage must be a number, got {value!r}")
                module.set_supply_voltage(value)
            case _:
                raise WorldTopicError(f"unknown sim topic {'/'.join(path)!r}")
    except (ValueError, TypeError) as exc:
        if isinstance(exc, WorldTopicError):
            raise
        raise WorldTopicError(str(exc)) from exc
