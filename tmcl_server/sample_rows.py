"""A recording's samples, kept compactly and made when read.

Six axes sampled every millisecond are 6,000 rows a simulated second; built as named tuples
and kept in a list, they cost more than simulating the module (3.6 million rows for ten
minutes: about 4 CPU seconds and half a gigabyte however they are made), and most of them
are axes at rest, whose rows differ only in their time.  So an axis's stretch at rest is
kept as one :class:`SampleRun`, a moving axis's samples as arrays of numbers
(:class:`MovingRun`: kept tuples are objects the garbage collector walks again and again),
and :class:`SampleRows` makes each row when it is read: a test that looks at a few rows pays
for a few, and reading them all costs what keeping them all did.  The rows read are the
same :class:`Sample` tuples, in the same order, as a list would hold
(tests/tmcl_server/test_record.py compares them with rows sampled one by one).
"""

from __future__ import annotations

from array import array
from bisect import bisect_right
from collections.abc import Iterator, Sequence
from itertools import chain, islice, repeat
from typing import NamedTuple, overload

_new = tuple.__new__


class Sample(NamedTuple):
    """One axis at one instant of simulated time (a named tuple: a recorder builds one per
    axis and instant, a thousand a simulated second at 1 ms for each axis, and a tuple costs
    a tenth of a frozen dataclass to build)."""

    t: float  # simulated seconds
    module: int  # the module's address (slot)
    axis: int
    position: int
    velocity: int
    acceleration: float  # velocity units per second, over the last sample interval
    current: int
    target: int
    reached: int
    left: int
    right: int
    home: int


class Run:
    """Consecutive samples of one axis kept as one item of a column (``count`` of them, at
    ``times[start:]``), made when read."""

    __slots__ = ("start", "times")

    def __init__(self, times: list[float], start: int) -> None:
        self.times = times
        self.start = start

    @property
    def count(self) -> int:
        raise NotImplementedError

    def samples(self) -> Iterator[Sample]:
        raise NotImplementedError

    def sample(self, k: int) -> Sample:
        raise NotImplementedError

    def cut(self, begin: int, end: int) -> Run:
        """Its samples ``begin`` to ``end`` (exclusive) as a run of their own."""
        raise NotImplementedError


class SampleRun(Run):
    """``count`` samples of one axis that differ only in their time, ``times[start:]``: the
    rest of a sample's fields (``rest``, everything after ``t``) are the same in each."""

    __slots__ = ("_count", "rest")

    def __init__(self, times: list[float], start: int, count: int,
                 rest: tuple[int, int, int, int, float, int, int, int, int, int, int]) -> None:
        super().__init__(times, start)
        self._count = count
        self.rest = rest

    @property
    def count(self) -> int:
        return self._count

    def samples(self) -> Iterator[Sample]:
        start = self.start
        # (zip makes each row's tuple in C, and reuses it once copied)
        return map(_new, repeat(Sample), zip(self.times[start:start + self._count],
                                             *map(repeat, self.rest), strict=False))

    def sample(self, k: int) -> Sample:
        return _new(Sample, (self.times[self.start + k], *self.rest))

    def cut(self, begin: int, end: int) -> SampleRun:
        return SampleRun(self.times, self.start + begin, end - begin, self.rest)


class MovingRun(Run):
    """Samples of a moving axis at consecutive instants whose current, target and switch
    levels are the same (``fixed``): its positions, velocities, accelerations and "reached"
    flags as arrays of numbers (a recorder at 1 ms keeps a thousand a simulated second per
    moving axis: as tuples, each is an object the garbage collector walks again and again)."""

    __slots__ = ("accelerations", "axis", "fixed", "module", "positions", "reached", "velocities")

    def __init__(self, times: list[float], start: int, module: int, axis: int,
                 fixed: tuple[int, int, bool, bool, bool]) -> None:
        super().__init__(times, start)
        self.module = module
        self.axis = axis
        self.fixed = fixed  # current, target, left, right, home
        self.positions = array("q")
        self.velocities = array("q")
        self.accelerations = array("d")
        self.reached = array("b")

    @property
    def count(self) -> int:
        return len(self.positions)

    def samples(self) -> Iterator[Sample]:
        return map(self.sample, range(len(self.positions)))

    def sample(self, k: int) -> Sample:
        current, target, left, right, home = self.fixed
        return _new(Sample, (self.times[self.start + k], self.module, self.axis,
                             self.positions[k], self.velocities[k], self.accelerations[k],
                             current, target, self.reached[k], int(left), int(right),
                             int(home)))

    def cut(self, begin: int, end: int) -> MovingRun:
        part = MovingRun(self.times, self.start + begin, self.module, self.axis, self.fixed)
        part.positions = self.positions[begin:end]
        part.velocities = self.velocities[begin:end]
        part.accelerations = self.accelerations[begin:end]
        part.reached = self.reached[begin:end]
        return part


Item = Sample | Run


class SampleColumn(list[Item]):
    """One axis's samples of a span of instants, in time order: samples, and runs among them
    (``runs``: whether any, so a column of samples alone is cut by a plain slice)."""

    __slots__ = ("runs",)

    def __init__(self) -> None:
        super().__init__()
        self.runs = False

    def add_run(self, run: Run) -> None:
        """Add ``run`` (a moving run may still grow: it counts as it is when cut)."""
        self.append(run)
        self.runs = True

    def reset(self) -> None:
        self.clear()
        self.runs = False

    def cut(self, begin: int, end: int) -> list[Item]:
        """The items of its instants ``begin`` to ``end`` (exclusive), runs cut to fit."""
        if not self.runs:
            return self[begin:end]
        items: list[Item] = []
        at = 0
        for item in self:
            size = item.count if isinstance(item, Run) else 1
            low, high = max(begin, at), min(end, at + size)
            if low < high:
                whole = low == at and high == at + size
                items.append(item if whole else item.cut(low - at, high - at))  # type: ignore[union-attr]
            at += size
            if at >= end:
                break
        return items


def _samples(items: list[Item], runs: bool) -> Iterator[Sample]:
    if not runs:
        return iter(items)  # type: ignore[arg-type]
    return chain.from_iterable(item.samples() if isinstance(item, Run) else (item,)
                               for item in items)


def _item_at(items: list[Item], runs: bool, k: int) -> Sample:
    if not runs:
        return items[k]  # type: ignore[return-value]
    for item in items:
        if isinstance(item, Run):
            if k < item.count:
                return item.sample(k)
            k -= item.count
        elif k == 0:
            return item  # type: ignore[return-value]
        else:
            k -= 1
    raise IndexError(k)


class _Span(NamedTuple):
    """Rows from ``first_row`` on, one column per recorded axis (instant by instant, then
    column by column); ``runs[c]``: column ``c`` may hold runs."""

    first_row: int
    columns: list[list[Item]]
    runs: list[bool]

    def rows(self) -> Iterator[Sample]:
        columns = [_samples(items, runs) for items, runs in zip(self.columns, self.runs,
                                                                 strict=True)]
        return chain.from_iterable(zip(*columns, strict=True))

    def row(self, k: int) -> Sample:
        instant, column = divmod(k, len(self.columns))
        return _item_at(self.columns[column], self.runs[column], instant)


class SampleRows(Sequence[Sample]):
    """A recording's rows, instant by instant, module by module, axis by axis: a read-only
    sequence whose rows are made when read; equal to a list (or any sequence) of the same
    samples.  The recorder adds spans (:meth:`add_span`) or single rows (:meth:`append`)."""

    def __init__(self) -> None:
        self._spans: list[_Span] = []
        self._starts: list[int] = []
        self._length = 0

    def add_span(self, instants: int, columns: list[list[Item]], runs: list[bool]) -> None:
        if instants <= 0 or not columns:
            return
        self._spans.append(_Span(self._length, columns, runs))
        self._starts.append(self._length)
        self._length += instants * len(columns)  # last: a reader on another thread sees
        # no row before its span is there

    def append(self, sample: Sample) -> None:
        spans = self._spans
        if spans and len(spans[-1].columns) == 1 and not spans[-1].runs[0]:
            spans[-1].columns[0].append(sample)  # (one column: its rows are the span's)
            self._length += 1
        else:
            self.add_span(1, [[sample]], [False])

    def __len__(self) -> int:
        return self._length

    def __iter__(self) -> Iterator[Sample]:
        return islice(chain.from_iterable(span.rows() for span in list(self._spans)),
                      self._length)

    @overload
    def __getitem__(self, index: int) -> Sample: ...

    @overload
    def __getitem__(self, index: slice) -> list[Sample]: ...

    def __getitem__(self, index: int | slice) -> Sample | list[Sample]:
        if isinstance(index, slice):
            start, stop, step = index.indices(self._length)
            if step == 1:
                return list(islice(self, start, max(start, stop)))
            return [self[k] for k in range(start, stop, step)]
        if index < 0:
            index += self._length
        if not 0 <= index < self._length:
            raise IndexError("sample index out of range")
        span = self._spans[bisect_right(self._starts, index) - 1]
        return span.row(index - span.first_row)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Sequence) or isinstance(other, str | bytes):
            return NotImplemented
        return len(self) == len(other) and all(a == b for a, b in zip(self, other,
                                                                        strict=True))

    __hash__ = None  # type: ignore[assignment]  # (it grows: not hashable, as a list)

    def __repr__(self) -> str:
        return f"SampleRows({list(self)!r})"
