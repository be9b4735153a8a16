"""Turn ``sim/fault`` messages (MQTT) into faults injected on purpose (tmcl_server/faults.py).

    sim/fault            a fault spec (``noreply:opcode=GAP,rate=0.1``) or a JSON table
                         ({"kind": "delay", "ms": 50}): injected for this module (``module=``
                         is this module's slot unless the spec names modules)
    sim/fault            ``clear`` (or an empty message): this module's faults are removed
    sim/fault/remove     a fault id: that fault is removed
    sim/power_cycle      anything: the module is switched off and on now

After every change the bridge publishes the faults installed (retained) on ``PREFIX/faults``;
a message it cannot use gets an answer on ``PREFIX/A/sim_error`` (docs/mqtt.md).
"""

from __future__ import annotations

from typing import Any

from tmcl_server.fault_language import FaultSpecError, fault_from_mapping, parse_fault
from tmcl_server.faults import FaultInjector
from tmcl_server.module import TMCLModule
from tmcl_server.transports.mqtt.payload import PayloadError, decode_text, parse_json

#: The ``sim/`` topics this file serves.
FAULT_TOPICS = ("fault", "power_cycle")


def apply_fault_message(injector: FaultInjector, module: TMCLModule, path: list[str],
                        payload: bytes) -> None:
    """Act on one ``sim/fault...`` or ``sim/power_cycle`` message; FaultSpecError if unusable."""
    try:
        text = decode_text(payload)
    except PayloadError as exc:
        raise FaultSpecError(str(exc)) from None
    match path:
        case ["power_cycle"]:
            injector.power_cycle(module)
        case ["fault"] if text.lower() in ("", "clear", "null"):
            injector.clear(module.slot)
        case ["fault"]:
            injector.add(_spec(text, module))
        case ["fault", "remove"]:
            if not text.isdigit():
                raise FaultSpecError(f"sim/fault/remove takes a fault id, got {text!r}")
            injector.remove(int(text))
        case _:
            raise FaultSpecError(f"unknown sim topic {'/'.join(path)!r}")


def _spec(text: str, module: TMCLModule) -> Any:
    if text.startswith("{"):
        try:
            table = parse_json(text)
        except PayloadError as exc:
            raise FaultSpecError(f"fault is not valid JSON: {exc}") from None
        if not isinstance(table, dict):
            raise FaultSpecError("a JSON fault must be an object with a 'kind'")
        return fault_from_mapping({"module": module.slot, **table})
    spec = parse_fault(text)
    if "module" in spec.keys:
        return spec
    return parse_fault(f"{text}{',' if ':' in text else ':'}module={module.slot}")
