"""``tmcl plot``: a recording (``tmcl-server --record``) as a picture, with matplotlib.

Per axis two panels on one time line: position (with the switches shaded where they were
active) and velocity (with the acceleration phases visible as slopes); module events are
vertical marks.  matplotlib is an optional extra (``pip install tmcl-sim[plot]``) and is
imported only here, through its object API (no pyplot state, no display needed).
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tmcl_server.record import Mark, Sample, read_record

#: How event kinds are drawn: colour and line style.
_EVENT_STYLE = {
    "target_reached": ("tab:green", ":"),
    "stall": ("tab:red", "-"),
    "deviation": ("tab:red", "--"),
    "reference_search_done": ("tab:purple", ":"),
    "interrupt_taken": ("0.6", ":"),
    "program_started": ("tab:blue", "-."),
    "program_stopped": ("tab:blue", "-."),
}
_SWITCH_COLOURS = {"left": "tab:orange", "right": "tab:red", "home": "tab:cyan"}
#: Events of one kind drawn at most (a timer interrupt every 10 ms would paint the plot grey).
MAX_MARKS_PER_KIND = 60
#: Events that are state, not moments: shown by the shading, not as lines.
_SHADED = {"left_switch", "right_switch", "home_switch", "current_changed"}


class PlotError(ValueError):
    pass


def plot_file(record: Path, output: Path, axes: Sequence[int] | None = None,
              size: tuple[float, float] = (10.0, 6.0), dpi: int = 100,
              title: str | None = None, whole: bool = False) -> list[str]:
    """Draw ``record`` into ``output`` (PNG, SVG or PDF by extension); the axes drawn.

    Unless ``whole``, the time line is cut to where something moved (plus a margin): a
    recording on a real clock is mostly the host getting ready.
    """
    samples, marks = _read(record)
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise PlotError("plotting needs matplotlib: pip install 'tmcl-sim[plot]'") from None

    series = _by_axis(samples)
    chosen = _choose(series, axes)
    if not chosen:
        raise PlotError(f"{record}: none of the axes {list(axes or [])} was recorded")
    several_modules = len({module for module, _ in series}) > 1
    if not whole:
        marks = _crop(series, chosen, marks)

    figure = Figure(figsize=size, dpi=dpi, layout="constrained")
    FigureCanvasAgg(figure)
    grid = figure.subplots(2 * len(chosen), 1, sharex=True, squeeze=False)[:, 0]
    names = []
    for row, (module, axis) in enumerate(chosen):
        name = f"m{module} axis {axis}" if several_modules else f"axis {axis}"
        names.append(name)
        _draw_axis(grid[2 * row], grid[2 * row + 1], name, series[(module, axis)],
                   _marks_of(marks, module, axis))
    grid[-1].set_xlabel("simulated time (s)", fontsize=8)
    figure.suptitle(title or f"{record.name}", fontsize=10)
    try:
        figure.savefig(output, dpi=dpi)
    except (OSError, ValueError) as exc:
        raise PlotError(f"{output}: {exc}") from None
    return names


def _by_axis(samples: list[Sample]) -> dict[tuple[int, int], list[Sample]]:
    """The samples of each (module, axis), in the recording's order."""
    series: dict[tuple[int, int], list[Sample]] = defaultdict(list)
    for sample in samples:
        series[(sample.module, sample.axis)].append(sample)
    return series


def _marks_of(marks: list[Mark], module: int, axis: int) -> list[Mark]:
    """An axis's marks and its module's (those of no axis)."""
    return [m for m in marks if m.module == module and m.axis in (axis, None)]


def _read(record: Path) -> tuple[list[Sample], list[Mark]]:
    """The recording's samples and marks, or one PlotError that names the file."""
    try:
        samples, marks = read_record(record)
    except (OSError, ValueError, KeyError) as exc:
        raise PlotError(f"{record}: cannot read the recording: {exc}") from None
    if not samples:
        raise PlotError(f"{record}: no samples in the recording")
    return samples, marks


def _crop(series: dict[tuple[int, int], list[Sample]], chosen: list[tuple[int, int]],
          marks: list[Mark]) -> list[Mark]:
    """Cut the chosen axes' samples to where something moved; the marks left in that span."""
    start, end = _active_span([series[key] for key in chosen])
    for key in chosen:
        series[key] = [s for s in series[key] if start <= s.t <= end]
    return [m for m in marks if start <= m.t <= end]


def _draw_axis(position: Any, velocity: Any, name: str, rows: list[Sample],
               marks: list[Mark]) -> None:
    """One axis's two panels: position and target above, velocity below, with its marks."""
    t = [s.t for s in rows]
    position.plot(t, [s.position for s in rows], color="tab:blue", linewidth=1.2, label="position")
    position.plot(t, [s.target for s in rows], color="tab:blue", linewidth=0.8, alpha=0.4,
                  linestyle="--", label="target")
    position.set_ylabel(f"{name}\nposition", fontsize=8)
    _shade_switches(position, rows)
    velocity.plot(t, [s.velocity for s in rows], color="tab:green", linewidth=1.2, label="velocity")
    velocity.set_ylabel("velocity", fontsize=8)
    velocity.axhline(0, color="0.8", linewidth=0.6)
    _marks(position, velocity, marks)
    for panel in (position, velocity):
        panel.grid(True, alpha=0.3)
        panel.tick_params(labelsize=7)
    position.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=7, borderaxespad=0)


def _active_span(all_rows: list[list[Sample]]) -> tuple[float, float]:
    """From shortly before the first change of any axis to shortly after the last one."""
    first, last = float("inf"), float("-inf")
    for rows in all_rows:
        for previous, sample in itertools.pairwise(rows):
            if (previous.position, previous.velocity, previous.left, previous.right, previous.home) != (
                    sample.position, sample.velocity, sample.left, sample.right, sample.home):
                first, last = min(first, previous.t), max(last, sample.t)
    begin = min(rows[0].t for rows in all_rows)
    end = max(rows[-1].t for rows in all_rows)
    if first > last:  # nothing moved: show it all
        return begin, end
    margin = max(0.1 * (last - first), 0.05)
    return max(begin, first - margin), min(end, last + margin)


def _choose(series: dict[tuple[int, int], list[Sample]], axes: Sequence[int] | None) -> list[tuple[int, int]]:
    keys = sorted(series)
    if axes is not None:
        return [k for k in keys if k[1] in axes]
    moved = [k for k in keys if len({(s.position, s.velocity) for s in series[k]}) > 1]
    return moved or keys[:1]


def _shade_switches(panel: Any, rows: list[Sample]) -> None:
    """Spans where a switch was active, one colour per switch, labelled once."""
    for name, colour in _SWITCH_COLOURS.items():
        for index, (start, end) in enumerate(_switch_spans(rows, name)):
            panel.axvspan(start, end, color=colour, alpha=0.2,
                          label=None if index else f"{name} switch")


def _switch_spans(rows: list[Sample], name: str) -> list[tuple[float, float]]:
    """(start, end) of each stretch in which switch ``name`` was active; one still active at
    the last sample ends there."""
    spans = []
    start = None
    for sample in rows:
        active = getattr(sample, name)
        if active and start is None:
            start = sample.t
        elif not active and start is not None:
            spans.append((start, sample.t))
            start = None
    if start is not None:
        spans.append((start, rows[-1].t))
    return spans


def _marks(position: object, velocity: object, marks: list[Mark]) -> None:
    drawn: dict[str, int] = defaultdict(int)
    for mark in marks:
        if mark.event in _SHADED or drawn[mark.event] >= MAX_MARKS_PER_KIND:
            continue
        colour, style = _EVENT_STYLE.get(mark.event, ("0.4", ":"))
        for panel in (position, velocity):
            panel.axvline(mark.t, color=colour, linestyle=style, linewidth=0.9,  # type: ignore[attr-defined]
                          label=mark.event if drawn[mark.event] == 0 and panel is position else None)
        drawn[mark.event] += 1
