"""Faults on purpose (issue 17): what a real link and a real module do to a host, on demand.

A fault is one line of a small language (docs/faults.md has the whole of it)::

    KIND[:KEY=VALUE[,KEY=VALUE]...]
    noreply:opcode=GAP,rate=0.1,seed=7        every GAP has a 10 % chance of losing its reply
    delay:ms=20..80,module=2                  module 2 answers 20 to 80 ms late
    stuck:axis=0                              axis 0's motor stops following its steps

or the same as a TOML/JSON table (``{"kind": "noreply", "opcode": "GAP"}``).  KIND says what
happens, the other keys say to which requests (``endpoint``, ``module``, ``opcode``, ``type``,
``motor``), how often (``rate`` with ``seed``, ``count``, ``after``) and how (the kind's own
parameters, :data:`KINDS`).

A :class:`FaultInjector` holds the faults of one simulation.  The simulation calls it around
every host request (:meth:`FaultInjector.before`: a lost request, a module reset;
:meth:`FaultInjector.after`: a lost or altered reply), so every transport gets the same
decisions; what an altered reply looks like on the wire is a :class:`Delivery`, which each
transport sends its own way (a byte stream can tear it, a CAN frame cannot).  Physical faults
(a stuck axis, a broken switch, a sagging supply) change the module's world and stay until
removed.  Every injected fault is noted in the trace (kind ``fault``) and in
:attr:`FaultInjector.history`.  Each fault draws from its own random generator, seeded by
``seed`` (default 0): the same requests meet the same faults on every run.

The injector is a plain API for every front end: the command line (``--fault``,
``--faults FILE``), Python (:class:`FaultHandle`, ``SimulatorThread.fault``), MQTT
(``sim/fault``) and the dashboard (:meth:`FaultInjector.add`, :meth:`FaultInjector.remove`,
:meth:`FaultInjector.describe`, :data:`KINDS`).
"""

from __future__ import annotations

import difflib
import json
import random
import stat
import weakref
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tmcl_server.delivery import Delivery
from tmcl_server.dispatch import Interface, ReplySink
from tmcl_server.protocol import Reply, Request
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.modules import module_type
from tmcl_spec.names import module_names
from tmcl_spec.parameters import SWITCH_NAMES

if TYPE_CHECKING:
    from tmcl_server.module import TMCLModule
    from tmcl_server.simulation import Routed, Simulation

#: A fault acts on the request (it never reaches the module), on the reply, or on the world.
REQUEST, REPLY, STATE = "request", "reply", "state"
#: How many injections :attr:`FaultInjector.history` keeps.
HISTORY = 10_000
#: The supply a ``sag`` drops to unless told: below the module's 10 V minimum (docs/faults.md).
DEFAULT_SAG_VOLTS = 9.0
#: What the trace calls an endpoint nobody named.
UNNAMED = "-"
#: Bounds on what a fault spec may ask (docs/faults.md, "Limits"): faults installed at once
#: (a file holds at most as many), a spec's length and one value's, a fault file's size ...
MAX_FAULTS = 256
MAX_SPEC_CHARS = 1024
MAX_VALUE_CHARS = 256
MAX_FAULT_FILE = 256 * 1024
#: ... and how long a reply may be held back: a delay, and a torn reply's pauses.
MAX_DELAY_MS = 10_000.0
MAX_PAUSE_MS = 1_000.0


class FaultSpecError(ValueError):
    """A fault spec that names no kind, no key or no value the simulator knows."""


# == values =====================================================================================


def _shown(text: str, width: int = 40) -> str:
    """A value as an error message quotes it: long ones cut, with their length."""
    if len(text) <= width:
        return repr(text)
    return f"{text[:width]!r}... ({len(text):,} characters)"


def _alternatives(text: str) -> list[str]:
    """``A|B|C``; an empty alternative (``opcode=||``, ``opcode=GAP|``) is refused: it
    would match nothing and the fault would never strike (issue 36, N9)."""
    parts = [part.strip() for part in text.split("|")]
    if not all(parts):
        raise FaultSpecError(f"an empty alternative in {_shown(text)} (write A|B, no empty "
                             "part)")
    return parts


def _integer(text: str, what: str, lo: int, hi: int) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise FaultSpecError(f"{what} must be an integer, got {_shown(text)}") from None
    if not lo <= value <= hi:
        raise FaultSpecError(f"{what} must be {lo}..{hi}, got {value}")
    return value


def _number(text: str, what: str, lo: float, hi: float) -> float:
    try:
        value = float(text)
    except ValueError:
        raise FaultSpecError(f"{what} must be a number, got {_shown(text)}") from None
    if not lo <= value <= hi:
        raise FaultSpecError(f"{what} must be {lo:g}..{hi:g}, got {value:g}")
    return value


def _integers(what: str, lo: int, hi: int) -> Callable[[str], frozenset[int]]:
    def parse(text: str) -> frozenset[int]:
        return frozenset(_integer(part, what, lo, hi) for part in _alternatives(text))
    return parse


def _opcodes(text: str) -> frozenset[int]:
    """``GAP``, ``6``, ``GAP|SAP``: mnemonics (or control command names) and numbers."""
    found = set()
    for part in _alternatives(text):
        if part.isdigit():
            found.add(_integer(part, "opcode", 0, 255))
            continue
        try:
            found.add(int(Opcode[part.upper()]))
        except KeyError:
            hint = difflib.get_close_matches(part.upper(), Opcode.__members__, n=1)
            guess = f" (did you mean {hint[0]}?)" if hint else ""
            raise FaultSpecError(f"unknown opcode {_shown(part)}{guess}") from None
    return frozenset(found)


def _types(text: str) -> frozenset[int]:
    """Type numbers, or parameter names (``ActualPosition``) of the default module type."""
    axis, banks = module_names(module_type())
    tables = [axis, *banks.values()]
    found = set()
    for part in _alternatives(text):
        number = next((n for n in (t.number(part) for t in tables) if n is not None), None)
        if number is None:
            raise FaultSpecError(f"type must be a number or a parameter name, got {_shown(part)}")
        found.add(_integer(str(number), "type", 0, 255))
    return frozenset(found)


def _milliseconds(text: str) -> tuple[float, float]:
    """``100`` or ``20..80`` (a range: each injection draws a value from it)."""
    low, sep, high = text.partition("..")
    lo = _number(low, "ms", 0.0, MAX_DELAY_MS)
    hi = _number(high, "ms", 0.0, MAX_DELAY_MS) if sep else lo
    if hi < lo:
        raise FaultSpecError(f"ms range {_shown(text)} runs backwards")
    return lo, hi


def _status(text: str) -> int:
    if text.strip().lstrip("-").isdigit():
        return _integer(text, "status", 0, 255)
    try:
        return int(Status[text.strip().upper()])
    except KeyError:
        raise FaultSpecError(f"status must be a number or one of {', '.join(Status.__members__)}, "
                             f"got {_shown(text)}") from None


def _hex(text: str) -> bytes:
    try:
        data = bytes.fromhex(text.replace(":", " "))
    except ValueError:
        raise FaultSpecError(f"data must be hex bytes, got {_shown(text)}") from None
    if not 1 <= len(data) <= 64:
        raise FaultSpecError("data must be 1..64 bytes")
    return data


def _choice(what: str, choices: Iterable[str]) -> Callable[[str], str]:
    options = tuple(choices)

    def parse(text: str) -> str:
        value = text.strip().lower()
        if value not in options:
            raise FaultSpecError(f"{what} must be one of {', '.join(options)}, got {_shown(text)}")
        return value
    return parse


@dataclass(frozen=True)
class Param:
    """One key of a fault kind: how to read it, its default, what it means."""

    parse: Callable[[str], Any]
    default: Any = None
    required: bool = False
    help: str = ""


@dataclass(frozen=True)
class FaultKind:
    """What a fault does (``category``: request, reply or state) and the keys it takes."""

    name: str
    category: str
    summary: str
    params: Mapping[str, Param] = field(default_factory=dict)


_AXIS = Param(lambda t: _integer(t, "axis", 0, 255), required=True, help="axis index")

#: Every fault kind by name, with its own keys (docs/faults.md; a dashboard builds forms from it).
KINDS: dict[str, FaultKind] = {kind.name: kind for kind in (
    FaultKind("noreply", REPLY, "the module executes the request but its reply is lost"),
    FaultKind("drop", REQUEST, "the request is lost on the way (a dropped frame): the module never "
                               "sees it and sends nothing"),
    FaultKind("delay", REPLY, "the reply comes late", {
        "ms": Param(_milliseconds, (100.0, 100.0), help="milliseconds, or a range LOW..HIGH")}),
    FaultKind("checksum", REPLY, "the reply has a wrong checksum (CAN: it fails its CRC and is lost)"),
    FaultKind("status", REPLY, "the reply carries another status code", {
        "status": Param(_status, int(Status.INVALID_VALUE), help="a number or a Status name")}),
    FaultKind("tear", REPLY, "the reply arrives in pieces with pauses between them", {
        "pieces": Param(lambda t: _integer(t, "pieces", 2, 9), 3, help="2..9"),
        "pause_ms": Param(lambda t: _number(t, "pause_ms", 0.0, MAX_PAUSE_MS), 2.0,
                          help="milliseconds between two pieces")}),
    FaultKind("garbage", REPLY, "extra bytes arrive before the reply", {
        "bytes": Param(lambda t: _integer(t, "bytes", 1, 64), 3, help="random bytes, 1..64"),
        "data": Param(_hex, None, help="these bytes instead (hex)")}),
    FaultKind("duplicate", REPLY, "the reply arrives more than once", {
        "copies": Param(lambda t: _integer(t, "copies", 1, 8), 1, help="extra copies, 1..8")}),
    FaultKind("wrong_address", REPLY, "the reply names another module", {
        "address": Param(lambda t: _integer(t, "address", 0, 255), None,
                         help="the address it names (default: the module's + 1)")}),
    FaultKind("reset", REQUEST, "the module power-cycles when the request arrives (RAM as after "
                                "power-on, EEPROM kept); without a request filter: at once"),
    FaultKind("stuck", STATE, "the motor stops following its steps: mechanics, switches and encoder "
                              "stay where they are", {
        "axis": _AXIS,
        "load": Param(lambda t: _integer(t, "load", 0, 1023), None,
                      help="what stallGuard2 reads meanwhile (0: a blocked rotor)")}),
    FaultKind("switch", STATE, "a switch is broken: its input is stuck active or inactive", {
        "axis": _AXIS,
        "switch": Param(_choice("switch", SWITCH_NAMES), "left", help="left, right or home"),
        "state": Param(_choice("state", ("active", "inactive")), "active",
                       help="the electrical level it is stuck at")}),
    FaultKind("sag", STATE, "the supply voltage sags (GIO 8, 1 reads it)", {
        "volts": Param(lambda t: _number(t, "volts", 0.0, 100.0), DEFAULT_SAG_VOLTS,
                       help="the sagged supply in volts")}),
)}

#: Keys every kind takes: which requests (the first five) and how often (the rest).
COMMON_KEYS: dict[str, Param] = {
    "endpoint": Param(str, help="tcp, pty, serial, can, mqtt, or a whole endpoint name"),
    "module": Param(_integers("module", 1, 255), help="module slots (the address it started with)"),
    "opcode": Param(_opcodes, help="mnemonics or numbers, e.g. GAP|SAP"),
    "type": Param(_types, help="type numbers or parameter names"),
    "motor": Param(_integers("motor", 0, 255), help="motor (or bank) numbers"),
    "rate": Param(lambda t: _number(t, "rate", 0.0, 1.0), 1.0, help="chance per matching request"),
    "seed": Param(lambda t: _integer(t, "seed", 0, 2**63 - 1), 0, help="of this fault's random numbers"),
    "count": Param(lambda t: _integer(t, "count", 1, 2**31), None, help="inject at most this often"),
    "after": Param(lambda t: _integer(t, "after", 0, 2**31), 0, help="let this many matching "
                                                                     "requests pass first"),
}
def describe_kinds() -> list[dict[str, Any]]:
    """Every kind and key in words and defaults, JSON-ready (a front end builds its forms from it)."""
    def keys(params: Mapping[str, Param]) -> list[dict[str, Any]]:
        return [{"key": name, "help": param.help, "required": param.required,
                 "default": list(param.default) if isinstance(param.default, tuple) else param.default}
                for name, param in params.items()]
    return [{"kind": kind.name, "category": kind.category, "summary": kind.summary,
             "keys": keys(kind.params), "common_keys": keys(COMMON_KEYS)} for kind in KINDS.values()]


#: Keys that make a fault wait for requests (a state fault or a reset without them acts at once).
_TRIGGER_KEYS = ("endpoint", "opcode", "type", "motor", "rate", "count", "after")


# == specs ======================================================================================


@dataclass(frozen=True)
class FaultSpec:
    """One fault as written: its kind, its filters and triggers, its own parameters."""

    kind: FaultKind
    #: The kind's parameters, defaults filled in.
    params: dict[str, Any]
    #: The common keys given (parsed), e.g. {"opcode": frozenset({6}), "rate": 0.1}.
    keys: dict[str, Any]
    #: The spec as text, in the order written (for traces, lists and error messages).
    text: str

    def key(self, name: str) -> Any:
        return self.keys.get(name, COMMON_KEYS[name].default)

    @property
    def waits_for_requests(self) -> bool:
        """A state fault or a reset acts at once unless a key ties it to requests."""
        return self.kind.category == REPLY or self.kind.name == "drop" or any(
            name in self.keys for name in _TRIGGER_KEYS)


def _normalise_kind(text: str) -> FaultKind:
    name = text.strip().lower().replace("-", "_")
    kind = KINDS.get(name) or KINDS.get(name.replace("_", ""))
    if kind is None:
        hint = difflib.get_close_matches(name[:MAX_VALUE_CHARS], KINDS, n=1)
        guess = f"; did you mean {hint[0]!r}?" if hint else ""
        raise FaultSpecError(f"unknown fault {_shown(text)}{guess} (known: {', '.join(KINDS)})")
    return kind


def _value_text(value: Any) -> str:
    """A TOML/JSON value in the spec language's spelling."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, list | tuple):
        return "|".join(_value_text(v) for v in value)
    return str(value)


def make_spec(kind_name: str, items: Iterable[tuple[str, Any]]) -> FaultSpec:
    """A spec from its kind and ``(key, value)`` pairs (values as text, or TOML/JSON values)."""
    kind = _normalise_kind(kind_name)
    params: dict[str, Any] = {}
    keys: dict[str, Any] = {}
    written: list[str] = []
    for raw_key, raw_value in items:
        key = str(raw_key).strip().lower()
        text = _value_text(raw_value).strip()
        if len(key) > MAX_VALUE_CHARS:
            raise FaultSpecError(f"{kind.name}: unknown key {_shown(key)}")
        if not text:
            raise FaultSpecError(f"{kind.name}: {key}= has no value (leave the key out instead)")
        if len(text) > MAX_VALUE_CHARS:
            raise FaultSpecError(f"{kind.name}: {key}= is {len(text):,} characters long "
                                 f"(at most {MAX_VALUE_CHARS})")
        if key in kind.params:
            params[key] = kind.params[key].parse(text)
        elif key in COMMON_KEYS:
            keys[key] = COMMON_KEYS[key].parse(text)
        else:
            known = [*kind.params, *COMMON_KEYS]
            hint = difflib.get_close_matches(key, known, n=1)
            guess = f"; did you mean {hint[0]!r}?" if hint else ""
            raise FaultSpecError(f"{kind.name}: unknown key {_shown(key)}{guess} "
                                 f"(known: {', '.join(known)})")
        written.append(f"{key}={text}")
    for name, param in kind.params.items():
        if name not in params:
            if param.required:
                raise FaultSpecError(f"{kind.name} needs {name}= ({param.help})")
            params[name] = param.default
    return FaultSpec(kind, params, keys, kind.name + (":" + ",".join(written) if written else ""))


def _split(text: str) -> tuple[str, list[tuple[str, str]]]:
    head, _, tail = text.strip().partition(":")
    if len(head) > MAX_VALUE_CHARS:
        raise FaultSpecError(f"unknown fault {_shown(head)}")
    items = []
    for item in (part for part in tail.split(",") if part.strip()):
        key, sep, value = item.partition("=")
        if not sep:
            raise FaultSpecError(f"{_shown(text)}: expected KEY=VALUE, got {_shown(item)}")
        if len(value.strip()) > MAX_VALUE_CHARS:  # named here, before the whole spec's bound
            raise FaultSpecError(f"{head.strip()[:20]}: {key.strip()[:20]}= is "
                                 f"{len(value.strip()):,} characters long (at most {MAX_VALUE_CHARS})")
        items.append((key, value))
    if len(text) > MAX_SPEC_CHARS:
        raise FaultSpecError(f"a fault spec of {len(text):,} characters (at most {MAX_SPEC_CHARS:,})")
    return head, items


def parse_fault(text: str) -> FaultSpec:
    """``KIND[:KEY=VALUE,...]`` (docs/faults.md)."""
    return make_spec(*_split(text))


def fault_from_mapping(table: Mapping[str, Any]) -> FaultSpec:
    """A TOML/JSON table: ``{"kind": "noreply", "opcode": "GAP", "rate": 0.1}``."""
    if "kind" not in table:
        raise FaultSpecError(f"a fault table needs a 'kind' (one of {', '.join(KINDS)})")
    if len(table) > len(COMMON_KEYS) + 8:
        raise FaultSpecError(f"a fault table with {len(table)} keys (a fault has at most "
                             f"{len(COMMON_KEYS) + 4})")
    return make_spec(str(table["kind"]), ((k, v) for k, v in table.items() if k != "kind"))


def fault_spec(fault: FaultSpec | str | Mapping[str, Any], **params: Any) -> FaultSpec:
    """Whatever a front end holds, as a spec: a spec, its text, a table, or a kind + keywords."""
    if isinstance(fault, FaultSpec):
        return fault
    if isinstance(fault, Mapping):
        return fault_from_mapping({**fault, **params})
    if not isinstance(fault, str):  # sim.fault(123): say what is expected (issue 36, N9)
        raise FaultSpecError(f"a fault is a spec string (\"noreply:opcode=GAP\"), a table or a "
                             f"FaultSpec, got {type(fault).__name__} {_shown(repr(fault))}")
    head, items = _split(fault)
    return make_spec(head, [*items, *((k, v) for k, v in params.items() if v is not None)])


def load_fault_file(path: str | Path) -> list[FaultSpec]:
    """Faults from a file: TOML (``[[fault]]`` tables) or JSON (a list of tables, or
    ``{"fault": [...]}``); a plain text file holds one spec per line (``#`` comments).  The file
    must be a regular file of at most MAX_FAULT_FILE bytes holding at most MAX_FAULTS faults
    (a FIFO or a device is refused before it is opened); a UTF-8 byte order mark is skipped; an
    error names the line (text) or the fault's place in the list (TOML, JSON)."""
    source = Path(path)
    try:
        info = source.stat()
        if not stat.S_ISREG(info.st_mode):
            raise FaultSpecError(f"fault file {path}: not a regular file")
        if info.st_size > MAX_FAULT_FILE:
            raise FaultSpecError(f"fault file {path}: {info.st_size:,} bytes (at most "
                                 f"{MAX_FAULT_FILE:,})")
        with open(source, "rb") as stream:
            raw = stream.read(MAX_FAULT_FILE + 1)
        if len(raw) > MAX_FAULT_FILE:  # it grew since
            raise FaultSpecError(f"fault file {path}: more than {MAX_FAULT_FILE:,} bytes")
        text = raw.decode("utf-8-sig")
    except OSError as exc:
        raise FaultSpecError(f"fault file {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise FaultSpecError(f"fault file {path}: not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start})") from None
    try:
        if source.suffix == ".toml":
            import tomllib

            data: Any = tomllib.loads(text)
        elif source.suffix == ".json":
            data = json.loads(text)
        else:
            return _faults_of_lines(text)
        if isinstance(data, dict):
            unknown = set(data) - {"fault", "faults"}
            if unknown:
                raise FaultSpecError(f"unknown top-level key(s) {sorted(unknown)[:5]}: use [[fault]]")
            data = data.get("fault", data.get("faults", []))
        if not isinstance(data, list) or not all(isinstance(t, dict) for t in data):
            raise FaultSpecError("expected a list of fault tables")
        _check_count(len(data))
        specs = []
        for number, table in enumerate(data, 1):
            try:
                specs.append(fault_from_mapping(table))
            except FaultSpecError as exc:
                raise FaultSpecError(f"fault {number}: {exc}") from None
        return specs
    except (ValueError, TypeError) as exc:  # tomllib and json errors are ValueErrors
        raise FaultSpecError(f"fault file {path}: {exc}") from exc
    except RecursionError:  # JSON nested deeper than the parser goes
        raise FaultSpecError(f"fault file {path}: nested too deeply") from None


def _faults_of_lines(text: str) -> list[FaultSpec]:
    """One spec a line, ``#`` comments: an error names its line."""
    specs: list[FaultSpec] = []
    for number, line in enumerate(text.splitlines(), 1):
        spec = line.split("#")[0]
        if not spec.strip():
            continue
        _check_count(len(specs) + 1)
        try:
            specs.append(parse_fault(spec))
        except FaultSpecError as exc:
            raise FaultSpecError(f"line {number}: {exc}") from None
    return specs


def _check_count(count: int) -> None:
    if count > MAX_FAULTS:
        raise FaultSpecError(f"more than {MAX_FAULTS} faults (the most installed at once)")


# == what the wire carries ======================================================================




@dataclass(frozen=True, slots=True)
class Injection:
    """One fault injected: when, which, where, and what it did."""

    time_ns: int
    fault: int
    kind: str
    module: int
    endpoint: str
    request: Request | None
    what: str


# == the injector ===============================================================================


class ActiveFault:
    """An installed fault: its spec, its random numbers, how often it matched and fired."""

    def __init__(self, fault_id: int, spec: FaultSpec) -> None:
        self.id = fault_id
        self.spec = spec
        self.random = random.Random(spec.key("seed"))
        #: Matching requests seen, and injections made.
        self.seen = 0
        self.fired = 0
        #: A state fault in effect (its undo actions), or a one-shot fault that has acted.
        self.applied = False
        self.removed = False
        self._undo: list[Callable[[], None]] = []

    @property
    def kind(self) -> FaultKind:
        return self.spec.kind

    @property
    def exhausted(self) -> bool:
        count = self.spec.key("count")
        return (count is not None and self.fired >= count) or (
            self.kind.category == STATE and self.applied)

    def matches(self, module: TMCLModule, request: Request, endpoint: str) -> bool:
        keys = self.spec.keys
        if not keys:
            return True
        modules = keys.get("module")
        if modules is not None and module.slot not in modules:
            return False
        for name, value in (("opcode", request.opcode), ("type", request.type),
                            ("motor", request.motor)):
            allowed = keys.get(name)
            if allowed is not None and value not in allowed:
                return False
        wanted = keys.get("endpoint")
        return wanted is None or endpoint == wanted or endpoint.startswith(wanted + " ")

    def fires(self, module: TMCLModule, request: Request, endpoint: str) -> bool:
        """One matching request more: does the fault strike it?  (Draws its random number.)"""
        if self.exhausted or not self.matches(module, request, endpoint):
            return False
        self.seen += 1
        if self.seen <= self.spec.key("after"):
            return False
        rate = self.spec.key("rate")
        if rate < 1.0 and self.random.random() >= rate:
            return False
        self.fired += 1
        return True

    def describe(self) -> dict[str, Any]:
        """As a dashboard or MQTT lists it."""
        return {"id": self.id, "spec": self.spec.text, "kind": self.kind.name,
                "category": self.kind.category, "fired": self.fired, "seen": self.seen,
                "applied": self.applied, "exhausted": self.exhausted}


_INJECTORS: weakref.WeakKeyDictionary[Simulation, FaultInjector] = weakref.WeakKeyDictionary()


class FaultInjector:
    """The faults of one simulation.  Not thread-safe: call it on the server's event loop."""

    def __init__(self, simulation: Simulation) -> None:
        self.simulation = simulation
        self.faults: dict[int, ActiveFault] = {}
        #: Every injection so far (the last :data:`HISTORY`).
        self.history: deque[Injection] = deque(maxlen=HISTORY)
        self._next_id = 1
        #: Faults that watch requests (the simulation calls before/after while there are any).
        self._watching: list[ActiveFault] = []
        #: What before() decided for the request being executed: module id -> (module, faults).
        self._struck: dict[int, tuple[TMCLModule, list[ActiveFault]]] = {}
        self._endpoint = UNNAMED

    @classmethod
    def of(cls, simulation: Simulation) -> FaultInjector:
        """The simulation's injector, made on first use."""
        injector = _INJECTORS.get(simulation)
        if injector is None:
            injector = _INJECTORS[simulation] = cls(simulation)
        return injector

    # -- the API: add, remove, list ----------------------------------------------------------

    def add(self, fault: FaultSpec | str | Mapping[str, Any], **params: Any) -> ActiveFault:
        """Install a fault; a state fault (or a reset) without request keys acts at once."""
        spec = fault_spec(fault, **params)
        if len(self.faults) >= MAX_FAULTS:
            raise FaultSpecError(f"{MAX_FAULTS} faults are installed (the most at once): remove "
                                 "some first")
        self._check(spec)
        active = ActiveFault(self._next_id, spec)
        self._next_id += 1
        self.faults[active.id] = active
        if spec.waits_for_requests:
            self._watching.append(active)
            self.simulation.faults = self
        else:
            for module in self._modules(spec):
                active.fired += 1
                self._strike_now(active, module)
            if spec.kind.category == REQUEST:  # a reset at once: done, nothing to undo
                del self.faults[active.id]
        return active

    def add_all(self, faults: Iterable[FaultSpec | str | Mapping[str, Any]]) -> list[ActiveFault]:
        return [self.add(fault) for fault in faults]

    def remove(self, fault: int | ActiveFault) -> None:
        """Take a fault away; a state fault is undone (the axis follows again, ...)."""
        active = self.faults.pop(fault if isinstance(fault, int) else fault.id, None)
        if active is None:
            return
        active.removed = True
        if active in self._watching:
            self._watching.remove(active)
        if not self._watching and self.simulation.faults is self:
            self.simulation.faults = None
        undo, active._undo = active._undo, []
        for action in reversed(undo):
            action()
        if undo:
            self.simulation.notify_changed()

    def clear(self, module: int | None = None) -> None:
        """Remove every fault (of the module with this slot: those that name it alone)."""
        for active in list(self.faults.values()):
            modules = active.spec.key("module")
            if module is None or modules == frozenset({module}):
                self.remove(active)

    def describe(self) -> list[dict[str, Any]]:
        return [active.describe() for active in self.faults.values()]

    def power_cycle(self, module: TMCLModule) -> None:
        """Switch a module off and on now (RAM reset, EEPROM kept)."""
        module.power_cycle()
        self.simulation.notify_changed()

    def _modules(self, spec: FaultSpec) -> list[TMCLModule]:
        slots = spec.key("module")
        return [m for m in self.simulation.modules if slots is None or m.slot in slots]

    def _check(self, spec: FaultSpec) -> None:
        """Refuse what no module can do (an axis it does not have) before anything happens."""
        axis = spec.params.get("axis")
        modules = self._modules(spec)
        if not modules:
            raise FaultSpecError(f"{spec.text}: no module has slot {sorted(spec.key('module'))}")
        for module in modules:
            if axis is not None and axis >= len(module.axes):
                raise FaultSpecError(f"{spec.text}: the {module.type.name} has axes "
                                     f"0..{len(module.axes) - 1}")

    # -- the simulation's hooks (Simulation._execute) ----------------------------------------

    def before(self, request: Request, interface: Interface, targets: list[TMCLModule],
               sink: ReplySink | None) -> list[TMCLModule]:
        """A request is about to run on ``targets``: decide its faults; returns the modules that
        still get it (a dropped request or a reset module gets nothing)."""
        self._struck = {}
        self._endpoint = endpoint = getattr(sink, "endpoint", None) or UNNAMED
        kept = targets
        for module in targets:
            struck = [f for f in self._watching if f.fires(module, request, endpoint)]
            if not struck:
                continue
            lost = next((f for f in struck if f.kind.category == REQUEST), None)
            if lost is None:
                self._struck[id(module)] = (module, struck)
                continue
            kept = [m for m in kept if m is not module]
            if lost.kind.name == "reset":
                self._note(lost, module, request, "the module power-cycles instead of answering "
                           "(RAM as after power-on, EEPROM kept)")
                self.power_cycle(module)
            else:
                self._note(lost, module, request, "the request is lost on the way: the module "
                           "never sees it")
        self._retire()
        return kept

    def after(self, request: Request, interface: Interface, routed: list[Routed]) -> list[Routed]:
        """The modules ran the request: lose or alter their replies, start triggered faults."""
        struck, self._struck = self._struck, {}
        if not struck:
            return routed
        replies: dict[int, Any] = {id(module): reply for module, reply in routed}
        for key, (module, faults) in struck.items():
            reply = replies.get(key)
            delivery: Delivery | None = None
            for fault in faults:
                if fault.kind.category == STATE:
                    self._strike_now(fault, module, request)
                elif reply is None:
                    self._note(fault, module, request, f"{fault.kind.name}: no reply to alter")
                elif fault.kind.name == "noreply":
                    self._note(fault, module, request, "the reply is lost (the module executed "
                               "the command)")
                    reply = None
                else:
                    delivery = delivery or Delivery(reply)
                    self._note(fault, module, request, self._alter(fault, delivery, module, interface))
            replies[key] = delivery if delivery is not None and reply is not None else reply
        self._retire()
        return [(module, replies[id(module)]) for module, _ in routed if replies[id(module)] is not None]

    def _retire(self) -> None:
        """Faults that will never fire again stop being asked."""
        if any(f.exhausted for f in self._watching):
            self._watching = [f for f in self._watching if not f.exhausted]
            if not self._watching and self.simulation.faults is self:
                self.simulation.faults = None

    # -- what each fault does ------------------------------------------------------------------

    def _alter(self, fault: ActiveFault, delivery: Delivery, module: TMCLModule,
               interface: Interface) -> str:
        """Apply one reply fault to ``delivery``; returns what it did, in words."""
        params, name = fault.spec.params, fault.kind.name
        reply = delivery.reply
        if name == "delay":
            lo, hi = params["ms"]
            ms = lo if lo == hi else fault.random.uniform(lo, hi)
            delivery.delay_s += ms / 1000
            return f"the reply comes {ms:.1f} ms late"
        if name == "checksum":
            delivery.bad_checksum = True
            if interface is Interface.CAN:
                return "the reply frame fails its CRC: every receiver discards it (lost)"
            good = reply.encode()[-1]
            return f"the reply's checksum is {good ^ 0xFF:#04x} instead of {good:#04x}"
        if name == "tear":
            delivery.pieces, delivery.pause_s = params["pieces"], params["pause_ms"] / 1000
            return f"the reply comes in {params['pieces']} pieces, {params['pause_ms']:g} ms apart"
        if name == "garbage":
            data = params["data"] or fault.random.randbytes(params["bytes"])
            delivery.garbage += data
            return f"{len(data)} garbage bytes before the reply: {data.hex(' ')}"
        if name == "duplicate":
            delivery.copies += params["copies"]
            return f"the reply is sent {delivery.copies} times"
        if not isinstance(reply, Reply):  # the 136 string and 134's record have no such fields
            return f"{name}: not applicable to this reply's special layout"
        if name == "status":
            delivery.reply = reply._replace(status=params["status"])
            return f"the reply's status is {params['status']} instead of {reply.status}"
        if name == "wrong_address":
            address = params["address"]
            if address is None:
                address = reply.module % 255 + 1
            delivery.reply = reply._replace(module=address)
            return f"the reply names module {address} instead of {reply.module}"
        raise AssertionError(f"no reply action for {name}")

    def _strike_now(self, fault: ActiveFault, module: TMCLModule, request: Request | None = None) -> None:
        """A state fault starts (or a reset happens) on ``module``."""
        params, name = fault.spec.params, fault.kind.name
        if name == "reset":
            fault.applied = True
            self._note(fault, module, request, "the module power-cycles (RAM as after power-on, "
                       "EEPROM kept)")
            self.power_cycle(module)
            return
        if name == "stuck":
            axis, load = params["axis"], params["load"]
            module.set_axis_stuck(axis, True, load)
            fault._undo.append(lambda: module.set_axis_stuck(axis, False))
            what = f"axis {axis} is stuck: the motor stops following its steps" + (
                f" (stallGuard2 reads {load})" if load is not None else "")
        elif name == "switch":
            axis, switch, active = params["axis"], params["switch"], params["state"] == "active"
            module.break_switch(axis, switch, active)
            fault._undo.append(lambda: module.break_switch(axis, switch, None))
            what = f"the {switch} switch of axis {axis} is broken: stuck {params['state']}"
        elif name == "sag":
            before, volts = module.world.supply_voltage, params["volts"]
            was = module.supply_voltage
            module.set_supply_voltage(volts)
            fault._undo.append(lambda: self._restore_supply(module, before))
            what = f"the supply sags to {volts:g} V (was {was:g} V)"
        else:
            raise AssertionError(f"no state action for {name}")
        fault.applied = True
        self._note(fault, module, request, what)
        self.simulation.notify_changed()

    @staticmethod
    def _restore_supply(module: TMCLModule, volts: float | None) -> None:
        module.world.supply_voltage = volts
        module.emit("supply_changed", None, volts=module.supply_voltage)

    def _note(self, fault: ActiveFault, module: TMCLModule, request: Request | None, what: str) -> None:
        endpoint = self._endpoint if request is not None else UNNAMED
        self.history.append(Injection(module.now_ns, fault.id, fault.kind.name, module.slot, endpoint,
                                      request, what))
        tracer = self.simulation.tracer
        if tracer is not None:
            tracer.injected(endpoint, module, request, f"{what} [fault #{fault.id} {fault.spec.text}, "
                            "injected]", {"fault": fault.kind.name, "fault_id": fault.id,
                                          "spec": fault.spec.text})


# == Python front end ===========================================================================


class FaultHandle:
    """A fault installed from another thread (``SimulatorThread.fault``): a context manager
    that removes it at the end of its block, and a window on how often it struck."""

    def __init__(self, call: Callable[..., Any], injector: FaultInjector, active: ActiveFault) -> None:
        self._call = call
        self.injector = injector
        self.active = active

    @property
    def id(self) -> int:
        return self.active.id

    @property
    def fired(self) -> int:
        return self._call(lambda: self.active.fired)

    def injections(self) -> list[Injection]:
        """What this fault did so far."""
        return self._call(lambda: [i for i in self.injector.history if i.fault == self.active.id])

    def remove(self) -> None:
        self._call(self.injector.remove, self.active)

    def __enter__(self) -> FaultHandle:
        return self

    def __exit__(self, *exc: object) -> None:
        self.remove()
