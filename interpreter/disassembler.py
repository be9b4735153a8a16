"""Disassembler: program memory or a ``.bin`` file back to readable TMCL source.

Like CPython's ``dis``, jump targets get generated labels (``L1``, ``L2``, ... in address
order) so the output assembles again to the same bytes.  :func:`listing` prints one
``address: instruction`` line per command with numeric addresses instead.
"""

from __future__ import annotations

from collections.abc import Sequence

from interpreter.isa import Instruction
from tmcl_spec.commands import OPERANDS, Field, Opcode

_SLOTS = ("type", "motor", "value")


def _field_value(ins: Instruction, slot: str) -> int:
    return {"type": ins.type, "motor": ins.motor, "value": ins.value}[slot]


def _operand(ins: Instruction, spec: Field, labels: dict[int, str] | None) -> str:
    value = _field_value(ins, spec.slot)
    if spec.symbols is not None:
        try:
            return spec.symbols(value).name
        except ValueError:
            return str(value)
    if spec.address and labels is not None and value in labels:
        return labels[value]
    return str(value)


def format_instruction(ins: Instruction, labels: dict[int, str] | None = None) -> str:
    """One instruction as source text, e.g. ``MVP REL, 0, 200``."""
    try:
        opcode = Opcode(ins.opcode)
        specs = OPERANDS[opcode]
    except (ValueError, KeyError):
        return f"// opcode {ins.opcode}, type {ins.type}, motor {ins.motor}, value {ins.value}"
    text = opcode.name
    if specs:
        text += " " + ", ".join(_operand(ins, spec, labels) for spec in specs)
    used = {spec.slot for spec in specs}
    extra = [f"{slot} {_field_value(ins, slot)}" for slot in _SLOTS
             if slot not in used and _field_value(ins, slot)]
    if extra:
        text += "  // also " + ", ".join(extra)
    return text


def jump_targets(instructions: Sequence[Instruction]) -> list[int]:
    """Addresses that JA, JC, CSUB or VECT refer to, sorted."""
    targets = set()
    for ins in instructions:
        try:
            specs = OPERANDS[Opcode(ins.opcode)]
        except (ValueError, KeyError):
            continue
        if any(spec.address for spec in specs):
            targets.add(ins.value)
    return sorted(targets)


def labelled(instructions: Sequence[Instruction]) -> list[tuple[int, str | None, str]]:
    """(address, label or None, source text) per instruction: what :func:`disassemble` prints,
    line by line (a debugger shows it with the current instruction and breakpoints)."""
    labels = {address: f"L{n}" for n, address in
              enumerate((a for a in jump_targets(instructions) if 0 <= a < len(instructions)), 1)}
    return [(address, labels.get(address), format_instruction(ins, labels))
            for address, ins in enumerate(instructions)]


def disassemble(instructions: Sequence[Instruction]) -> str:
    """Source text with generated labels; assembling it gives the same instructions.

    Targets beyond the program (or outside memory) stay numeric.
    """
    lines = []
    for _, label, text in labelled(instructions):
        if label is not None:
            lines.append(f"{label}:")
        lines.append(f"    {text}")
    return "\n".join(lines) + ("\n" if lines else "")


def listing(instructions: Sequence[Instruction], origin: int = 0) -> str:
    """``address: instruction`` per line, addresses numeric (the TMCL-IDE's view)."""
    lines = [f"    {address}: {format_instruction(ins)}"
             for address, ins in enumerate(instructions, origin)]
    return "\n".join(lines) + ("\n" if lines else "")
