"""I14 (interpreter/skipping.py): a moving read r through CALC/CALCX becomes int32(s * r + o),
and its comparison with a COMP value changes only at the reads ``Affine.flips`` names.

Checked by brute force next to each named read and next to random ones, with the
interpreter's own arithmetic (``calculate``) computing the function, so a wrong inversion
or a forgotten wrap shows as two neighbouring reads that compare otherwise with no flip
between them.
"""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from interpreter.machine import calculate
from interpreter.skipping import Affine
from tmcl_spec.commands import CalcOp
from tmcl_spec.numbers import INT32_MAX, INT32_MIN, to_int32

int32s = st.integers(INT32_MIN, INT32_MAX)
edges = st.sampled_from([0, 1, -1, INT32_MAX, INT32_MIN, INT32_MAX - 1, INT32_MIN + 1])


def _through_calc(read: int, sign: int, offset: int) -> int:
    """What the interpreter computes: the read negated (CALC MUL -1) if ``sign`` is -1,
    then CALC ADD ``offset``."""
    value = calculate(CalcOp.MUL, read, -1) if sign < 0 else read
    return calculate(CalcOp.ADD, value, offset)


def _side(value: int) -> int:
    return (value > 0) - (value < 0)


@given(st.sampled_from([1, -1]), int32s | edges, int32s | edges, int32s | edges,
       st.integers(-40, 40))
def test_a_comparison_through_calc_changes_only_at_the_named_reads(
        sign: int, offset: int, compared: int, near: int, around: int) -> None:
    affine = Affine(0, sign, to_int32(offset), compared)
    flips = set(affine.flips())
    for centre in (*flips, near):
        for read in range(centre + around - 3, centre + around + 3):
            here, there = to_int32(read), to_int32(read + 1)
            if here in flips or there in flips or here == INT32_MAX:
                continue  # (the read's own wrap is the forecast's: axes/forecast.py F3)
            before = _side(_through_calc(here, sign, offset) - compared)
            after = _side(_through_calc(there, sign, offset) - compared)
            assert before == after, (sign, offset, compared, here)


def test_the_function_meets_its_comp_value_at_the_first_flip() -> None:
    """The inversion itself: each named read gives the COMP value or one side of the wrap."""
    for sign, offset, compared in [(1, 1000, 0), (-1, 5, INT32_MAX), (-1, INT32_MIN, -7),
                                   (1, INT32_MAX, INT32_MIN)]:
        met, top, bottom = Affine(0, sign, offset, compared).flips()
        assert _through_calc(met, sign, offset) == compared
        assert _through_calc(top, sign, offset) == INT32_MAX
        assert _through_calc(bottom, sign, offset) == INT32_MIN
