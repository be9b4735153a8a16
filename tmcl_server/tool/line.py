"""``tmcl send``'s command: one TMCL line, read by the assembler's own parser
(:mod:`interpreter.syntax`), so ``tmcl send ROR 1, 20000`` sends what ``ROR 1, 20000`` in a
program stores.

A mnemonic takes the operands the manual gives it, in its order (``MST 1``, ``GIO 8, 1``),
commas optional.  Names: the parameter tables' compact names (``MaxPositioningSpeed``; the
type field of SAP/GAP/..., and of SGP/GGP/... for the bank given), the constants of the shipped
include files (``APMaxPositioningSpeed``, ``Motor0``, ``TI_TIMER0``) and the type field's
symbols (``ABS``, ``START``, ``GE``).  A control command (``GET_FIRMWARE_VERSION``, 128..138,
146..148, which have no mnemonic) or a command given by number is a raw frame: up to three
operands, TYPE MOTOR VALUE, missing ones 0.

The tool used to read TYPE MOTOR VALUE for every command; a line whose operand count does not
fit its command is refused (never sent), and when it reads as that old form the message says
what to write instead.
"""

from __future__ import annotations

import difflib
import re
import textwrap
from dataclasses import dataclass
from typing import Any

from interpreter.assembler import include_constants
from interpreter.syntax import (
    MNEMONICS,
    AssemblyError,
    Location,
    Operand,
    encode,
    excerpt,
    field_value,
    split_operands,
)
from tmcl_server.decode import Vocabulary
from tmcl_spec.commands import (
    AXIS_PARAMETER_COMMANDS,
    GLOBAL_PARAMETER_COMMANDS,
    OPERAND_NAMES,
    OPERANDS,
    TYPE_SYMBOLS,
    Field,
    Opcode,
    mnemonic_syntax,
)

#: Names people type for the control commands, besides the Opcode names.
ALIASES = {"GETVERSION": Opcode.GET_FIRMWARE_VERSION, "VERSION": Opcode.GET_FIRMWARE_VERSION,
           "RUN": Opcode.RUN_APPLICATION, "STOPAPP": Opcode.STOP_APPLICATION,
           "STATUS": Opcode.GET_APPLICATION_STATUS}
_RAW_FIELDS = (Field("type"), Field("motor"), Field("value"))
_SLOTS = ("type", "motor", "value")
_HEAD = re.compile(r"\s*([^\s,]+)")


class LineError(ValueError):
    """A line that cannot be sent as written (the message is one line)."""


@dataclass(frozen=True)
class Command:
    opcode: int
    type: int
    motor: int
    value: int


def parse_opcode(text: str) -> int:
    """A mnemonic (``SAP``), an opcode name (``GET_FIRMWARE_VERSION``) or a number 0..255."""
    name = text.strip().upper().replace("-", "_")
    if name in Opcode.__members__:
        return int(Opcode[name])
    if name in ALIASES:
        return int(ALIASES[name])
    try:
        number = int(text.strip(), 0)
    except ValueError:
        number = None
    if number is not None and 0 <= number <= 255:
        return number
    close = difflib.get_close_matches(name, list(Opcode.__members__), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise LineError(f"unknown command {text!r}{hint}")


class _Names:
    """How ``tmcl send`` resolves a name in one operand."""

    def __init__(self, opcode: int, words: Vocabulary) -> None:
        self.opcode = opcode
        self.words = words

    def _parameters(self, where: Location, spec: Field, done: dict[str, int]) -> Any:
        """The parameter names a type operand may use (axis, or the bank already given), or
        None for any other operand."""
        if spec.slot != "type":
            return None
        if self.opcode in AXIS_PARAMETER_COMMANDS:
            return self.words.axis
        if self.opcode in GLOBAL_PARAMETER_COMMANDS:
            bank = done.get("motor", 0)
            tables = self.words.banks.get(bank)
            if tables is None:
                raise AssemblyError(where, f"{self.words.type.name} has no global parameter bank {bank}")
            return tables
        return None

    def __call__(self, name: str, where: Location, spec: Field, done: dict[str, int]) -> int:
        tables = self._parameters(where, spec, done)
        if tables is not None:
            number = tables.number(name)
            if number is not None:
                return number
        symbols = TYPE_SYMBOLS.get(self.opcode) if spec.slot == "type" else None  # type: ignore[call-overload]
        if symbols is not None and name.upper() in symbols.__members__:  # a raw frame's MVP ABS
            return int(symbols[name.upper()])
        constant = include_constants().get(name.lower())
        if constant is not None:
            return constant
        raise _unknown(name, where, tables, symbols)


def _unknown(name: str, where: Location, tables: Any, symbols: Any) -> AssemblyError:
    """The error for a name nothing knows: the closest parameter names, or the symbols."""
    if tables is not None:
        close = difflib.get_close_matches(name, [n for _, n in tables], n=3)
        hint = f" (did you mean {', '.join(close)}?)" if close else ""
        return AssemblyError(where, f"unknown parameter {excerpt(name)}{hint}")
    known = f"; one of {', '.join(symbols.__members__)}" if symbols is not None else ""
    return AssemblyError(where, f"unknown name {excerpt(name)}{known}")


def parse_command(text: str, words: Vocabulary) -> Command:
    """The frame a ``tmcl send`` line stands for; LineError (one line) if it is not clear."""
    line = text.strip()
    head = _HEAD.match(line)
    if head is None:
        raise LineError("no command given")
    where = Location("", 1, 1)

    def at(column: int) -> Location:
        return where.at_column(column + 1)

    try:
        operands = split_operands(line, head.end(), at)
        mnemonic = MNEMONICS.get(head.group(1).upper())
        if mnemonic is not None:
            _check_count(mnemonic, operands, line)
            ins = encode(mnemonic, operands, at(head.start(1)), _Names(mnemonic, words))
            return Command(ins.opcode, ins.type, ins.motor, ins.value)
        opcode = parse_opcode(head.group(1))
        return _raw(opcode, operands, line, words)
    except AssemblyError as exc:
        first = exc.errors[0]
        more = f" (and {len(exc.errors) - 1} more)" if len(exc.errors) > 1 else ""
        raise LineError(f"{excerpt(line)}, column {first.location.column}: {first.message}{more}") from None


def _raw(opcode: int, operands: list[Operand], line: str, words: Vocabulary) -> Command:
    """TYPE MOTOR VALUE, missing ones 0: a control command or a command given by number."""
    if len(operands) > 3:
        raise LineError(f"{excerpt(line)}: a raw frame takes at most 3 operands (type, motor, value), "
                        f"got {len(operands)}")
    names = _Names(opcode, words)
    fields = dict.fromkeys(_SLOTS, 0)
    done: dict[str, int] = {}
    for index in sorted(range(len(operands)), key=lambda i: _SLOTS[i] != "motor"):  # the bank first
        spec = _RAW_FIELDS[index]  # any number goes: a raw frame may be meant to be refused
        fields[spec.slot] = done[spec.slot] = field_value(
            Opcode.UF0, spec, operands[index],  # (the opcode matters only to symbolic fields)
            lambda name, where, spec=spec: names(name, where, spec, done))  # type: ignore[misc]
    return Command(opcode, fields["type"], fields["motor"], fields["value"])


def _check_count(opcode: Opcode, operands: list[Operand], line: str) -> None:
    """Refuse a line whose operand count does not fit, saying what the old form meant."""
    specs = OPERANDS[opcode]
    if len(operands) == len(specs):
        return
    message = (f"{opcode.name} takes {len(specs)} operand(s), got {len(operands)} in {excerpt(line)}; "
               f"the manual's form is {mnemonic_syntax(opcode)}")
    old = dict(zip(_SLOTS, (o.text for o in operands), strict=False)) if len(operands) <= 3 else None
    if old is not None:
        used = {spec.slot for spec in specs}
        unused_zero = all(_is_zero(text) for slot, text in old.items() if slot not in used)
        if unused_zero and used <= set(old) | {"value"}:
            mapped = ", ".join(old.get(spec.slot, "0") for spec in specs)
            suggestion = f"{opcode.name} {mapped}".strip()
            message += f" (as the old TYPE MOTOR VALUE form, this line is {suggestion})"
    raise LineError(message)


def _is_zero(text: str) -> bool:
    try:
        return int(text, 0) == 0
    except ValueError:
        return False


def old_form_help() -> str:
    """How the old ``tmcl send CMD TYPE MOTOR VALUE`` form maps to the manual's operands."""
    same = []
    changed = []
    for opcode, specs in OPERANDS.items():
        slots = [spec.slot for spec in specs]
        if slots == list(_SLOTS[:len(slots)]):
            same.append(opcode.name)
            continue
        named = dict(zip(slots, OPERAND_NAMES[opcode], strict=True))
        last = max(_SLOTS.index(slot) for slot in slots)
        old = " ".join(f"<{named[slot]}>" if slot in named else "0" for slot in _SLOTS[:last + 1])
        changed.append(f"  {mnemonic_syntax(opcode):<36} was  {opcode.name} {old}")
    return ("operands: each command takes the operands the manual gives it, in its order, commas\n"
            "optional (tmcl-asm reads the same lines).  Earlier versions of tmcl send read TYPE MOTOR\n"
            "VALUE for every command; for these commands nothing changes (all operands required):\n"
            + textwrap.fill(" ".join(same), 92, initial_indent="  ", subsequent_indent="  ") + "\n"
            "for these the old form maps as shown:\n" + "\n".join(changed) + "\n"
            "Control commands (GET_FIRMWARE_VERSION, 128..138, ...) and commands given by number are\n"
            "raw frames: TYPE MOTOR VALUE, missing ones 0.  A line whose operand count does not fit\n"
            "its command is refused with the manual's form, never sent.")
