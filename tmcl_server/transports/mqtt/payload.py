"""Reading MQTT payloads safely: bounded size and nesting, strict UTF-8, finite numbers.

Every topic the bridge reads (requests, ``sim/...`` world and fault topics) goes through
:func:`parse_json` or :func:`decode_text`, so a payload that is too big, too deeply nested,
not UTF-8, or holds ``NaN``/``Infinity``/``1e999`` gets a clear error answer instead of a
RecursionError in the log or a value the models cannot use (docs/mqtt.md).
"""

from __future__ import annotations

import json
import math
from typing import Any

#: Longest payload read (a request is tens of bytes, a load profile a few KiB).
MAX_PAYLOAD = 64 * 1024
#: Deepest nesting of JSON arrays and objects read (the deepest message needs 3).
MAX_DEPTH = 16


class PayloadError(ValueError):
    """A payload the bridge will not read; the message says why."""


def decode_text(payload: bytes) -> str:
    """The payload as text: at most MAX_PAYLOAD bytes of UTF-8 (strict), blanks stripped."""
    if len(payload) > MAX_PAYLOAD:
        raise PayloadError(f"payload of {len(payload)} bytes is longer than {MAX_PAYLOAD}")
    try:
        return payload.decode("utf-8").strip()
    except UnicodeDecodeError as exc:
        raise PayloadError(f"payload is not UTF-8 text ({exc.reason} at byte {exc.start})") from None


def _depth(text: str) -> int:
    """How deeply arrays and objects nest (brackets inside strings do not count)."""
    depth = deepest = 0
    in_string = escaped = False
    for char in text:
        if in_string:
            if escaped:
                escaped = False
            elif char == "\\":
                escaped = True
            elif char == '"':
                in_string = False
        elif char == '"':
            in_string = True
        elif char in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif char in "]}":
            depth -= 1
    return deepest


def _finite(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise PayloadError(f"number {text} is out of range")
    return value


def _no_constant(name: str) -> Any:
    raise PayloadError(f"{name} is not a number the simulator accepts")


def parse_json(text: str) -> Any:
    """JSON with finite numbers only, nested at most MAX_DEPTH deep; PayloadError otherwise."""
    if text.count("[") + text.count("{") > MAX_DEPTH and _depth(text) > MAX_DEPTH:
        raise PayloadError(f"JSON nested deeper than {MAX_DEPTH} levels")
    try:
        return json.loads(text, parse_float=_finite, parse_constant=_no_constant)
    except PayloadError:
        raise
    except ValueError as exc:  # JSONDecodeError, an integer of more than 4300 digits
        raise PayloadError(f"not valid JSON: {exc}") from None
