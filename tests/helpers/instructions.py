"""Hypothesis strategies for TMCL instructions, shared by the assembler and line-syntax tests."""

from __future__ import annotations

from hypothesis import strategies as st

from interpreter.isa import PROGRAM_MEMORY_SIZE, Instruction
from tmcl_spec.commands import OPERANDS, CalcOp, Opcode


@st.composite
def canonical_instructions(draw: st.DrawFn) -> Instruction:
    """Any canonical instruction: operands only in the fields the mnemonic has (CALC without
    SWAP, which exists for CALCX alone)."""
    opcode = draw(st.sampled_from(list(OPERANDS)))
    fields = {"type": 0, "motor": 0, "value": 0}
    for spec in OPERANDS[opcode]:
        if spec.symbols is not None:
            members = [m for m in spec.symbols
                       if not (opcode == Opcode.CALC and m == CalcOp.SWAP)]
            fields[spec.slot] = int(draw(st.sampled_from(members)))
        elif spec.address:
            fields[spec.slot] = draw(st.integers(0, PROGRAM_MEMORY_SIZE - 1))
        elif spec.slot == "value":
            fields[spec.slot] = draw(st.integers(-(2**31), 2**31 - 1))
        else:
            fields[spec.slot] = draw(st.integers(0, 255))
    return Instruction(int(opcode), fields["type"], fields["motor"], fields["value"])
