"""Turn ``sim/...`` messages (MQTT) into changes of the simulated world.

    sim/input/<n>           "1"/"0"/true/false (digital) or {"analog": 0..65535}
"""

from __future__ import annotations

import json
from typing import Any

from tmcl_server.module import TMCM6212


class WorldTopicError(ValueError):
    """A ``sim/`` message that names nothing the simulator has, or carries a bad value."""


def _parse(payload: bytes) -> Any:
    text = payload.decode(errors="replace").strip()
    try:
        return json.loads(text)
    except ValueError:
        lowered = text.lower()
        if lowered in ("on", "high", "active"):
            return True
        if lowered in ("off", "low", "inactive"):
            return False
        raise WorldTopicError(f"cannot read value {text!r}") from None


def _index(text: str, what: str, count: int) -> int:
    if not text.isdigit() or not 0 <= int(text) < count:
        raise WorldTopicError(f"{what} must be 0..{count - 1}, got {text!r}")
    return int(text)


def _level(value: Any) -> bool:
    if isinstance(value, bool) or value in (0, 1):
        return bool(value)
    raise WorldTopicError(f"expected 0/1 or true/false, got {value!r}")


def apply_sim_message(module: TMCM6212, path: list[str], payload: bytes) -> None:
    value = _parse(payload)
    match path:
        case ["input", port]:
            n = _index(port, "input", len(module.analog_inputs))
            if isinstance(value, dict) and set(value) == {"analog"}:
                analog = value["analog"]
                if not isinstance(analog, int) or not 0 <= analog <= 65535:
                    raise WorldTopicError(f"analog value must be 0..65535, got {analog!r}")
                module.set_analog_input(n, analog)
            else:
                module.set_digital_input(n, _level(value))
        case _:
            raise WorldTopicError(f"unknown sim topic {'/'.join(path)!r}")
