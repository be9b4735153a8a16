"""The world around the axes: switches, encoder, load, and the module's inputs.

Positions in the world are *mechanical* positions in 1/256 microsteps (the finest resolution
of the driver), counted from where the axis was at power-on.  With the factory microstep
setting (AP 140 = 8, 256 microsteps) that is exactly the step count, so a fresh axis's AP 1
and the world agree until AP 1 is rewritten (by SAP 1 or a reference search).

A world file is TOML (docs/world.md has the format and an example); :func:`load_world` reads
it and :meth:`World.from_dict` builds the same from a dict (used by the run-time API).
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tmcl_spec.parameters import SWITCH_NAMES

INFINITY = float("inf")
DEFAULT_SIDES = {"left": "below", "right": "above", "home": "centre"}
DEFAULT_LOAD = 500
LOAD_MAX = 1023


@dataclass(frozen=True, slots=True)
class Switch:
    """One switch: active on the closed interval [low, high] of mechanical positions."""

    low: float
    high: float
    normally_closed: bool = False

    @classmethod
    def place(cls, position: int, width: int | None = None, side: str = "centre",
              normally_closed: bool = False) -> Switch:
        """A switch whose switching point is ``position`` and whose cam extends to ``side``.

        ``side`` "below" / "above": the active zone is [position - width, position] /
        [position, position + width] (no width: to the end of travel).  "centre": the zone
        is ``width`` wide and centred on ``position``.
        """
        if width is not None and width < 0:
            raise ValueError("switch width must not be negative")
        if side == "below":
            return cls(-INFINITY if width is None else position - width, position, normally_closed)
        if side == "above":
            return cls(position, INFINITY if width is None else position + width, normally_closed)
        if side in ("centre", "center"):
            half = (width or 0) // 2
            return cls(position - half, position - half + (width or 0), normally_closed)
        raise ValueError(f"unknown switch side {side!r} (below, above or centre)")

    def actuated(self, position: int) -> bool:
        return self.low <= position <= self.high

    def level(self, position: int) -> bool:
        """Electrical level: actuated, or not actuated for a normally-closed contact."""
        return self.actuated(position) != self.normally_closed

    def edges(self) -> list[int]:
        """Positions p where the level at p differs from the level at p - 1."""
        out = []
        if self.low != -INFINITY:
            out.append(int(self.low))
        if self.high != INFINITY:
            out.append(int(self.high) + 1)
        return out


@dataclass(frozen=True, slots=True)
class LoadZone:
    """A stretch [low, high] where the stallGuard2 load value reads ``load`` (0 = stall)."""

    low: int
    high: int
    load: int

    def edges(self) -> list[int]:
        return [self.low, self.high + 1]


@dataclass(slots=True)
class AxisWorld:
    """Everything outside the module that one axis touches."""

    switches: dict[str, Switch] = field(default_factory=dict)
    load_zones: list[LoadZone] = field(default_factory=list)
    free_load: int = DEFAULT_LOAD
    #: Fraction of the motor's motion that the encoder does not see (lost steps), 0..1.
    encoder_slip: float = 0.0
    encoder_counts_per_rev: int = 51200
    motor_fullsteps_per_rev: int = 200

    def level(self, name: str, position: int) -> bool:
        switch = self.switches.get(name)
        return switch.level(position) if switch is not None else False

    def load_at(self, position: int) -> int:
        for zone in self.load_zones:
            if zone.low <= position <= zone.high:
                return zone.load
        return self.free_load

    def edges(self) -> list[int]:
        """Every position where a switch level or the load value changes (sorted)."""
        points: set[int] = set()
        for switch in self.switches.values():
            points.update(switch.edges())
        for zone in self.load_zones:
            points.update(zone.edges())
        return sorted(points)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> AxisWorld:
        switches = {}
        for name in SWITCH_NAMES:
            spec = data.get(name)
            if spec is None:
                continue
            if isinstance(spec, int):
                spec = {"position": spec}
            switches[name] = Switch.place(int(spec["position"]), spec.get("width"),
                                          spec.get("side", DEFAULT_SIDES[name]),
                                          bool(spec.get("normally_closed", False)))
        zones = []
        for zone in data.get("load_zone", []):
            load = int(zone.get("load", 0))
            if not 0 <= load <= LOAD_MAX:
                raise ValueError(f"load value {load} outside 0..{LOAD_MAX}")
            zones.append(LoadZone(int(zone["from"]), int(zone["to"]), load))
        slip = float(data.get("encoder_slip", 0.0))
        if not 0.0 <= slip <= 1.0:
            raise ValueError("encoder_slip must be between 0 and 1")
        world = cls(switches, zones, int(data.get("load", DEFAULT_LOAD)), slip,
                    int(data.get("encoder_resolution", 51200)),
                    int(data.get("motor_fullsteps", 200)))
        if world.encoder_counts_per_rev <= 0 or world.motor_fullsteps_per_rev <= 0:
            raise ValueError("encoder_resolution and motor_fullsteps must be positive")
        return world


@dataclass(slots=True)
class World:
    """The whole world file: axes, module inputs, chip clock."""

    axes: dict[int, AxisWorld] = field(default_factory=dict)
    analog_inputs: dict[int, int] = field(default_factory=dict)
    digital_inputs: dict[int, bool] = field(default_factory=dict)
    clock_hz: int | None = None

    @classmethod
    def from_dict(cls, data: dict[str, Any], number_of_axes: int | None = None) -> World:
        """The world a dict describes; ``number_of_axes`` bounds the axis indices if given."""
        world = cls()
        for entry in data.get("axis", []):
            index = int(entry["index"])
            if index < 0 or (number_of_axes is not None and index >= number_of_axes):
                limit = "" if number_of_axes is None else f"..{number_of_axes - 1}"
                raise ValueError(f"axis index {index} outside 0{limit}")
            world.axes[index] = AxisWorld.from_dict(entry)
        inputs = data.get("inputs", {})
        for port, value in enumerate(inputs.get("analog", [])):
            world.analog_inputs[port] = int(value)
        for port, value in enumerate(inputs.get("digital", [])):
            world.digital_inputs[port] = bool(value)
        clock = data.get("chip", {}).get("clock_hz")
        world.clock_hz = int(clock) if clock is not None else None
        return world


def load_world(path: str | Path, number_of_axes: int | None = None) -> World:
    """Read a TOML world file; errors name the file."""
    try:
        with open(path, "rb") as f:
            return World.from_dict(tomllib.load(f), number_of_axes)
    except (OSError, tomllib.TOMLDecodeError, KeyError, ValueError, TypeError) as exc:
        raise ValueError(f"world file {path}: {exc}") from exc
