"""The world around the axes: switches, encoder, load, and the module's inputs.

Positions in the world are *mechanical* positions in 1/256 microsteps (the finest resolution
of the driver), counted from where the axis was at power-on.  With the factory microstep
setting (AP 140 = 8, 256 microsteps) that is exactly the step count, so a fresh axis's AP 1
and the world agree until AP 1 is rewritten (by SAP 1 or a reference search).

A world file is TOML (docs/world.md has the format and an example); :func:`load_world` reads
it and :meth:`World.from_dict` builds the same from a dict (used by the run-time API).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tmcl_spec.parameters import SWITCH_NAMES

INFINITY = float("inf")
DEFAULT_SIDES = {"left": "below", "right": "above", "home": "centre"}
DEFAULT_LOAD = 500
LOAD_MAX = 1023
#: The load value of a blocked motor (a hard stop, a load beyond the motor's torque): its
#: stallGuard2 reading at threshold 0 would lie this far below the scale's 0, where the
#: driver's reading stops.  A threshold (AP 174) raises every reading by 16 per unit, so a
#: blocked motor reads 0, a stall, at every threshold up to 32 and a partial load keeps its
#: own reading [MODEL] (docs/motion.md, "stallGuard2 and coolStep").
BLOCKED_LOAD = -512
ANALOG_MAX = 65535
#: Highest supply voltage a world may set (the module is specified for 10..35 V).
SUPPLY_VOLTAGE_MAX = 100.0
#: Encoder counts per motor revolution where neither the world nor the module type says.
DEFAULT_ENCODER_COUNTS_PER_REV = 51200


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


def is_blocked(load: int, blocked: bool | None) -> bool:
    """Whether a load is a blocked motor: as the world says, or (not said) a load value of 0,
    the stall itself (what a load of 0 always meant in a world file)."""
    return load == 0 if blocked is None else blocked


@dataclass(frozen=True, slots=True)
class LoadZone:
    """A stretch [low, high] where the stallGuard2 load value reads ``load`` at threshold 0.

    ``blocked``: the motor is blocked there (a hard stop, a load beyond its torque), as
    opposed to a partial load; None: blocked if ``load`` is 0.
    """

    low: int
    high: int
    load: int
    blocked: bool | None = None

    def edges(self) -> list[int]:
        return [self.low, self.high + 1]

    @property
    def value(self) -> int:
        """The load value stallGuard2 works from: ``load``, or BLOCKED_LOAD if blocked."""
        return BLOCKED_LOAD if is_blocked(self.load, self.blocked) else self.load


@dataclass(slots=True)
class AxisWorld:
    """Everything outside the module that one axis touches."""

    switches: dict[str, Switch] = field(default_factory=dict)
    load_zones: list[LoadZone] = field(default_factory=list)
    free_load: int = DEFAULT_LOAD
    #: Fraction of the motor's motion that the encoder does not see (lost steps), 0..1.
    encoder_slip: float = 0.0
    #: None: the module's own encoder (``Axis.builtin_encoder_counts``: the sensOstep's 1024
    #: on the TMCM-1140/1160/1161), else DEFAULT_ENCODER_COUNTS_PER_REV.
    encoder_counts_per_rev: int | None = None
    motor_fullsteps_per_rev: int = 200
    #: Faults of the mechanics and wiring (tmcl_server/faults.py, docs/faults.md); they belong
    #: to the world, so a module restart keeps them.  The motor stops following its steps:
    stuck: bool = False
    #: ... and stallGuard2 reads this while it is stuck (None: the load of the place it is stuck at).
    stuck_load: int | None = None
    #: Broken switches: name -> the electrical level the input is stuck at, wherever the axis is.
    broken_switches: dict[str, bool] = field(default_factory=dict)
    #: Whether the motor is blocked outside the load zones (None: if ``free_load`` is 0).
    free_blocked: bool | None = None

    def level(self, name: str, position: int) -> bool:
        broken = self.broken_switches.get(name)
        if broken is not None:
            return broken
        switch = self.switches.get(name)
        return switch.level(position) if switch is not None else False

    def load_at(self, position: int) -> int:
        """The load value at ``position`` (the stallGuard2 reading at threshold 0), or
        :data:`BLOCKED_LOAD` where the motor is blocked (a stuck motor's load 0 is one)."""
        if self.stuck and self.stuck_load is not None:
            return BLOCKED_LOAD if self.stuck_load == 0 else self.stuck_load
        for zone in self.load_zones:
            if zone.low <= position <= zone.high:
                return zone.value
        return BLOCKED_LOAD if is_blocked(self.free_load, self.free_blocked) else self.free_load

    def edges(self) -> list[int]:
        """Every position where a switch level or the load value changes (sorted)."""
        points: set[int] = set()
        for name, switch in self.switches.items():
            if name not in self.broken_switches:  # a broken switch's level never changes
                points.update(switch.edges())
        for zone in self.load_zones:
            points.update(zone.edges())
        return sorted(points)

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: KeyPath = ()) -> AxisWorld:
        """The world of one ``[[axis]]`` table; unknown keys are refused (WorldError)."""
        _table(data, where, _AXIS_KEYS)
        switches = {}
        for name in SWITCH_NAMES:
            spec = data.get(name)
            if spec is None:
                continue
            at = (*where, name)
            if not isinstance(spec, dict):
                spec = {"position": _integer(spec, at)}
            _table(spec, at, _SWITCH_KEYS, required=("position",))
            width = spec.get("width")
            position = _integer(spec["position"], (*at, "position"))
            width = None if width is None else _integer(width, (*at, "width"), 0)
            side = _text(spec.get("side", DEFAULT_SIDES[name]), (*at, "side"))
            closed = _boolean(spec.get("normally_closed", False), (*at, "normally_closed"))
            try:
                switches[name] = Switch.place(position, width, side, closed)
            except ValueError as exc:  # an unknown side
                raise WorldError(f"{_name(at)}: {exc}", (*at, "side")) from None
        zones_data = data.get("load_zone", [])
        if not isinstance(zones_data, list):
            raise WorldError(f"{_name((*where, 'load_zone'))} must be an array of tables "
                             "([[axis.load_zone]])", (*where, "load_zone"))
        zones = []
        for number, zone in enumerate(zones_data):
            at = (*where, "load_zone", number)
            _table(zone, at, _ZONE_KEYS, required=("from", "to"))
            low, high = _integer(zone["from"], (*at, "from")), _integer(zone["to"], (*at, "to"))
            if high < low:
                raise WorldError(f"{_name(at)}: 'to' ({high}) lies below 'from' ({low})", at)
            load, blocked = _load(zone, at, 0)
            zones.append(LoadZone(low, high, load, blocked))
        free_load, free_blocked = _load(data, where, DEFAULT_LOAD)
        return cls(switches, zones, free_load,
                   _number(data.get("encoder_slip", 0.0), (*where, "encoder_slip"), 0.0, 1.0),
                   None if data.get("encoder_resolution") is None else
                   _integer(data["encoder_resolution"], (*where, "encoder_resolution"), 1),
                   _integer(data.get("motor_fullsteps", 200), (*where, "motor_fullsteps"), 1),
                   free_blocked=free_blocked)


@dataclass(slots=True)
class World:
    """The whole world file: axes, module inputs, chip clock."""

    axes: dict[int, AxisWorld] = field(default_factory=dict)
    analog_inputs: dict[int, int] = field(default_factory=dict)
    digital_inputs: dict[int, bool] = field(default_factory=dict)
    clock_hz: int | None = None
    #: The chip core the axes run on (``[chip] core``); None: the module type's.
    chip_core: str | None = None
    #: Supply voltage in volts (``GIO 8, 1``); None: the module type's nominal voltage.
    supply_voltage: float | None = None

    @classmethod
    def from_dict(cls, data: dict[str, Any], number_of_axes: int | None = None,
                  number_of_inputs: int | None = None, analog_full_scale: int = ANALOG_MAX,
                  chip_cores: Iterable[str] | None = None) -> World:
        """The world a dict (a parsed world file) describes; anything unknown is an error.

        ``number_of_axes`` / ``number_of_inputs`` bound the axis indices and input lists if
        given, ``analog_full_scale`` the analogue values (the module's ADC: 4095 on the TMC429
        modules), ``chip_cores`` the names ``[chip] core`` may take.  Errors are
        :class:`WorldError` naming the key path.
        """
        _table(data, (), _TOP_KEYS)
        world = cls()
        world._axes_from(data, number_of_axes)
        world._inputs_from(data, number_of_inputs, analog_full_scale)
        chip = _table(data.get("chip", {}), ("chip",), _CHIP_KEYS)
        if "clock_hz" in chip:
            world.clock_hz = _integer(chip["clock_hz"], ("chip", "clock_hz"), 1)
        if "core" in chip:
            world.chip_core = _chip_core(chip["core"], chip_cores)
        supply = _table(data.get("supply", {}), ("supply",), _SUPPLY_KEYS)
        if "voltage" in supply:
            world.supply_voltage = check_supply_voltage(
                _number(supply["voltage"], ("supply", "voltage"), 0.0, SUPPLY_VOLTAGE_MAX))
        return world

    def _axes_from(self, data: dict[str, Any], number_of_axes: int | None) -> None:
        entries = data.get("axis", [])
        if not isinstance(entries, list):
            raise WorldError("'axis' must be an array of tables ([[axis]])", ("axis",))
        for number, entry in enumerate(entries):
            at: KeyPath = ("axis", number)
            _table(entry, at, _AXIS_KEYS, required=("index",))
            limit = None if number_of_axes is None else number_of_axes - 1
            index = _integer(entry["index"], (*at, "index"), 0, limit, what="axis index")
            if index in self.axes:
                raise WorldError(f"{_name(at)}: axis index {index} appears twice", (*at, "index"))
            self.axes[index] = AxisWorld.from_dict(entry, at)

    def _inputs_from(self, data: dict[str, Any], number_of_inputs: int | None,
                     analog_full_scale: int) -> None:
        inputs = _table(data.get("inputs", {}), ("inputs",), _INPUT_KEYS)
        for kind in ("analog", "digital"):
            values = inputs.get(kind, [])
            at: KeyPath = ("inputs", kind)
            if not isinstance(values, list):
                raise WorldError(f"{_name(at)} must be an array", at)
            if number_of_inputs is not None and len(values) > number_of_inputs:
                raise WorldError(f"{_name(at)} lists {len(values)} inputs; the module has "
                                 f"{number_of_inputs}", at)
            for port, value in enumerate(values):
                if kind == "analog":
                    self.analog_inputs[port] = _integer(value, (*at, port), 0, analog_full_scale)
                else:
                    self.digital_inputs[port] = _boolean(value, (*at, port))


def _chip_core(value: Any, chip_cores: Iterable[str] | None) -> str:
    """``[chip] core``: one of ``chip_cores`` (any case), as its name."""
    core = _text(value, ("chip", "core"))
    known = None if chip_cores is None else sorted(chip_cores)
    if known is not None and core.lower() not in known:
        raise WorldError(f"chip.core {core!r} is not a chip core (known: "
                         f"{', '.join(known)})", ("chip", "core"))
    return core.lower()


def load_world(path: str | Path, number_of_axes: int | None = None,
               number_of_inputs: int | None = None, analog_full_scale: int = ANALOG_MAX,
               chip_cores: Iterable[str] | None = None) -> World:
    """Read a TOML world file; errors name the file, the line (when it can be found) and the key."""
    import tomllib  # only when there is a world file to read

    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ValueError(f"world file {path}: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ValueError(f"world file {path}: not UTF-8 text ({exc.reason} at byte "
                         f"{exc.start})") from exc
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:  # its message ends with "(at line L, column C)"
        raise ValueError(f"world file {path}: {exc}") from exc
    try:
        return World.from_dict(data, number_of_axes, number_of_inputs, analog_full_scale,
                               chip_cores)
    except WorldError as exc:
        line = locate_key(text, exc.where)
        at = f", line {line}" if line is not None else ""
        raise ValueError(f"world file {path}{at}: {exc}") from exc


# == validation ================================================================================

KeyPath = tuple[str | int, ...]

_TOP_KEYS = frozenset({"axis", "inputs", "chip", "supply"})
_AXIS_KEYS = frozenset({"index", *SWITCH_NAMES, "load", "blocked", "load_zone", "encoder_slip",
                        "encoder_resolution", "motor_fullsteps"})
_SWITCH_KEYS = frozenset({"position", "width", "side", "normally_closed"})
_ZONE_KEYS = frozenset({"from", "to", "load", "blocked"})
_INPUT_KEYS = frozenset({"analog", "digital"})
_CHIP_KEYS = frozenset({"clock_hz", "core"})
_SUPPLY_KEYS = frozenset({"voltage"})


class WorldError(ValueError):
    """A world description that is not valid; ``where`` is the key path of the culprit."""

    def __init__(self, message: str, where: KeyPath = ()) -> None:
        super().__init__(message)
        self.where = where


def check_supply_voltage(volts: float) -> float:
    """A supply voltage the simulated monitor can show (0..SUPPLY_VOLTAGE_MAX volts)."""
    if isinstance(volts, bool) or not isinstance(volts, int | float) or not (
            0.0 <= volts <= SUPPLY_VOLTAGE_MAX):
        raise ValueError(f"supply voltage must be 0..{SUPPLY_VOLTAGE_MAX:g} V, got {volts!r}")
    return float(volts)


def _name(where: KeyPath) -> str:
    """``axis[1].left.position``: where a key is, in words a user can find in the file."""
    text = ""
    for part in where:
        text += f"[{part}]" if isinstance(part, int) else (f".{part}" if text else part)
    return text or "the file"


def _table(value: Any, where: KeyPath, known: frozenset[str],
           required: tuple[str, ...] = ()) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise WorldError(f"{_name(where)} must be a table", where)
    for key in value:
        if key not in known:
            import difflib  # only to word an error

            hint = difflib.get_close_matches(key, known, n=1)
            guess = f"; did you mean {hint[0]!r}?" if hint else ""
            raise WorldError(f"unknown key {_name((*where, key))!r}{guess} (known here: "
                             f"{', '.join(sorted(known))})", (*where, key))
    for key in required:
        if key not in value:
            raise WorldError(f"{_name(where)}: missing key {key!r}", where)
    return value


def _integer(value: Any, where: KeyPath, lo: int | None = None, hi: int | None = None,
             what: str | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise WorldError(f"{_name(where)} must be an integer, got {value!r}", where)
    if (lo is not None and value < lo) or (hi is not None and value > hi):
        span = f"{'' if lo is None else lo}..{'' if hi is None else hi}"
        raise WorldError(f"{what or _name(where)} {value} outside {span}", where)
    return value


def _load(table: dict[str, Any], where: KeyPath, default: int) -> tuple[int, bool | None]:
    """``load`` and ``blocked`` of an axis or a load zone: a blocked motor has no load value
    of its own (``blocked = true`` with a ``load`` other than 0 is refused)."""
    blocked = _boolean(table["blocked"], (*where, "blocked")) if "blocked" in table else None
    load = _integer(table.get("load", 0 if blocked else default), (*where, "load"), 0, LOAD_MAX)
    if blocked and load:
        raise WorldError(f"{_name(where)}: a blocked motor has no load value (load = {load}); "
                         "drop 'load' or set blocked = false", (*where, "load"))
    return load, blocked


def _number(value: Any, where: KeyPath, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not lo <= value <= hi:
        raise WorldError(f"{_name(where)} must be a number {lo:g}..{hi:g}, got {value!r}", where)
    return float(value)


def _boolean(value: Any, where: KeyPath) -> bool:
    if not isinstance(value, bool):
        raise WorldError(f"{_name(where)} must be true or false, got {value!r}", where)
    return value


def _text(value: Any, where: KeyPath) -> str:
    if not isinstance(value, str):
        raise WorldError(f"{_name(where)} must be a string, got {value!r}", where)
    return value


_HEADER = re.compile(r"^\s*\[\[?\s*([^\]]+?)\s*\]\]?\s*(#.*)?$")


def _header(line: str) -> str | None:
    match = _HEADER.match(line)
    return match.group(1).replace(" ", "").replace('"', "") if match else None


def locate_key(text: str, where: KeyPath) -> int | None:
    """The 1-based line of the TOML text where the key path ``where`` is written, if found.

    tomllib keeps no positions, so the file is searched: table headers (``[[axis]]``, the
    n-th for an index) narrow the search to their block, and keys are matched as ``key =``,
    also inside inline tables.  A best effort: None when the key cannot be found.
    """
    lines = text.splitlines()
    start, end, prefix, found = 0, len(lines), "", None
    parts = list(where)
    while parts:
        part = parts.pop(0)
        if isinstance(part, int):
            continue
        name = f"{prefix}.{part}" if prefix else part
        headers = [n for n in range(start, end) if _header(lines[n]) == name]
        if headers:
            index = 0
            if parts and isinstance(following := parts[0], int):  # the n-th such table
                index = following
                del parts[0]
            if index >= len(headers):
                return found
            top = headers[index]
            start, end, prefix, found = top + 1, _block_end(lines, top, end, name), name, top + 1
            continue
        line = _key_line(lines, start, end, part)
        if line is None:
            return found
        start, found = line, line + 1
    return found


def _block_end(lines: list[str], top: int, end: int, name: str) -> int:
    """Where the table whose header is on line ``top`` ends: at the next header that is not
    one of its sub-tables (or ``end``)."""
    return next((n for n in range(top + 1, end) if (h := _header(lines[n])) is not None
                 and not h.startswith(name + ".")), end)


def _key_line(lines: list[str], start: int, end: int, key: str) -> int | None:
    """The first line in ``start..end`` (not a header) that writes ``key =`` (also inside
    an inline table), ignoring comments."""
    pattern = re.compile(rf'(^|[{{,\s.]){re.escape(key)}"?\s*[=.]')
    return next((n for n in range(start, end)
                 if _header(lines[n]) is None and pattern.search(lines[n].split("#")[0])), None)
