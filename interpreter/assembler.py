"""Assembler for TMCL source (``.tmc``) as the TMCL-IDE writes it.

One instruction per line; ``Label:`` (optionally followed by an instruction on the same
line); ``Name = expression`` constants; ``#include file``; ``//`` comments.  Mnemonics,
symbolic operands (ABS, TICKS, ADD, GE, ETO, ...) and symbol names are case-insensitive.
Operands are integer expressions over numbers (decimal, ``0x``/``$`` hex, ``0b``/``%``
binary), constants and labels, parsed with Python's ``ast`` and evaluated with 32-bit
two's-complement wrap.  Errors carry file, line and column.
"""

from __future__ import annotations

import ast
import operator
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from interpreter.isa import PROGRAM_MEMORY_SIZE, Instruction
from tmcl_spec.commands import CALC_MAX_OPERATION, OPERANDS, CalcOp, Field, Opcode

#: The include files shipped with the package (TMCLParam.tmc, Interrupts.inc).
INCLUDE_DIR = Path(__file__).with_name("include")

_MNEMONICS = {op.name: op for op in OPERANDS}
_LABEL = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*:(?!=)")
_CONSTANT = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*=(?!=)\s*")
_WORD = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")
_INCLUDE = re.compile(r"\s*#\s*include\b\s*", re.IGNORECASE)
_HEX_DOLLAR = re.compile(r"\$([0-9A-Fa-f]+)")
_BIN_PERCENT = re.compile(r"(?<![\w)])%([01]+)")

_BINARY_OPERATORS: dict[type[ast.operator], Callable[[int, int], int]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.FloorDiv: lambda a, b: int(a / b),
    ast.Div: lambda a, b: int(a / b),
    ast.Mod: lambda a, b: a - b * int(a / b),
    ast.BitAnd: operator.and_,
    ast.BitOr: operator.or_,
    ast.BitXor: operator.xor,
    ast.LShift: operator.lshift,
    ast.RShift: operator.rshift,
}
_UNARY_OPERATORS: dict[type[ast.unaryop], Callable[[int], int]] = {
    ast.USub: operator.neg,
    ast.UAdd: operator.pos,
    ast.Invert: operator.invert,
}


@dataclass(frozen=True, slots=True)
class Location:
    file: str
    line: int
    column: int = 1

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"


class AssemblyError(Exception):
    """A source error, printed as ``file:line:col: message`` like a compiler does."""

    def __init__(self, location: Location, message: str) -> None:
        super().__init__(f"{location}: {message}")
        self.location = location
        self.message = message


@dataclass(slots=True)
class _Operand:
    text: str
    location: Location


@dataclass(slots=True)
class _Statement:
    opcode: Opcode
    operands: list[_Operand]
    location: Location
    source: str


@dataclass(slots=True)
class _Symbol:
    """A label (address known) or a constant (expression evaluated on first use)."""

    name: str
    location: Location
    value: int | None = None
    expression: _Operand | None = None
    resolving: bool = False


@dataclass
class SourceLine:
    """One assembled instruction with where it came from (for listings)."""

    address: int
    instruction: Instruction
    location: Location
    source: str


@dataclass
class Program:
    """The result of assembling: instructions from address 0, plus symbols for tools."""

    instructions: list[Instruction]
    labels: dict[str, int] = field(default_factory=dict)
    constants: dict[str, int] = field(default_factory=dict)
    lines: list[SourceLine] = field(default_factory=list)

    def binary(self) -> bytes:
        return b"".join(ins.encode() for ins in self.instructions)

    def listing(self) -> str:
        """Address, the 8-byte record and the source line of every instruction."""
        out = []
        for line in self.lines:
            record = line.instruction.encode().hex(" ")
            out.append(f"{line.address:5d}  {record}  {line.source.strip()}")
        return "\n".join(out) + ("\n" if out else "")


class _Assembler:
    def __init__(self, include_path: Sequence[Path]) -> None:
        self.include_path = list(include_path)
        self.symbols: dict[str, _Symbol] = {}
        self.statements: list[_Statement] = []
        self.including: list[Path] = []

    # -- pass 1: lines, labels, constants ------------------------------------------------------

    def read(self, text: str, filename: str, directory: Path | None) -> None:
        for number, raw in enumerate(text.splitlines(), 1):
            line = raw.split("//", 1)[0].rstrip()
            self._line(line, raw, filename, number, directory)

    def _line(self, line: str, raw: str, filename: str, number: int, directory: Path | None) -> None:
        def at(column: int) -> Location:
            return Location(filename, number, column + 1)

        include = _INCLUDE.match(line)
        if include:
            name = line[include.end():].strip().strip('"<>').strip()
            self._include(name, at(include.end()), directory)
            return
        pos = 0
        while True:
            label = _LABEL.match(line, pos)
            if not label:
                break
            self._define(label.group(1), at(label.start(1)), value=len(self.statements))
            pos = label.end()
        constant = _CONSTANT.match(line, pos)
        if constant:
            expression = line[constant.end():]
            if not expression.strip():
                raise AssemblyError(at(constant.end()), f"missing value for {constant.group(1)}")
            self._define(constant.group(1), at(constant.start(1)),
                         expression=_Operand(expression, at(constant.end())))
            return
        word = _WORD.match(line, pos)
        if not word:
            if line[pos:].strip():
                column = pos + len(line[pos:]) - len(line[pos:].lstrip())
                raise AssemblyError(at(column), f"cannot parse {line[pos:].strip()!r}")
            return
        mnemonic = word.group(1)
        opcode = _MNEMONICS.get(mnemonic.upper())
        if opcode is None:
            raise AssemblyError(at(word.start(1)), f"unknown mnemonic {mnemonic!r}")
        operands: list[_Operand] = []
        rest = line[word.end():]
        if rest.strip():
            offset = word.end()
            for piece in rest.split(","):
                stripped = piece.strip()
                column = offset + len(piece) - len(piece.lstrip())
                operands.append(_Operand(stripped, at(column)))
                offset += len(piece) + 1
        self.statements.append(_Statement(opcode, operands, at(word.start(1)), raw))

    def _include(self, name: str, location: Location, directory: Path | None) -> None:
        if not name:
            raise AssemblyError(location, "#include needs a file name")
        path = self._find(name, directory)
        if path is None:
            raise AssemblyError(location, f"include file {name!r} not found")
        if path in self.including:
            raise AssemblyError(location, f"{name!r} includes itself")
        self.including.append(path)
        try:
            self.read(path.read_text(encoding="latin-1"), str(path), path.parent)
        finally:
            self.including.pop()

    def _find(self, name: str, directory: Path | None) -> Path | None:
        """Look next to the including file, then on the include path; case-insensitively,
        because TMCL projects come from Windows."""
        candidate = Path(name)
        if candidate.is_absolute():
            return candidate if candidate.is_file() else None
        for folder in ([directory] if directory else []) + self.include_path:
            exact = folder / name
            if exact.is_file():
                return exact.resolve()
            if folder.is_dir():
                for entry in folder.iterdir():
                    if entry.name.lower() == candidate.name.lower() and entry.is_file():
                        return entry.resolve()
        return None

    def _define(self, name: str, location: Location, value: int | None = None,
                expression: _Operand | None = None) -> None:
        key = name.lower()
        previous = self.symbols.get(key)
        if previous is not None:
            kind = "label" if value is not None else "constant"
            raise AssemblyError(location, f"duplicate {kind} {name!r} (first defined at {previous.location})")
        self.symbols[key] = _Symbol(name, location, value, expression)

    # -- pass 2: operands ----------------------------------------------------------------------

    def resolve(self, name: str, location: Location) -> int:
        symbol = self.symbols.get(name.lower())
        if symbol is None:
            raise AssemblyError(location, f"undefined symbol {name!r}")
        if symbol.value is None:
            assert symbol.expression is not None
            if symbol.resolving:
                raise AssemblyError(symbol.location, f"constant {symbol.name!r} depends on itself")
            symbol.resolving = True
            symbol.value = self.evaluate(symbol.expression)
            symbol.resolving = False
        return symbol.value

    def evaluate(self, operand: _Operand) -> int:
        text = _BIN_PERCENT.sub(r"0b\1", _HEX_DOLLAR.sub(r"0x\1", operand.text))
        try:
            tree = ast.parse(text.strip(), mode="eval")
        except SyntaxError:
            raise AssemblyError(operand.location, f"bad expression {operand.text!r}") from None
        return self._eval(tree.body, operand)

    def _eval(self, node: ast.expr, operand: _Operand) -> int:
        if isinstance(node, ast.Constant) and type(node.value) is int:
            return node.value
        if isinstance(node, ast.Name):
            loc = operand.location
            return self.resolve(node.id, Location(loc.file, loc.line, loc.column + node.col_offset))
        if isinstance(node, ast.BinOp) and type(node.op) in _BINARY_OPERATORS:
            left, right = self._eval(node.left, operand), self._eval(node.right, operand)
            if isinstance(node.op, ast.Div | ast.FloorDiv | ast.Mod) and right == 0:
                raise AssemblyError(operand.location, "division by zero in expression")
            return _BINARY_OPERATORS[type(node.op)](left, right)
        if isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY_OPERATORS:
            return _UNARY_OPERATORS[type(node.op)](self._eval(node.operand, operand))
        raise AssemblyError(operand.location, f"bad expression {operand.text!r}")

    def operand(self, statement: _Statement, spec: Field, operand: _Operand) -> int:
        if not operand.text:
            raise AssemblyError(operand.location, "empty operand")
        if spec.symbols is not None:
            allowed = list(spec.symbols)
            if statement.opcode == Opcode.CALC:
                allowed = [op for op in CalcOp if op <= CALC_MAX_OPERATION]
            names = {member.name: member.value for member in allowed}
            symbolic = names.get(operand.text.upper())
            if symbolic is not None:
                return symbolic
            choices = "/".join(names)
            if operand.text.upper() in spec.symbols.__members__:
                raise AssemblyError(operand.location,
                                    f"{operand.text} is not allowed in {statement.opcode.name} "
                                    f"(expected {choices})")
            value = self.evaluate(operand)
            if value not in names.values():
                raise AssemblyError(operand.location,
                                    f"operand {operand.text!r} out of range for "
                                    f"{statement.opcode.name} (expected {choices})")
            return value
        value = self.evaluate(operand)
        if spec.slot != "value":
            if not 0 <= value <= 255:
                raise AssemblyError(operand.location,
                                    f"operand {operand.text!r} = {value} out of range 0..255")
            return value
        if spec.address and not 0 <= value < PROGRAM_MEMORY_SIZE:
            raise AssemblyError(operand.location,
                                f"address {operand.text!r} = {value} outside program memory "
                                f"0..{PROGRAM_MEMORY_SIZE - 1}")
        if not -(2**31) <= value <= 2**32 - 1:
            raise AssemblyError(operand.location,
                                f"operand {operand.text!r} = {value} does not fit 32 bits")
        return value - 2**32 if value >= 2**31 else value

    def build(self) -> Program:
        instructions: list[Instruction] = []
        lines: list[SourceLine] = []
        for address, statement in enumerate(self.statements):
            specs = OPERANDS[statement.opcode]
            if len(statement.operands) != len(specs):
                raise AssemblyError(statement.location,
                                    f"{statement.opcode.name} takes {len(specs)} operand(s), "
                                    f"got {len(statement.operands)}")
            fields = {"type": 0, "motor": 0, "value": 0}
            for spec, operand in zip(specs, statement.operands, strict=True):
                fields[spec.slot] = self.operand(statement, spec, operand)
            ins = Instruction(int(statement.opcode), fields["type"], fields["motor"], fields["value"])
            instructions.append(ins)
            lines.append(SourceLine(address, ins, statement.location, statement.source))
        if len(instructions) > PROGRAM_MEMORY_SIZE:
            raise AssemblyError(self.statements[PROGRAM_MEMORY_SIZE].location,
                                f"program longer than {PROGRAM_MEMORY_SIZE} commands")
        labels: dict[str, int] = {}
        constants: dict[str, int] = {}
        for symbol in self.symbols.values():
            if symbol.expression is None:
                assert symbol.value is not None
                labels[symbol.name] = symbol.value
            else:
                constants[symbol.name] = self.resolve(symbol.name, symbol.location)
        return Program(instructions, labels, constants, lines)


def assemble(text: str, filename: str = "<source>", include_path: Sequence[str | Path] = (),
             directory: str | Path | None = None, append_stop: bool = False) -> Program:
    """Assemble TMCL source; ``#include`` looks in ``directory``, ``include_path`` and the
    shipped include files.  ``append_stop`` adds a STOP unless the program ends with one."""
    assembler = _Assembler([Path(p) for p in include_path] + [INCLUDE_DIR])
    assembler.read(text, filename, Path(directory) if directory is not None else None)
    program = assembler.build()
    if append_stop and (not program.instructions or program.instructions[-1].opcode != Opcode.STOP):
        program.instructions.append(Instruction(int(Opcode.STOP)))
    return program


def assemble_file(path: str | Path, include_path: Sequence[str | Path] = (),
                  append_stop: bool = False) -> Program:
    source = Path(path)
    return assemble(source.read_text(encoding="latin-1"), str(source), include_path,
                    source.parent, append_stop)
