"""One TMCL instruction line as the TMCL-IDE writes it: the parser ``tmcl-asm`` and ``tmcl send``
share, so a line means the same in a source file and on the command line.

``MNEMONIC operand, operand, ...`` with each command's operands in the manual's order
(:data:`tmcl_spec.commands.OPERAND_NAMES`): ``ROR 1, 20000``, ``MST 1``, ``SAP 4, 0, 51200``,
``MVP ABS, 2, 1000``, ``GIO 8, 1``.  Commas may be left out: then spaces separate operands, and
a sign with a space before it and none after starts a new operand (``MVP REL 0 -500``; with
commas, or with spaces on both sides, ``0 -500`` is a subtraction).

Operands are integer expressions over numbers (decimal, ``0x``/``$`` hex, ``0b``/``%`` binary,
``0o`` octal), names (constants, labels, the type field's symbols such as ABS or GE) and the
operators ``| ^ & << >> + - * / // % ~`` with C's precedence (Python's, which is the same for
these), ``/`` and ``//`` truncating toward zero.

Limits, each ending in one clear error: :data:`MAX_TOKENS` tokens in a line's operands,
:data:`MAX_NESTING` levels of parentheses and signs, values within 64 bits at every step
(:data:`VALUE_BITS`), shift counts 0..:data:`MAX_SHIFT`.  They bound the work of any line to
microseconds whatever its text (a "multiplication bomb" ends at its first factor beyond 64 bits).
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

from interpreter.isa import PROGRAM_MEMORY_SIZE, Instruction
from tmcl_spec.commands import CALC_MAX_OPERATION, OPERANDS, CalcOp, Field, Opcode, mnemonic_syntax

#: Tokens a line's operands may have (a real operand has a handful).
MAX_TOKENS = 256
#: Parentheses and unary signs nested at most this deep.
MAX_NESTING = 32
#: Every intermediate value must fit this many bits (sign apart).
VALUE_BITS = 64
#: Shift counts allowed: 0..MAX_SHIFT.
MAX_SHIFT = VALUE_BITS - 1
#: Quoted source text in messages is cut to this many characters (file names: NAME_EXCERPT).
EXCERPT = 40
NAME_EXCERPT = 200

_VALUE_LIMIT = 1 << VALUE_BITS
#: Mnemonics the assembler knows (the commands a program may hold).
MNEMONICS = {op.name: op for op in OPERANDS}


@dataclass(frozen=True, slots=True)
class Location:
    file: str
    line: int
    column: int = 1
    #: The line's place in reading order (include files are read where they are included).
    order: int = field(default=0, compare=False)

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}"

    def at_column(self, column: int) -> Location:
        return Location(self.file, self.line, column, self.order)


class AssemblyError(Exception):
    """Source errors, printed as ``file:line:col: message`` lines like a compiler's.

    ``errors`` holds every error found (in source order); ``location`` and ``message`` are
    the first one's.
    """

    def __init__(self, location: Location, message: str,
                 errors: Sequence[AssemblyError] | None = None) -> None:
        self.location = location
        self.message = message
        self.errors: list[AssemblyError] = list(errors) if errors else [self]
        super().__init__("\n".join(f"{e.location}: {e.message}" for e in self.errors))

    @classmethod
    def of(cls, errors: Sequence[AssemblyError]) -> AssemblyError:
        """One exception carrying several errors, sorted into source order."""
        ordered = sorted(errors, key=lambda e: (e.location.order, e.location.line, e.location.column))
        first = ordered[0]
        return cls(first.location, first.message, ordered)


class LimitError(AssemblyError):
    """A limit was reached (size, depth, nesting): the assembly stops there, and this error is
    the one reported, since what follows it would only be noise."""


def excerpt(text: str, width: int = EXCERPT) -> str:
    """Source text for a message: quoted, on one line, at most ``width`` characters."""
    text = text.strip()
    if len(text) > width:
        text = text[:width - 1] + "…"
    return repr(text)


# -- tokens ------------------------------------------------------------------------------------

_TOKEN = re.compile(r"""
    (?P<space>\s+)
  | (?P<number>(?:0[xX][0-9A-Fa-f]+|0[bB][01]+|0[oO][0-7]+|\$[0-9A-Fa-f]+|[0-9]+)(?P<glued>[A-Za-z0-9_$]*))
  | (?P<name>[A-Za-z_][A-Za-z0-9_]*)
  | (?P<op><<|>>|//|[-+*/%&|^~(),])
  | (?P<bad>.)
""", re.VERBOSE)


@dataclass(slots=True)
class Token:
    kind: str  # "number", "name" or "op"
    text: str
    column: int  # 0-based offset in the line
    spaced: bool  # whitespace (or the line start) before it


#: Longer number texts are beyond VALUE_BITS whatever their leading zeros (and beyond what
#: int() converts: 4,300 digits).
MAX_NUMBER_TEXT = 1_000


def _number(text: str) -> int:
    if text.startswith("$"):
        return int(text[1:], 16)
    if len(text) > 1 and text[0] == "0" and text[1] in "xXbBoO":
        return int(text, 0)
    return int(text, 10)


def tokenize(line: str, start: int, at: Callable[[int], Location]) -> list[Token]:
    """The tokens of ``line[start:]`` (``at`` turns a 0-based column into a Location)."""
    tokens: list[Token] = []
    spaced = True
    for match in _TOKEN.finditer(line, start):
        kind = match.lastgroup or ""
        if kind == "space":
            spaced = True
            continue
        column = match.start()
        if kind == "bad":
            raise AssemblyError(at(column), f"unexpected character {match.group()!r}")
        if kind == "number" and match.group("glued"):  # 12ab, 0x, 0b2
            raise AssemblyError(at(column), f"bad number {excerpt(match.group())}")
        if len(tokens) >= MAX_TOKENS:
            raise LimitError(at(column), f"operands too long (more than {MAX_TOKENS} tokens)")
        tokens.append(Token(kind, match.group(), column, spaced))
        spaced = False
    return tokens


# -- expressions -------------------------------------------------------------------------------

@dataclass(slots=True)
class Number:
    value: int
    column: int


@dataclass(slots=True)
class Name:
    name: str
    column: int


@dataclass(slots=True)
class Unary:
    op: str
    operand: Node
    column: int


@dataclass(slots=True)
class Binary:
    op: str
    left: Node
    right: Node
    column: int


Node = Number | Name | Unary | Binary

#: Binding power of the binary operators (C's order; Python's for these).
_PRECEDENCE = {"|": 1, "^": 2, "&": 3, "<<": 4, ">>": 4, "+": 5, "-": 5,
               "*": 6, "/": 6, "//": 6, "%": 6}
_UNARY = frozenset("+-~")


class _ExpressionParser:
    """Precedence climbing over one operand's tokens; nesting is counted, never unbounded."""

    def __init__(self, tokens: list[Token], at: Callable[[int], Location], end_column: int) -> None:
        self.tokens = tokens
        self.at = at
        self.end_column = end_column
        self.i = 0
        self.depth = 0

    def parse(self) -> Node:
        node = self.binary(1)
        if self.i < len(self.tokens):
            token = self.tokens[self.i]
            if token.text == ")":
                raise AssemblyError(self.at(token.column), "unbalanced ')'")
            raise AssemblyError(self.at(token.column),
                                f"missing operator or comma before {excerpt(token.text)}")
        return node

    def binary(self, min_power: int) -> Node:
        left = self.unary()
        while self.i < len(self.tokens):
            token = self.tokens[self.i]
            power = _PRECEDENCE.get(token.text) if token.kind == "op" else None
            if power is None or power < min_power:
                break
            self.i += 1
            right = self.binary(power + 1)
            left = Binary(token.text, left, right, token.column)
        return left

    def unary(self) -> Node:
        if self.i >= len(self.tokens):
            if not self.tokens:
                raise AssemblyError(self.at(self.end_column), "empty operand")
            last = self.tokens[-1]
            raise AssemblyError(self.at(last.column), f"missing operand after {excerpt(last.text)}")
        token = self.tokens[self.i]
        self.i += 1
        if token.kind == "number":
            if len(token.text) > MAX_NUMBER_TEXT:  # int() refuses past 4,300 digits (N9)
                raise AssemblyError(self.at(token.column),
                                    f"number {excerpt(token.text)} beyond {VALUE_BITS} bits")
            value = _number(token.text)
            if value >= _VALUE_LIMIT:
                raise AssemblyError(self.at(token.column),
                                    f"number {excerpt(token.text)} beyond {VALUE_BITS} bits")
            return Number(value, token.column)
        if token.kind == "name":
            return Name(token.text, token.column)
        if token.text == "%" and self.i < len(self.tokens):  # %1010: binary, where a value is due
            digits = self.tokens[self.i]
            if (digits.kind == "number" and not digits.spaced and set(digits.text) <= {"0", "1"}):
                self.i += 1
                return Number(int(digits.text, 2), token.column)
        if token.text in _UNARY or token.text == "(":
            self.depth += 1
            if self.depth > MAX_NESTING:
                raise LimitError(self.at(token.column),
                                 f"expression nested deeper than {MAX_NESTING} levels")
            if token.text == "(":
                inner = self.binary(1)
                if self.i >= len(self.tokens) or self.tokens[self.i].text != ")":
                    raise AssemblyError(self.at(token.column), "unbalanced '('")
                self.i += 1
                node: Node = inner
            else:
                node = Unary(token.text, self.unary(), token.column)
            self.depth -= 1
            return node
        raise AssemblyError(self.at(token.column), f"unexpected {excerpt(token.text)}")


def parse_expression(tokens: list[Token], at: Callable[[int], Location], end_column: int) -> Node:
    return _ExpressionParser(tokens, at, end_column).parse()


def names_in(node: Node) -> Iterator[Name]:
    """The names an expression uses, left to right."""
    stack = [node]
    while stack:
        top = stack.pop()
        if isinstance(top, Name):
            yield top
        elif isinstance(top, Unary):
            stack.append(top.operand)
        elif isinstance(top, Binary):
            stack += (top.right, top.left)


def _truncated_division(a: int, b: int) -> int:
    quotient = abs(a) // abs(b)
    return quotient if (a < 0) == (b < 0) else -quotient


#: How a name becomes a value: (name, where it is written) -> value, AssemblyError if unknown.
Resolver = Callable[[str, Location], int]


def evaluate(node: Node, resolve: Resolver, at: Callable[[int], Location]) -> int:
    """The value of an expression; every step within :data:`VALUE_BITS` bits."""
    if isinstance(node, Number):
        return node.value
    if isinstance(node, Name):
        return resolve(node.name, at(node.column))
    if isinstance(node, Unary):
        value = evaluate(node.operand, resolve, at)
        return -value if node.op == "-" else ~value if node.op == "~" else value
    left = evaluate(node.left, resolve, at)
    right = evaluate(node.right, resolve, at)
    op = node.op
    if op in ("/", "//", "%") and right == 0:
        raise AssemblyError(at(node.column), "division by zero in expression")
    if op in ("<<", ">>") and not 0 <= right <= MAX_SHIFT:
        raise AssemblyError(at(node.column), f"shift count {right} outside 0..{MAX_SHIFT}")
    if op == "+":
        result = left + right
    elif op == "-":
        result = left - right
    elif op == "*":
        result = left * right if abs(left).bit_length() + abs(right).bit_length() <= VALUE_BITS + 1 \
            else _VALUE_LIMIT  # beyond the limit whatever the exact product: do not compute it
    elif op in ("/", "//"):
        result = _truncated_division(left, right)
    elif op == "%":
        result = left - right * _truncated_division(left, right)
    elif op == "&":
        result = left & right
    elif op == "|":
        result = left | right
    elif op == "^":
        result = left ^ right
    elif op == "<<":
        result = left << right
    else:
        result = left >> right
    if not -_VALUE_LIMIT < result < _VALUE_LIMIT:
        raise AssemblyError(at(node.column), f"value beyond {VALUE_BITS} bits in expression")
    return result


# -- instruction lines -------------------------------------------------------------------------

@dataclass(slots=True)
class Operand:
    """One operand as written: its text, where it starts, and its parsed expression."""

    text: str
    location: Location
    tree: Node


def _starts_operand(token: Token, following: Token | None) -> bool:
    """Without commas: does ``token`` begin a new operand?  A value does; a sign does when a
    space stands before it and none after (``0 -500``)."""
    if token.kind in ("number", "name") or token.text == "(":
        return True
    return (token.text in _UNARY or token.text == "%") and token.spaced and \
        following is not None and not following.spaced


def _ends_operand(token: Token) -> bool:
    return token.kind in ("number", "name") or token.text == ")"


def split_operands(line: str, start: int, at: Callable[[int], Location],
                   count: Callable[[list[Token], Location], list[Token]] | None = None) -> list[Operand]:
    """The operands written in ``line[start:]``, split at commas or, without commas, at spaces
    (``count`` sees the tokens first: the assembler's budget for a whole source)."""
    tokens = tokenize(line, start, at)
    if count is not None:
        count(tokens, at(start))
    if not tokens:
        return []
    groups: list[list[Token]] = [[]]
    starts = [tokens[0].column]  # where each operand begins (after its comma when empty)
    depth = 0
    commas = any(t.text == "," for t in tokens)
    for index, token in enumerate(tokens):
        if token.text == ",":
            if depth > 0:
                raise AssemblyError(at(token.column), "unbalanced '('")
            groups.append([])
            starts.append(token.column + 1)
            continue
        current = groups[-1]
        if (not commas and depth == 0 and current and token.spaced and _ends_operand(current[-1])
                and _starts_operand(token, tokens[index + 1] if index + 1 < len(tokens) else None)):
            groups.append(current := [])
            starts.append(token.column)
        if token.text == "(":
            depth += 1
        elif token.text == ")":
            depth -= 1
        current.append(token)
    operands = []
    errors: list[AssemblyError] = []
    for group, first in zip(groups, starts, strict=True):
        if group:
            first = group[0].column
        last = group[-1].column + len(group[-1].text) if group else first
        try:
            operands.append(Operand(line[first:last], at(first), parse_expression(group, at, last)))
        except LimitError:
            raise
        except AssemblyError as exc:
            errors.append(exc)
    if errors:
        raise AssemblyError.of(errors)
    return operands


def check_count(opcode: Opcode, operands: Sequence[Operand], location: Location,
                written: str | None = None) -> None:
    specs = OPERANDS[opcode]
    if len(operands) != len(specs):
        shown = f" in {excerpt(written)}" if written else ""
        raise AssemblyError(location, f"{opcode.name} takes {len(specs)} operand(s), got "
                            f"{len(operands)}{shown} (the manual's form: {mnemonic_syntax(opcode)})")


#: Resolves a name in one operand: (name, where, the field, the fields evaluated so far).
FieldResolver = Callable[[str, Location, Field, dict[str, int]], int]


def field_value(opcode: Opcode, spec: Field, operand: Operand, resolve: Resolver) -> int:
    """One operand's value for its field, checked against the field's range."""
    if spec.symbols is not None:
        allowed = list(spec.symbols)
        if opcode == Opcode.CALC:
            allowed = [op for op in CalcOp if op <= CALC_MAX_OPERATION]
        names = {member.name: member.value for member in allowed}
        tree = operand.tree
        if isinstance(tree, Name):
            symbolic = names.get(tree.name.upper())
            if symbolic is not None:
                return symbolic
            if tree.name.upper() in spec.symbols.__members__:
                raise AssemblyError(operand.location, f"{tree.name} is not allowed in {opcode.name} "
                                    f"(expected {'/'.join(names)})")
        value = operand_value(operand, resolve)
        if value not in names.values():
            raise AssemblyError(operand.location, f"operand {excerpt(operand.text)} out of range for "
                                f"{opcode.name} (expected {'/'.join(names)})")
        return value
    value = operand_value(operand, resolve)
    if spec.slot != "value":
        if not 0 <= value <= 255:
            raise AssemblyError(operand.location,
                                f"operand {excerpt(operand.text)} = {value} out of range 0..255")
        return value
    if spec.address and not 0 <= value < PROGRAM_MEMORY_SIZE:
        raise AssemblyError(operand.location, f"address {excerpt(operand.text)} = {value} outside "
                            f"program memory 0..{PROGRAM_MEMORY_SIZE - 1}")
    if not -(2**31) <= value <= 2**32 - 1:
        raise AssemblyError(operand.location,
                            f"operand {excerpt(operand.text)} = {value} does not fit 32 bits")
    return value - 2**32 if value >= 2**31 else value


def columns(line: Location) -> Callable[[int], Location]:
    """Turns a 0-based column of ``line`` into a Location."""
    return lambda column: line.at_column(column + 1)


def operand_value(operand: Operand, resolve: Resolver) -> int:
    return evaluate(operand.tree, resolve, columns(operand.location))


#: The order fields are evaluated in: the bank (motor field) first, since a global parameter's
#: name depends on its bank.
_EVALUATION_ORDER = {"motor": 0, "value": 1, "type": 2}


def encode(opcode: Opcode, operands: Sequence[Operand], location: Location,
           resolve: FieldResolver, written: str | None = None) -> Instruction:
    """The instruction a line stands for; every error of the line in one AssemblyError."""
    check_count(opcode, operands, location, written)
    specs = OPERANDS[opcode]
    fields = {"type": 0, "motor": 0, "value": 0}
    done: dict[str, int] = {}
    errors: list[AssemblyError] = []
    for spec, operand in sorted(zip(specs, operands, strict=True),
                                key=lambda pair: _EVALUATION_ORDER[pair[0].slot]):
        try:
            fields[spec.slot] = done[spec.slot] = field_value(
                opcode, spec, operand,
                lambda name, where, spec=spec: resolve(name, where, spec, dict(done)))  # type: ignore[misc]
        except LimitError:
            raise
        except AssemblyError as exc:
            errors.extend(exc.errors)
    if errors:
        raise AssemblyError.of(errors)
    return Instruction(int(opcode), fields["type"], fields["motor"], fields["value"])
