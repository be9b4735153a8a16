"""Reference search (RFS, AP 193 modes 1..8 with +64/+128) as a plan of phases.

:func:`reference_plan` turns a mode into the phases the firmware drives one after another;
:func:`reference_point` computes the zero point from the positions recorded on the way.
The state machine that drives the phases is part of the firmware layer (axes/firmware.py);
the sequences where the manual's figures are missing are explained in docs/motion.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(slots=True)
class Phase:
    """One step of a reference search: drive until a switch reaches a level."""

    kind: str  # "seek" (fast, may reverse), "leave", "enter" (slow), "finish"
    switch: str  # "left", "right" or "home"
    direction: int
    record: str | None = None  # name under which to keep the position where it happened
    reverse_on: str | None = None  # seek only: limit switch that turns the search around


def _calibrate(switch: str, direction: int, tag: str) -> list[Phase]:
    """Back out of a switch slowly and re-enter it: its switching point without hysteresis.

    ``direction`` is the way the switch was entered; records ``tag1`` and ``tag2``.
    """
    return [Phase("leave", switch, -direction, f"{tag}1"), Phase("enter", switch, direction, f"{tag}2")]


def _middle(switch: str, direction: int) -> list[Phase]:
    """Both ends of a switch cam entered travelling ``direction``: its middle."""
    return [*_calibrate(switch, direction, "near"), Phase("leave", switch, direction, "back1"),
            Phase("enter", switch, -direction, "back2")]


def reference_plan(mode: int) -> tuple[list[Phase], bool]:
    """The phases of RFS for AP 193 ``mode``, and whether the home switch is inverted."""
    inverted = mode >= 128
    base = mode - 128 if inverted else mode
    if inverted and base <= 4:
        base += 4  # the manual's own examples spell "mode 5..8 + 128" as 129..132
    mirrored = 64 < base < 128
    base = base - 64 if mirrored else base
    near, far, down = ("right", "left", 1) if mirrored else ("left", "right", -1)
    seek_near = Phase("seek", near, down)
    seek_far = Phase("seek", far, -down)
    if base == 1:
        phases = [seek_near, *_calibrate(near, down, "near")]
    elif base == 2:
        phases = [seek_far, *_calibrate(far, -down, "other"), seek_near, *_calibrate(near, down, "near")]
    elif base == 3:
        phases = [seek_far, *_calibrate(far, -down, "other"), seek_near, *_middle(near, down)]
    elif base == 4:
        phases = [seek_near, *_middle(near, down)]
    elif base == 5:
        phases = [Phase("seek", "home", -1, reverse_on="left"), *_calibrate("home", -1, "near")]
    elif base == 6:
        phases = [Phase("seek", "home", 1, reverse_on="right"), *_calibrate("home", 1, "near")]
    elif base == 7:
        phases = [Phase("seek", "home", 1), *_middle("home", 1)]
    elif base == 8:
        phases = [Phase("seek", "home", -1), *_middle("home", -1)]
    else:
        raise ValueError(f"reference search mode {mode} is not defined")
    return [*phases, Phase("finish", "", 0)], inverted


def reference_point(points: dict[str, int]) -> tuple[int, int | None]:
    """(zero point, end-switch distance or None) from the positions a search recorded.

    A calibrated edge is the mean of the two switching points (leaving and re-entering); the
    middle of a cam is the mean of both calibrated ends.  Means are floored.
    """
    tags = ("near", "back") if "back1" in points else ("near",)
    zero = sum(points[f"{tag}{n}"] for tag in tags for n in (1, 2)) // (2 * len(tags))
    if "other1" in points:
        other = (points["other1"] + points["other2"]) // 2
        return zero, abs(other - zero)
    return zero, None


@dataclass(slots=True)
class ReferenceSearch:
    phases: list[Phase]
    inverted_home: bool
    index: int = 0
    #: Positions recorded on the way, by the phases' ``record`` names.
    points: dict[str, int] = field(default_factory=dict)
    direction: int = 0
    reversed_once: bool = False

    @property
    def phase(self) -> Phase:
        return self.phases[self.index]
