"""Assembler for TMCL source (``.tmc``) as the TMCL-IDE writes it.

One instruction per line in the syntax of :mod:`interpreter.syntax` (shared with ``tmcl
send``); ``Label:`` (optionally followed by an instruction on the same line); ``Name =
expression`` constants; ``#include file``; ``//`` comments.  Mnemonics, symbolic operands
(ABS, TICKS, ADD, GE, ETO, ...) and symbol names are case-insensitive.  Operand values are
checked against their field (0..255, 32 bits, program addresses).

Every error of a source is reported in one run, in source order, as ``file:line:column:
message`` (one :class:`AssemblyError` carrying them all).  Reaching a limit stops the
assembly with that one error: include depth (:data:`MAX_INCLUDE_DEPTH`), files included
(:data:`MAX_INCLUDES`), source read in total (:data:`MAX_SOURCE_BYTES`,
:data:`MAX_SOURCE_LINES`), constants resolved through forward references
(:data:`MAX_FORWARD_DEPTH`), and the expression limits of :mod:`interpreter.syntax`.

``#include`` finds files next to the including file, in the folders given (``-I``) and in
the shipped include folder, and only inside the source's folder tree, those folders and the
shipped one (after following links): a source cannot make the assembler read, or quote in
an error, a file from elsewhere (docs/interpreter.md).
"""

from __future__ import annotations

import os
import re
import stat
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

from interpreter.isa import PROGRAM_MEMORY_SIZE, Instruction
from interpreter.syntax import (
    MNEMONICS,
    NAME_EXCERPT,
    AssemblyError,
    LimitError,
    Location,
    Node,
    Operand,
    Token,
    columns,
    encode,
    evaluate,
    excerpt,
    names_in,
    parse_expression,
    split_operands,
    tokenize,
)
from tmcl_spec.commands import Field, Opcode

__all__ = ["INCLUDE_DIR", "AssemblyError", "LimitError", "Location", "Program", "SourceLine",
           "assemble", "assemble_file", "include_constants"]

#: The include files shipped with the package (TMCLParam.tmc, Interrupts.inc).
INCLUDE_DIR = Path(__file__).with_name("include")

#: Includes nested at most this deep.
MAX_INCLUDE_DEPTH = 16
#: Include files read in one assembly at most (each time it is included counts).
MAX_INCLUDES = 256
#: Source read in one assembly at most, includes counted each time they are read.
MAX_SOURCE_BYTES = 2 << 20
MAX_SOURCE_LINES = 20_000
#: Tokens (numbers, names, operators) in all operands and constants of one assembly at most.
MAX_SOURCE_TOKENS = 200_000
#: A constant may use constants defined after it, through at most this many such steps.
MAX_FORWARD_DEPTH = 64
#: Errors reported at most; the rest are counted.
MAX_ERRORS = 100

_LABEL = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*:(?!=)")
_CONSTANT = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)\s*=(?!=)\s*")
_WORD = re.compile(r"\s*([A-Za-z_][A-Za-z0-9_]*)")
_INCLUDE = re.compile(r"\s*#\s*include\b\s*", re.IGNORECASE)


@dataclass(slots=True)
class _Statement:
    opcode: Opcode
    operands: list[Operand]
    location: Location
    source: str


@dataclass(slots=True)
class _Symbol:
    """A label (address known) or a constant (expression evaluated in pass 2)."""

    name: str
    location: Location
    value: int | None = None
    expression: Node | None = None
    #: A constant whose own line is wrong: its uses report nothing more.
    broken: bool = False
    state: int = 0  # constants: 0 not yet, 1 being resolved, 2 done


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


class _Silent(Exception):
    """An operand uses a constant already reported as wrong: nothing more to say."""


class _Assembler:
    def __init__(self, include_path: Sequence[Path], root: Path | None) -> None:
        self.include_path = [p.resolve() for p in include_path]
        #: Folders (with their subfolders) includes may come from.
        self.allowed = ([root.resolve()] if root is not None else []) + self.include_path
        self.symbols: dict[str, _Symbol] = {}
        self.statements: list[_Statement] = []
        self.errors: list[AssemblyError] = []
        self.including: list[Path] = []
        self.includes = 0
        self.bytes_read = 0
        self.lines_read = 0
        self.tokens_read = 0
        #: Where the first command beyond program memory is written.
        self.too_long: Location | None = None

    # -- pass 1: lines, labels, constants ------------------------------------------------------

    def read(self, text: str, filename: str, directory: Path | None) -> None:
        self.bytes_read += len(text)
        for number, raw in enumerate(text.splitlines(), 1):
            self.lines_read += 1
            location = Location(filename, number, 1, self.lines_read)
            if self.lines_read > MAX_SOURCE_LINES or self.bytes_read > MAX_SOURCE_BYTES:
                raise LimitError(location, f"source too long (more than {MAX_SOURCE_LINES} lines or "
                                 f"{MAX_SOURCE_BYTES >> 20} MiB in all, includes counted each time)")
            try:
                self._line(raw.split("//", 1)[0].rstrip(), raw, location, directory)
            except LimitError:
                raise
            except AssemblyError as exc:
                self.errors.extend(exc.errors)

    def _line(self, line: str, raw: str, where: Location, directory: Path | None) -> None:
        def at(column: int) -> Location:
            return where.at_column(column + 1)

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
            try:
                self._define(_Symbol(label.group(1), at(label.start(1)), value=len(self.statements)))
            except AssemblyError as exc:  # reported; the rest of the line may have more to say
                self.errors.append(exc)
            pos = label.end()
        constant = _CONSTANT.match(line, pos)
        if constant:
            symbol = _Symbol(constant.group(1), at(constant.start(1)), broken=True)
            self._define(symbol)
            if not line[constant.end():].strip():
                raise AssemblyError(at(constant.end()), f"missing value for {symbol.name}")
            tokens = self._count(tokenize(line, constant.end(), at), symbol.location)
            for token in tokens:
                if token.text == ",":
                    raise AssemblyError(at(token.column), "a constant has one value: unexpected ','")
            symbol.expression = parse_expression(tokens, at, len(line))
            symbol.broken = False
            return
        word = _WORD.match(line, pos)
        if not word:
            if line[pos:].strip():
                column = pos + len(line[pos:]) - len(line[pos:].lstrip())
                raise AssemblyError(at(column), f"cannot parse {excerpt(line[pos:])}")
            return
        mnemonic = word.group(1)
        opcode = MNEMONICS.get(mnemonic.upper())
        if opcode is None:
            raise AssemblyError(at(word.start(1)), f"unknown mnemonic {excerpt(mnemonic)}")
        operands = split_operands(line, word.end(), at, self._count)
        if len(self.statements) == PROGRAM_MEMORY_SIZE:  # checked, not kept: it cannot be stored
            if self.too_long is None:
                self.too_long = at(word.start(1))
            return
        self.statements.append(_Statement(opcode, operands, at(word.start(1)), raw))

    def _count(self, tokens: list[Token], where: Location) -> list[Token]:
        self.tokens_read += len(tokens)
        if self.tokens_read > MAX_SOURCE_TOKENS:
            raise LimitError(where, f"source too long (more than {MAX_SOURCE_TOKENS} tokens in all)")
        return tokens

    def _include(self, name: str, location: Location, directory: Path | None) -> None:
        if not name:
            raise AssemblyError(location, "#include needs a file name")
        if len(self.including) >= MAX_INCLUDE_DEPTH:
            raise LimitError(location, f"includes nested deeper than {MAX_INCLUDE_DEPTH} files")
        path = self._find(name, directory, location)
        if path in self.including:
            raise AssemblyError(location, f"{excerpt(name, NAME_EXCERPT)} includes itself")
        self.includes += 1
        if self.includes > MAX_INCLUDES:
            raise LimitError(location, f"more than {MAX_INCLUDES} include files read in all")
        budget = MAX_SOURCE_BYTES - self.bytes_read
        try:
            with path.open("rb") as stream:
                data = stream.read(budget + 1)
        except OSError as exc:
            raise AssemblyError(location, f"include file {excerpt(name, NAME_EXCERPT)} cannot be read "
                                f"({exc.strerror or exc})") from None
        self.including.append(path)
        try:
            self.read(data.decode("latin-1"), str(path), path.parent)
        finally:
            self.including.pop()

    def _find(self, name: str, directory: Path | None, location: Location) -> Path:
        """Next to the including file, then on the include path; case-insensitively, because
        TMCL projects come from Windows; only inside the allowed folders."""
        outside = False
        for folder in ([directory] if directory else []) + self.include_path:
            exact = folder / name
            candidates = [exact]
            parent = exact.parent
            if not exact.is_file() and parent.is_dir() and self._inside(parent.resolve()):
                candidates += [entry for entry in parent.iterdir()
                               if entry.name.lower() == exact.name.lower()]
            for candidate in candidates:
                if not candidate.is_file():
                    continue
                resolved = candidate.resolve()
                if self._inside(resolved):
                    return resolved
                outside = True
        if outside or Path(name).is_absolute() or ".." in Path(name).parts:
            raise AssemblyError(location, f"include file {excerpt(name, NAME_EXCERPT)} is outside the "
                                "source's folder, the -I folders and the shipped include folder")
        raise AssemblyError(location, f"include file {excerpt(name, NAME_EXCERPT)} not found")

    def _inside(self, path: Path) -> bool:
        return any(path.is_relative_to(folder) for folder in self.allowed)

    def _define(self, symbol: _Symbol) -> None:
        key = symbol.name.lower()
        previous = self.symbols.get(key)
        if previous is not None:
            kind = "label" if symbol.value is not None else "constant"
            raise AssemblyError(symbol.location, f"duplicate {kind} {excerpt(symbol.name)} "
                                f"(first defined at {previous.location})")
        self.symbols[key] = symbol

    # -- pass 2: constants, then operands ------------------------------------------------------

    def resolve(self, name: str, location: Location) -> int:
        symbol = self.symbols.get(name.lower())
        if symbol is None:
            raise AssemblyError(location, f"undefined symbol {excerpt(name, NAME_EXCERPT)}")
        if symbol.broken:
            raise _Silent
        if symbol.value is None:
            self._constant(symbol)
            if symbol.broken:
                raise _Silent
        assert symbol.value is not None
        return symbol.value

    def _constant(self, first: _Symbol) -> None:
        """Evaluate a constant, the constants it uses first, without recursion: a long chain
        costs a list, not the Python stack."""
        stack = [first]
        while stack:
            symbol = stack[-1]
            assert symbol.expression is not None
            symbol.state = 1
            waiting = None
            for use in names_in(symbol.expression):
                other = self.symbols.get(use.name.lower())
                if other is None or other.value is not None or other.broken:
                    continue
                if other.state == 1:
                    self._fail(stack, other, AssemblyError(
                        other.location, f"constant {excerpt(other.name)} depends on itself"))
                    return
                waiting = other
                break
            if waiting is not None:
                if len(stack) >= MAX_FORWARD_DEPTH:
                    raise LimitError(first.location, f"constant {excerpt(first.name)} needs a chain "
                                     f"of more than {MAX_FORWARD_DEPTH} constants defined after it")
                stack.append(waiting)
                continue
            try:
                symbol.value = evaluate(symbol.expression, self.resolve, columns(symbol.location))
            except _Silent:
                symbol.broken = True
            except LimitError:
                raise
            except AssemblyError as exc:
                symbol.broken = True
                self.errors.extend(exc.errors)
            symbol.state = 2
            stack.pop()

    def _fail(self, stack: list[_Symbol], culprit: _Symbol, error: AssemblyError) -> None:
        self.errors.append(error)
        for symbol in stack:
            symbol.broken, symbol.state = True, 2

    def _field_resolver(self, name: str, location: Location, spec: Field, done: dict[str, int]) -> int:
        return self.resolve(name, location)

    def build(self) -> Program:
        for symbol in list(self.symbols.values()):  # in definition order: chains resolve backwards
            if symbol.expression is not None and symbol.value is None and not symbol.broken:
                self._constant(symbol)
        instructions: list[Instruction] = []
        lines: list[SourceLine] = []
        for address, statement in enumerate(self.statements):
            try:
                ins = encode(statement.opcode, statement.operands, statement.location,
                             self._field_resolver)
            except _Silent:
                continue
            except LimitError:
                raise
            except AssemblyError as exc:
                self.errors.extend(e for e in exc.errors)
                continue
            instructions.append(ins)
            lines.append(SourceLine(address, ins, statement.location, statement.source))
        if self.too_long is not None:
            self.errors.append(AssemblyError(self.too_long,
                                             f"program longer than {PROGRAM_MEMORY_SIZE} commands"))
        if self.errors:
            raise _report(self.errors)
        labels: dict[str, int] = {}
        constants: dict[str, int] = {}
        for symbol in self.symbols.values():
            assert symbol.value is not None
            (labels if symbol.expression is None else constants)[symbol.name] = symbol.value
        return Program(instructions, labels, constants, lines)


def _report(errors: list[AssemblyError]) -> AssemblyError:
    """All errors in source order, at most :data:`MAX_ERRORS` of them."""
    report = AssemblyError.of(errors)
    if len(report.errors) > MAX_ERRORS:
        shown = report.errors[:MAX_ERRORS]
        last = shown[-1].location
        shown.append(AssemblyError(last, f"{len(report.errors) - MAX_ERRORS} more errors not shown"))
        report = AssemblyError(shown[0].location, shown[0].message, shown)
    return report


#: A quoted excerpt in a message (``excerpt`` writes them with repr).
_QUOTED = re.compile(r"'(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\"")


def _quoting_only(source: str, error: AssemblyError) -> AssemblyError:
    """The errors with no text quoted from an included file: an ``#include .env`` must not
    print the secret the file holds in "undefined symbol '...'" (issue 36, N10); the file,
    line and column still say where.  Text of the source itself is quoted as before."""
    def shown(one: AssemblyError) -> AssemblyError:
        if one.location.file == source or not _QUOTED.search(one.message):
            return one
        return type(one)(one.location, _QUOTED.sub("(text of an included file, not shown)",
                                                   one.message))

    errors = [shown(one) for one in error.errors]
    if len(errors) == 1:
        return errors[0]
    return type(error).of(errors)


def assemble(text: str, filename: str = "<source>", include_path: Sequence[str | Path] = (),
             directory: str | Path | None = None, append_stop: bool = False) -> Program:
    """Assemble TMCL source; ``#include`` looks in ``directory`` (the source's folder, whose
    tree includes may come from), ``include_path`` and the shipped include files.
    ``append_stop`` adds a STOP unless the program ends with one."""
    folder = Path(directory) if directory is not None else None
    assembler = _Assembler([Path(p) for p in include_path] + [INCLUDE_DIR], folder)
    try:
        assembler.read(text, filename, folder)
        program = assembler.build()
    except LimitError as exc:
        raise _quoting_only(filename, LimitError(exc.location, exc.message)) from None  # alone
    except AssemblyError as exc:
        raise _quoting_only(filename, exc) from None
    if append_stop and (not program.instructions or program.instructions[-1].opcode != Opcode.STOP):
        program.instructions.append(Instruction(int(Opcode.STOP)))
    return program


def assemble_file(path: str | Path, include_path: Sequence[str | Path] = (),
                  append_stop: bool = False) -> Program:
    source = Path(path)
    if not stat.S_ISREG(os.stat(source).st_mode):  # opening a FIFO waits for a writer (N9)
        raise AssemblyError(Location(str(source), 1), "not a regular file (a FIFO, a device "
                            "or a directory cannot be assembled)")
    with source.open("rb") as stream:
        data = stream.read(MAX_SOURCE_BYTES + 1)
    if len(data) > MAX_SOURCE_BYTES:
        raise LimitError(Location(str(source), 1), f"source longer than {MAX_SOURCE_BYTES >> 20} MiB")
    return assemble(data.decode("latin-1"), str(source), include_path, source.parent, append_stop)


@lru_cache(maxsize=1)
def include_constants() -> dict[str, int]:
    """Every constant of the shipped include files (``APMaxPositioningSpeed``, ``TI_TIMER0``,
    ...), by lower-case name: the names ``tmcl send`` accepts besides the parameter tables'."""
    constants: dict[str, int] = {}
    for path in sorted(p for p in INCLUDE_DIR.iterdir() if p.suffix.lower() in (".tmc", ".inc")):
        try:
            found = assemble(f"#include {path.name}").constants
        except AssemblyError:  # a broken shipped file must not take tmcl send down
            continue
        for name, value in found.items():
            constants.setdefault(name.lower(), value)
    return constants
