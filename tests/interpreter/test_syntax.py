"""One TMCL line syntax for ``tmcl-asm`` and ``tmcl send`` (interpreter/syntax.py)."""

from __future__ import annotations

import pytest
from hypothesis import given

from interpreter.assembler import AssemblyError, LimitError, assemble
from interpreter.disassembler import format_instruction
from interpreter.isa import Instruction
from interpreter.syntax import MAX_NESTING, MAX_TOKENS
from tests.helpers.instructions import canonical_instructions
from tmcl_server.decode import Vocabulary
from tmcl_server.tool.line import LineError, parse_command
from tmcl_spec.commands import OPERAND_NAMES, OPERANDS, Opcode

WORDS = Vocabulary()


def sent(line: str) -> Instruction:
    command = parse_command(line, WORDS)
    return Instruction(command.opcode, command.type, command.motor, command.value)


def stored(line: str) -> Instruction:
    return assemble("#include TMCLParam.tmc\n" + line).instructions[0]


@pytest.mark.parametrize(("line", "expected"), [
    ("ROR 1, 20000", Instruction(Opcode.ROR, 0, 1, 20000)),
    ("MST 1", Instruction(Opcode.MST, 0, 1, 0)),
    ("SAP 4, 0, 51200", Instruction(Opcode.SAP, 4, 0, 51200)),
    ("MVP ABS, 2, 1000", Instruction(Opcode.MVP, 0, 2, 1000)),
    ("GIO 8, 1", Instruction(Opcode.GIO, 8, 1, 0)),
    ("MVP REL 0 -500", Instruction(Opcode.MVP, 1, 0, -500)),  # a sign glued on: a new operand
    ("MVP REL, 0, 10 -500", Instruction(Opcode.MVP, 1, 0, -490)),  # with commas: arithmetic
    ("COMP 1000 - 10", Instruction(Opcode.COMP, 0, 0, 990)),  # spaces both sides: arithmetic
    ("SAP 4 0 (1 + 1) * 100", Instruction(Opcode.SAP, 4, 0, 200)),
    ("SAP APMaxPositioningSpeed, Motor0, $C800", Instruction(Opcode.SAP, 4, 0, 51200)),
    ("CALC AND, %1010 | 0b1", Instruction(Opcode.CALC, 5, 0, 11)),
    ("WAIT TICKS 0 100 / 3", Instruction(Opcode.WAIT, 0, 0, 33)),
])
def test_a_line_means_the_same_in_a_program_and_on_the_command_line(line: str, expected: Instruction) -> None:
    assert stored(line) == expected
    assert sent(line) == expected


@given(canonical_instructions())
def test_the_disassemblers_lines_with_or_without_commas_send_what_they_store(
        ins: Instruction) -> None:
    line = format_instruction(ins)
    for text in (line, line.replace(",", "")):
        assert stored(text) == ins, text
        assert sent(text) == ins, text


def test_the_manuals_operand_names_cover_every_command() -> None:
    assert set(OPERAND_NAMES) == set(OPERANDS)
    for opcode, names in OPERAND_NAMES.items():
        assert len(names) == len(OPERANDS[opcode]), opcode


@pytest.mark.parametrize(("line", "message"), [
    ("ROR 0 1 20000", "ROR takes 2 operand(s), got 3 in 'ROR 0 1 20000'; the manual's form is "
                      "ROR <axis>, <velocity> (as the old TYPE MOTOR VALUE form, this line is ROR 1, 20000)"),
    ("MST 0 1", "(as the old TYPE MOTOR VALUE form, this line is MST 1)"),
    ("MST", "MST takes 1 operand(s), got 0"),
    ("MVP ABS 0 4294967396", "column 11: operand '4294967396' = 4294967396 does not fit 32 bits"),
    ("MVP ABS, 0 1", "column 12: missing operator or comma before '1'"),
    ("SAP 4, 0, 1 << 99", "shift count 99 outside 0..63"),
    ("SAP MaxCurent 0 1", "unknown parameter 'MaxCurent' (did you mean MaxCurrent"),
    ("GGP SerialAddress 7", "TMCM-6212 has no global parameter bank 7"),
    ("FLY 1", "unknown command 'FLY'"),
])
def test_a_line_that_is_not_clear_is_refused_with_one_line(line: str, message: str) -> None:
    with pytest.raises(LineError) as info:
        parse_command(line, WORDS)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_control_commands_and_numbers_are_raw_frames() -> None:
    assert sent("GET_FIRMWARE_VERSION") == Instruction(Opcode.GET_FIRMWARE_VERSION, 0, 0, 0)
    assert sent("RUN_APPLICATION 1, 0, 5") == Instruction(Opcode.RUN_APPLICATION, 1, 0, 5)
    assert sent("138 0 0 1") == Instruction(Opcode.TARGET_REACHED_EVENT, 0, 0, 1)
    assert sent("13 9 0") == Instruction(Opcode.RFS, 9, 0, 0)  # by number: any field, as given
    assert sent("4 ABS 0 100") == Instruction(Opcode.MVP, 0, 0, 100)
    with pytest.raises(LineError, match="at most 3 operands"):
        parse_command("137 0 0 1234 5", WORDS)


@pytest.mark.parametrize(("line", "message"), [
    ("COMP " + "+".join(["1"] * 300), f"more than {MAX_TOKENS} tokens"),
    ("COMP " + "(" * 40 + "1" + ")" * 40, f"nested deeper than {MAX_NESTING} levels"),
    ("COMP " + "-" * 40 + "1", f"nested deeper than {MAX_NESTING} levels"),
])
def test_expression_limits(line: str, message: str) -> None:
    with pytest.raises(LimitError, match=message):
        assemble(line)
    with pytest.raises(LineError, match=message):
        parse_command(line, WORDS)


def test_values_stay_within_64_bits_at_every_step() -> None:
    with pytest.raises(AssemblyError, match="beyond 64 bits"):
        assemble("A = " + "*".join(["99999999"] * 50) + "\nCOMP A")
    with pytest.raises(AssemblyError, match="beyond 64 bits"):
        assemble("COMP 0x1" + "0" * 20)
    assert assemble("COMP (1 << 40) >> 20").instructions[0].value == 1 << 20
    assert assemble("COMP -7 / 2").instructions[0].value == -3  # truncated toward zero
    assert assemble("COMP -7 % 2").instructions[0].value == -1
