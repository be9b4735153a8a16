"""TMCL requests as JSON, for hosts that are not byte-oriented (the MQTT bridge).

    {"cmd": "MVP", "type": "ABS", "motor": 0, "value": 51200}

``cmd`` is a mnemonic or an opcode number (control commands by their `Opcode` name, e.g.
``"GET_FIRMWARE_VERSION"``), ``type`` a number or the command's symbolic operand (ABS,
START, ADD, GE, POS, ETO ...), ``motor`` (alias ``bank``) and ``value`` numbers.  Omitted
fields are 0.  Anything else is a :class:`RequestError` that says what was wrong.
"""

from __future__ import annotations

from typing import Any

from tmcl_server.protocol import AnyReply, RawReply, Request
from tmcl_server.transports.mqtt.payload import PayloadError, decode_text, parse_json
from tmcl_spec.commands import TYPE_SYMBOLS, Opcode, Status
from tmcl_spec.numbers import to_int32

FIELDS = ("cmd", "type", "motor", "bank", "value")


class RequestError(ValueError):
    """A request that cannot be turned into a TMCL command."""


def _number(name: str, raw: Any, lo: int, hi: int) -> int:
    if isinstance(raw, bool) or not isinstance(raw, int):
        raise RequestError(f"{name} must be an integer, got {raw!r}")
    if not lo <= raw <= hi:
        raise RequestError(f"{name} {raw} is out of range {lo}..{hi}")
    return raw


def _opcode(raw: Any) -> int:
    if isinstance(raw, str):
        try:
            return Opcode[raw.strip().upper()]
        except KeyError:
            raise RequestError(f"unknown mnemonic {raw!r}") from None
    return _number("cmd", raw, 0, 255)


def _type(opcode: int, raw: Any) -> int:
    if isinstance(raw, str):
        symbols = TYPE_SYMBOLS.get(opcode)
        name = raw.strip().upper()
        if symbols is None or name not in symbols.__members__:
            known = ", ".join(symbols.__members__) if symbols else "none (use a number)"
            raise RequestError(f"unknown type {raw!r} for this command; known: {known}")
        return symbols[name]
    return _number("type", raw, 0, 255)


def request_from_json(payload: bytes | str, address: int = 1) -> Request:
    try:
        text = decode_text(payload) if isinstance(payload, bytes) else payload
        body = parse_json(text)
    except PayloadError as exc:
        raise RequestError(f"request is not a 9-byte TMCL frame nor JSON: {exc}") from None
    if not isinstance(body, dict):
        raise RequestError("request must be a JSON object")
    unknown = sorted(set(body) - set(FIELDS))
    if unknown:
        raise RequestError(f"unknown field(s) {', '.join(unknown)}; use {', '.join(FIELDS)}")
    if "cmd" not in body:
        raise RequestError('request needs "cmd" (a mnemonic such as "GAP", or a number)')
    if "motor" in body and "bank" in body:
        raise RequestError('give either "motor" or "bank", not both')
    opcode = _opcode(body["cmd"])
    type_ = _type(opcode, body.get("type", 0))
    motor = _number("motor", body.get("motor", body.get("bank", 0)), 0, 255)
    value = _number("value", body.get("value", 0), -(2**31), 2**32 - 1)
    return Request(address, opcode, type_, motor, to_int32(value))


def reply_to_json(reply: AnyReply) -> dict[str, Any]:
    if isinstance(reply, RawReply):
        body: dict[str, Any] = {"status": int(Status.OK), "status_name": "OK",
                                "raw": reply.data.hex()}
        text = reply.data[1:]
        if text.isascii() and text.decode().isprintable():
            body["text"] = text.decode()
        return body
    try:
        status_name = Status(reply.status).name
    except ValueError:
        status_name = str(reply.status)
    try:
        cmd: str | int = Opcode(reply.opcode).name
    except ValueError:
        cmd = reply.opcode
    return {"status": int(reply.status), "status_name": status_name, "cmd": cmd,
            "opcode": int(reply.opcode), "value": to_int32(reply.value)}
