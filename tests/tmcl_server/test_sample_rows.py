"""SampleRows: a recording's rows kept compactly (an axis at rest is a run) read exactly as
the list of the same samples would be: length, order, every index and slice, equality."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tmcl_server.sample_rows import Sample, SampleColumn, SampleRows, SampleRun


def _rest(axis: int, level: int) -> tuple[int, int, int, int, float, int, int, int, int, int, int]:
    return (1, axis, level, -level, 0.0, 128, level, 1, 0, 1, 0)


#: A column of a span: per instant, a plain sample (False) or a run of this many (an int).
_pieces = st.lists(st.one_of(st.just(0), st.integers(1, 9)), min_size=1, max_size=8)


def _column(times: list[float], axis: int, pieces: list[int]) -> tuple[SampleColumn, list[Sample]]:
    """A column made of ``pieces`` (0: one sample; n: a run of n) and the samples it means."""
    column, plain, at = SampleColumn(), [], 0
    for level, size in enumerate(pieces):
        if size == 0:
            sample = Sample(times[at], *_rest(axis, level))
            column.append(sample)
            plain.append(sample)
            at += 1
        else:
            column.add_run(SampleRun(times, at, size, _rest(axis, level)))
            plain += [Sample(times[at + k], *_rest(axis, level)) for k in range(size)]
            at += size
    return column, plain


@settings(max_examples=200, deadline=None)
@given(spans=st.lists(st.tuples(st.integers(1, 4), _pieces, st.integers(0, 30)), max_size=4),
       appended=st.integers(0, 3), cuts=st.lists(st.integers(0, 40), max_size=4))
def test_rows_read_as_the_list_of_their_samples(spans: list[tuple[int, list[int], int]],
                                                appended: int, cuts: list[int]) -> None:
    rows, plain = SampleRows(), []
    for axes, pieces, cut in spans:
        instants = sum(size or 1 for size in pieces)
        times = [k / 1000 for k in range(instants)]
        columns = [_column(times, axis, pieces) for axis in range(axes)]
        begin = min(cut, instants - 1)  # a part of the span handed on, as the recorder does
        parts = [column.cut(begin, instants) for column, _ in columns]
        rows.add_span(instants - begin, parts, [column.runs for column, _ in columns])
        plain += [sample for row in zip(*(samples[begin:] for _, samples in columns), strict=True)
                  for sample in row]
    for k in range(appended):
        sample = Sample(9.0 + k, *_rest(7, k))
        rows.append(sample)
        plain.append(sample)
    assert len(rows) == len(plain)
    assert list(rows) == plain and rows == plain and plain == rows
    assert [rows[k] for k in range(len(plain))] == plain
    assert [rows[-k] for k in range(1, len(plain) + 1)] == [plain[-k] for k in range(1, len(plain) + 1)]
    for start in cuts:
        assert rows[start:start + 7] == plain[start:start + 7]
        assert rows[start::3] == plain[start::3]
        assert rows[::-2] == plain[::-2]
    if plain:
        assert rows != plain[:-1] and rows != [*plain[:-1], plain[0]._replace(t=-1.0)]


def test_an_index_past_the_end_is_refused_as_a_list_refuses_it() -> None:
    rows = SampleRows()
    rows.append(Sample(0.0, *_rest(0, 0)))
    assert rows[0] == rows[-1]
    for index in (1, -2):
        with pytest.raises(IndexError):
            rows[index]
