"""The recorder: what the axes did, sampled on simulated time at a chosen resolution.

A :class:`Recorder` attached to a simulation is called by the simulation before it brings any
module up to a time (``Simulation.run_due`` and ``sync_module``, which every advance passes
through): it brings each recorded module once to the last sample instant up to that time
(``module.advance_to(last)``) and samples each axis on the way, at an instant when a command
or an event is about to bring the axis past it (the module's ``sampler`` hook) or once the
module has reached the last instant (:class:`_ModuleSampler`), and writes a :class:`Sample`.
Nothing but its own motion changes an axis between two of those calls, and the axes are
exact at any instant, so a sample is what stopping the module at its instant would read, a
program's batches go on through the instants, and event times do not move
(tests/tmcl_server/test_record.py checks both against the stepping interpreter).  On the
virtual clock the samples are therefore exact; on a real clock they are exact too, only
computed when the simulation next catches up (a request, an internal event, or the
recorder's own wake-up).

Each sample holds position, velocity (AP 3 units), acceleration (the velocity's difference
quotient over the last sample interval), motor current, target, position-reached and the
three switch levels.  Module events (target reached, switches, stall, interrupts, program
start/stop) are kept as :class:`Mark` rows.  ``tmcl-server --record FILE`` writes both to a
CSV or JSONL file (by extension); ``SimulatorThread.record()`` keeps them for a test.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from axes.interface import FOREVER
from tmcl_server.sample_rows import Sample, SampleColumn, SampleRows, SampleRun
from tmcl_spec.numbers import NS_PER_S, seconds_to_ns

if TYPE_CHECKING:
    from axes.interface import AxisSample
    from tmcl_server.module import ModuleEvent, TMCLModule
    from tmcl_server.simulation import Simulation

#: Default sample interval (seconds of simulated time).
DEFAULT_RESOLUTION_S = 0.01


@dataclass(frozen=True, slots=True)
class Mark:
    """A module event at the instant it happened."""

    t: float
    module: int
    axis: int | None
    event: str
    data: dict[str, Any] = field(default_factory=dict)

    @property
    def detail(self) -> str:
        return " ".join(f"{k}={v}" for k, v in self.data.items() if v is not None)


SAMPLE_FIELDS: tuple[str, ...] = Sample._fields
#: CSV columns: a sample fills the sample fields, an event row t/module/axis/event/detail.
CSV_COLUMNS = (*SAMPLE_FIELDS, "event", "detail")


class Recorder:
    """Samples chosen axes of chosen modules every ``resolution`` seconds of simulated time."""

    def __init__(self, simulation: Simulation, resolution: float = DEFAULT_RESOLUTION_S,
                 modules: Iterable[int] | None = None, axes: Iterable[int] | None = None,
                 on_sample: Callable[[Sample], None] | None = None,
                 on_mark: Callable[[Mark], None] | None = None, keep: bool = True) -> None:
        if resolution <= 0:
            raise ValueError("the recording resolution must be positive")
        self.simulation = simulation
        self.step_ns = max(1, seconds_to_ns(resolution))
        wanted = None if modules is None else set(modules)
        self.modules = [m for m in simulation.modules if wanted is None or m.slot in wanted]
        if not self.modules:
            raise ValueError(f"no module with address {sorted(wanted or ())} to record")
        self.axes = list(axes) if axes is not None else None
        for module in self.modules:
            for index in self._axes_of(module):
                if not 0 <= index < len(module.axes):
                    raise ValueError(f"module {module.slot} has no axis {index}")
        self.on_sample = on_sample
        self.on_mark = on_mark
        self.keep = keep
        #: Kept compactly (an axis at rest is one run), each row made when read.
        self.rows = SampleRows()
        self.marks: list[Mark] = []
        self.next_ns = simulation.now_ns
        #: Instants a real clock made the recorder skip (it could not keep up).
        self.skipped = 0
        #: A moving axis's samples of a stretch at once where its core has the closed form
        #: (Axis.samples_at); False: each read from the axis brought to its instant (the
        #: reference tests/tmcl_server/test_record.py compares with).
        self.closed_forms = True
        #: Samples a closed form gave (how far :attr:`closed_forms` reached).
        self.at_once = 0
        self._last_velocity: dict[tuple[int, int], int] = {}
        #: (module, axis) -> (the module's epoch, the sample) of an axis at rest: its samples
        #: are the same until something intervenes (AxisRig.resting).
        self._resting: dict[tuple[int, int], tuple[int, AxisSample]] = {}
        self._listeners: list[tuple[TMCLModule, Callable[[ModuleEvent], None]]] = []
        #: While a span is taken with callbacks for samples and marks: the sampler whose
        #: samples before a mark are handed on first.
        self._ordered: _ModuleSampler | None = None

    def _axes_of(self, module: TMCLModule) -> list[int]:
        return self.axes if self.axes is not None else list(range(len(module.axes)))

    # -- attaching ----------------------------------------------------------------------------

    def start(self) -> Recorder:
        if self.simulation.recorder is not None:
            raise RuntimeError("a recorder is already running on this simulation")
        now = self.simulation.now_ns
        self.next_ns = -(-now // self.step_ns) * self.step_ns  # instants are multiples of the step
        for module in self.modules:
            listener = self._listener(module)
            module.listeners.append(listener)
            self._listeners.append((module, listener))
        self.simulation.recorder = self
        self.catch_up(now)  # the first sample, if the start is an instant
        return self

    def stop(self) -> SampleRows:
        """Record up to the present, detach, and return the samples."""
        if self.simulation.recorder is self:
            self.catch_up(self.simulation.now_ns)
            self.simulation.recorder = None
        for module, listener in self._listeners:
            if listener in module.listeners:
                module.listeners.remove(listener)
        self._listeners.clear()
        return self.rows

    def _listener(self, module: TMCLModule) -> Callable[[ModuleEvent], None]:
        def on_event(event: ModuleEvent) -> None:
            if event.axis is not None and self.axes is not None and event.axis not in self.axes:
                return
            if self._ordered is not None:
                self._before_mark(event.time_ns)
            mark = Mark(event.time_ns / NS_PER_S, module.slot, event.axis, event.kind,
                        {k: v for k, v in event.data.items() if v is not None})
            if self.keep:
                self.marks.append(mark)
            if self.on_mark is not None:
                self.on_mark(mark)
        return on_event

    # -- sampling -----------------------------------------------------------------------------

    def catch_up(self, t_ns: int, max_samples: int | None = None) -> int:
        """Take every sample due up to ``t_ns``, each module brought once to the last instant.

        The modules run on through the instants (a program's batches are not cut there):
        each axis is sampled at an instant when it is about to be brought past it (a command
        or an event touches it, :class:`_ModuleSampler`) or at the end, when the module has
        reached the last instant; nothing but its own motion changes an axis in between, so
        a sample is what stepping the module to its instant reads.  With ``max_samples`` at
        most that many instants are taken (a real clock's server bounds its work per turn);
        returns the time up to which every sample is taken: ``t_ns``, or less when the
        budget ran out.
        """
        first = self.next_ns
        if first > t_ns:
            return t_ns
        count = (t_ns - first) // self.step_ns + 1
        if max_samples is not None and count > max_samples:
            count = max_samples
            t_ns = first + count * self.step_ns - 1  # the rest next time
        last = first + (count - 1) * self.step_ns
        samplers = [_ModuleSampler(self, module, first, last) for module in self.modules]
        # With callbacks for both, samples and marks reach them in time order (a file): a
        # mark first takes the samples before it (one module; several step instant by instant)
        ordered = self.on_sample is not None and self.on_mark is not None
        if ordered and len(samplers) > 1:
            for instant in range(first, last + 1, self.step_ns):
                self._take(samplers, instant, instant)
        else:
            self._ordered = samplers[0] if ordered else None
            try:
                self._take(samplers, first, last)
            finally:
                self._ordered = None
        self.next_ns = last + self.step_ns
        for module in self.modules:
            self.simulation.replan(module)  # stepping may have handled or planned events
        return t_ns

    def _take(self, samplers: list[_ModuleSampler], first: int, last: int) -> None:
        """Bring each module to ``last`` with its sampler attached, sample the rest of the
        instants from ``first`` and hand them on in time order."""
        for sampler in samplers:
            sampler.open(first, last)
        for sampler in samplers:
            module = sampler.module
            module.sampler = sampler
            try:
                due = module.next_event_ns()
                if module.now_ns < last or (due is not None and due <= last):
                    module.advance_to(last)
                sampler.finish()
            finally:
                module.sampler = None
        self._hand_on(samplers, (last - first) // self.step_ns + 1)

    def _hand_on(self, samplers: list[_ModuleSampler], upto: int) -> None:
        """Keep and pass on the samples of the instants before index ``upto`` of the span
        not handed on yet: instant by instant, module by module, axis by axis."""
        columns = [column for sampler in samplers for column in sampler.columns]
        done = samplers[0].handed
        if upto <= done:
            return
        pieces = [column.cut(done, upto) for column in columns]
        runs = [column.runs for column in columns]
        for sampler in samplers:
            sampler.handed = upto
        if self.keep and self.on_sample is None:
            self.rows.add_span(upto - done, pieces, runs)  # the rows are made when read
            return
        span = SampleRows()
        span.add_span(upto - done, pieces, runs)
        for sample in span:
            if self.keep:
                self.rows.append(sample)
            if self.on_sample is not None:
                self.on_sample(sample)

    def _before_mark(self, time_ns: int) -> None:
        """A mark at ``time_ns`` is about to be passed on: the samples before it go first."""
        sampler = self._ordered
        if sampler is not None:
            sampler.take_all(time_ns)
            self._hand_on([sampler], sampler.taken_before(time_ns))

    def skip_to(self, t_ns: int) -> None:
        """A real clock ran away from the recorder: the instants before ``t_ns`` are not
        taken (a gap in the record, counted in :attr:`skipped`)."""
        if self.next_ns < t_ns:
            missed = -(-(t_ns - self.next_ns) // self.step_ns)
            self.skipped += missed
            self.next_ns += missed * self.step_ns


class _ModuleSampler:
    """One module's axes sampled over one span of instants (``module.sampler`` while the
    recorder brings the module through them, ``ModuleCore.AxisSampler``).

    Exact because nothing changes an axis without the module telling the sampler first: a
    command reaches an axis through ``ModuleCore.axis`` and an event through
    ``ModuleCore.step_to``, and both call :meth:`before_move` with the instant the axis is
    brought to; the instants before it are sampled then, from the axis brought to each of
    them (``ModuleCore.axis_at``: the module is past them, the axis is not, and only its own
    motion moved it since it was last touched).  An axis at rest is read once: nothing
    changes what it reads until it is touched again (``AxisRig.resting``), and across spans
    while the module's epoch (every command that changed something, every event, every
    host request and world change) stays what it was when it was read.
    """

    def __init__(self, recorder: Recorder, module: TMCLModule, first: int, last: int) -> None:
        self.recorder = recorder
        self.module = module
        self.indices = recorder._axes_of(module)
        self.due = [FOREVER] * len(module.axes)
        #: Per recorded axis (in ``indices`` order), its samples of the span so far.
        self.columns = [SampleColumn() for _ in self.indices]
        self._column = dict(zip(self.indices, self.columns, strict=True))
        self.first = first
        self.last = last
        #: The span's instants in seconds (a sample's ``t``), made when first needed.
        self._times: list[float] | None = None
        #: How many instants of the span were handed on (kept, passed to on_sample).
        self.handed = 0
        #: The module is between commands and events (finish): an axis found at rest may be
        #: kept under the present epoch (any later change counts in it).
        self._settled = False

    def open(self, first: int, last: int) -> None:
        self.first, self.last, self.handed = first, last, 0
        self._times = None
        for index, column in zip(self.indices, self.columns, strict=True):
            column.reset()
            self.due[index] = first

    def taken_before(self, t_ns: int) -> int:
        """How many instants of the span lie before ``t_ns``."""
        if t_ns <= self.first:
            return 0
        return min((t_ns - 1 - self.first) // self.recorder.step_ns + 1,
                   (self.last - self.first) // self.recorder.step_ns + 1)

    def before_move(self, index: int, t_ns: int) -> None:
        column = self._column.get(index)
        if column is None:
            self.due[index] = FOREVER
            return
        step = self.recorder.step_ns
        instant = self.due[index]
        end = min(t_ns - 1, self.last)
        if instant > end:
            return
        count = (end - instant) // step + 1
        after = instant + count * step
        self.due[index] = after if after <= self.last else FOREVER
        self._sample(index, column, instant, count)

    def take_all(self, t_ns: int) -> None:
        """Sample every axis at the instants before ``t_ns`` (the module has reached it)."""
        for index in self.indices:
            if self.due[index] < t_ns:
                self.before_move(index, t_ns)

    def finish(self) -> None:
        """The module has reached the span's last instant and rests there: the rest of the
        samples (an axis found at rest now is kept as read, for the spans after)."""
        self._settled = True
        try:
            self.take_all(self.last + 1)
        finally:
            self._settled = False

    def _sample(self, index: int, column: SampleColumn, instant: int, count: int) -> None:
        """Axis ``index`` at ``count`` instants from ``instant`` (no command or event touches
        it before the last of them)."""
        recorder = self.recorder
        module = self.module
        step = recorder.step_ns
        key = (module.slot, index)
        slot = module.slot
        previous = recorder._last_velocity.get(key)
        dt_s = step / NS_PER_S
        new = tuple.__new__
        end = instant + count * step
        kept = recorder._resting.get(key)
        if kept is not None and kept[0] == module.epoch:
            status = kept[1]  # at rest, and nothing intervened since it was read
        else:
            while True:
                axis = module.axis_at(index, instant)
                status = axis.sample()
                resting = axis.resting()
                if resting and self._settled:
                    recorder._resting[key] = (module.epoch, status)
                elif not resting and kept is not None:
                    del recorder._resting[key]
                    kept = None
                if resting or instant + step >= end:
                    break  # at rest, untouched up to the last instant: it reads the same
                # the instants after this one and before the last at once where the core has a
                # closed form (Axis.samples_at: a steady run); the last one the plain way, so
                # the axis ends where it does sampled one by one
                statuses = [status]
                before_last = (end - instant - step) // step - 1
                if before_last > 0 and recorder.closed_forms:
                    stretch = axis.samples_at(instant + step, step, before_last)
                    recorder.at_once += len(stretch)
                    statuses += stretch
                for (position, velocity, current, target, at_target, left_on, right_on,
                     home_on) in statuses:
                    column.append(new(Sample, (
                        instant / NS_PER_S, slot, index, position, velocity,
                        0.0 if previous is None else (velocity - previous) / dt_s,
                        current, target, int(at_target), int(left_on), int(right_on),
                        int(home_on))))
                    previous = velocity
                    instant += step
        # the rest of the instants read ``status``: its velocity does not change
        position, velocity, current, target = status[:4]
        reached, left, right, home = (int(status.position_reached), int(status.left_switch),
                                      int(status.right_switch), int(status.home_switch))
        column.append(new(Sample, (
            instant / NS_PER_S, slot, index, position, velocity,
            0.0 if previous is None else (velocity - previous) / dt_s,
            current, target, reached, left, right, home)))
        if end > instant + step:  # the times in seconds are the span's, made once for all axes
            times = self._times
            if times is None:
                times = self._times = [at / NS_PER_S for at in range(self.first, self.last + 1, step)]
            start = (instant + step - self.first) // step
            column.add_run(SampleRun(times, start, (end - self.first) // step - start, (
                slot, index, position, velocity, 0.0, current, target, reached, left, right,
                home)))  # one run: its rows are made when read
        recorder._last_velocity[key] = velocity


class Recording:
    """What ``SimulatorThread.record()`` returns: a recorder seen from the test's thread.

    ``rows`` and ``marks`` fill as simulated time passes; :meth:`stop` (or leaving the
    ``with`` block) records up to the present and detaches.
    """

    def __init__(self, recorder: Recorder, call: Callable[..., Any],
                 settle: Callable[[], None] = lambda: None) -> None:
        self._recorder = recorder
        self._call = call
        #: Applies the time the test's thread advanced (SimulatorThread.settle).
        self._settle = settle

    @property
    def rows(self) -> SampleRows:
        self._settle()
        return self._recorder.rows

    @property
    def marks(self) -> list[Mark]:
        self._settle()
        return self._recorder.marks

    def stop(self) -> SampleRows:
        return self._call(self._recorder.stop)

    def __enter__(self) -> Recording:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def axis(self, axis: int, module: int | None = None) -> list[Sample]:
        """The samples of one axis (of one module, when several are recorded)."""
        return [r for r in self.rows if r.axis == axis and (module is None or r.module == module)]

    def events(self, kind: str | None = None, axis: int | None = None) -> list[Mark]:
        return [m for m in self.marks
                if (kind is None or m.event == kind) and (axis is None or m.axis == axis)]


# -- files ------------------------------------------------------------------------------------

def file_format(path: str | Path) -> str:
    """``csv`` or ``jsonl``, by the file's extension."""
    suffix = Path(path).suffix.lower()
    if suffix == ".csv":
        return "csv"
    if suffix in (".jsonl", ".json", ".ndjson"):
        return "jsonl"
    raise ValueError(f"record file {path}: use a .csv or .jsonl extension")


class RecordWriter:
    """Writes samples and marks to an open text file as they come."""

    def __init__(self, stream: TextIO, fmt: str) -> None:
        self.stream = stream
        self.fmt = fmt
        self._csv = None
        if fmt == "csv":
            self._csv = csv.writer(stream, lineterminator="\n")
            self._csv.writerow(CSV_COLUMNS)

    def header(self) -> str:
        """What starts a new file (a rotated one): the CSV header line; nothing for JSONL."""
        return ",".join(CSV_COLUMNS) + "\n" if self._csv is not None else ""

    def sample(self, sample: Sample) -> None:
        if self._csv is not None:
            self._csv.writerow((*(getattr(sample, name) for name in SAMPLE_FIELDS), "", ""))
        else:
            self.stream.write(json.dumps(sample._asdict(), separators=(",", ":")) + "\n")

    def mark(self, mark: Mark) -> None:
        if self._csv is not None:
            self._csv.writerow((mark.t, mark.module, "" if mark.axis is None else mark.axis,
                                *([""] * (len(SAMPLE_FIELDS) - 3)), mark.event, mark.detail))
        else:
            body: dict[str, Any] = {"t": mark.t, "module": mark.module, "axis": mark.axis,
                                    "event": mark.event, **mark.data}
            self.stream.write(json.dumps(body, separators=(",", ":")) + "\n")


def read_record(path: str | Path) -> tuple[list[Sample], list[Mark]]:
    """Samples and marks back from a file written by ``--record`` (CSV or JSONL); ValueError
    naming the line when one is not a recorder's (a truncated file, another file)."""
    samples: list[Sample] = []
    marks: list[Mark] = []
    with open(path, newline="", encoding="utf-8") as stream:
        for line, row in _rows(stream, file_format(path)):
            try:
                if row.get("event"):
                    axis = row.get("axis")
                    data = row.get("data") or {}
                    marks.append(Mark(float(row["t"]), int(row["module"]),
                                      None if axis in (None, "") else int(axis), str(row["event"]), data))
                else:
                    samples.append(Sample(**{name: _number(row[name]) for name in SAMPLE_FIELDS}))
            except (TypeError, ValueError, KeyError, AttributeError) as exc:
                raise ValueError(f"line {line}: {_what_is_wrong(row, exc)}") from None
    return samples, marks


def _what_is_wrong(row: Any, exc: Exception) -> str:
    if not isinstance(row, dict):
        return f"not a recorder row (a JSON {type(row).__name__})"
    missing = [name for name in SAMPLE_FIELDS if row.get(name) in (None, "")]
    if missing and not row.get("event"):
        return f"incomplete row, no {', '.join(missing)} (a truncated file?)"
    return f"not a recorder row ({type(exc).__name__}: {exc})"


def _rows(stream: TextIO, fmt: str) -> Iterator[tuple[int, dict[str, Any]]]:
    """(line number, row) pairs; JSON that is not an object stays as it is, for the message."""
    if fmt == "csv":
        reader = csv.DictReader(stream)
        for row in reader:
            detail = row.pop("detail", "") or ""
            parsed: dict[str, Any] = dict(row)
            parsed["data"] = dict(part.split("=", 1) for part in detail.split() if "=" in part)
            yield reader.line_num, parsed
        return
    for line, text in enumerate(stream, 1):
        if text.strip():
            try:
                body = json.loads(text)
            except (ValueError, RecursionError) as exc:
                why = "nested too deeply" if isinstance(exc, RecursionError) else str(exc)
                raise ValueError(f"line {line}: not JSON ({why})") from None
            if isinstance(body, dict) and "event" in body:
                extra = {k: v for k, v in body.items() if k not in ("t", "module", "axis", "event")}
                body["data"] = extra
            yield line, body


def _number(text: Any) -> Any:
    if isinstance(text, int | float):
        return text
    try:
        return int(text)
    except ValueError:
        return float(text)
