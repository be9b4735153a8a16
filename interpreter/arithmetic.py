"""CALC and CALCX arithmetic: the manual's operations on signed 32-bit values, C's way.

Pure functions of two values, apart from the interpreter that applies them (the dispatch
loop calls :func:`calculate` for the operations it does not inline) and usable without
one (the pass analysis' tests check their algebra against it).
"""

from __future__ import annotations

from tmcl_spec.commands import CalcOp
from tmcl_spec.numbers import to_int32 as wrap32


def _c_div(a: int, b: int) -> int:
    """C division (truncates toward zero); x/0 gives 0 like an ARM SDIV without the trap."""
    if b == 0:
        return 0
    q = abs(a) // abs(b)
    return wrap32(q if (a < 0) == (b < 0) else -q)


def _c_mod(a: int, b: int) -> int:
    """C remainder (sign of the dividend); x%0 leaves x, as a - (a/0)*0 does on ARM."""
    if b == 0:
        return a
    return wrap32(a - b * _c_div(a, b))


def calculate(operation: int, a: int, b: int) -> int:
    """CALC/CALCX arithmetic on signed 32-bit values; unknown operations leave ``a``."""
    if operation == CalcOp.ADD:
        return wrap32(a + b)
    if operation == CalcOp.SUB:
        return wrap32(a - b)
    if operation == CalcOp.MUL:
        return wrap32(a * b)
    if operation == CalcOp.DIV:
        return _c_div(a, b)
    if operation == CalcOp.MOD:
        return _c_mod(a, b)
    if operation == CalcOp.AND:
        return wrap32(a & b)
    if operation == CalcOp.OR:
        return wrap32(a | b)
    if operation == CalcOp.XOR:
        return wrap32(a ^ b)
    if operation == CalcOp.NOT:
        return wrap32(~a)
    if operation == CalcOp.LOAD:
        return wrap32(b)
    return a
