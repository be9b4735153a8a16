"""``tmcl replay CAPTURE``: a captured session against a fresh simulator, every reply compared.

    tmcl replay session.jsonl                   # the module type the capture's identity names
    tmcl replay session.jsonl --world rig.toml --tolerance 0.005 --json

The requests run on an in-process simulation on the virtual clock, each at its captured
instant (the first request is the simulation's time 0).  A reply matches when its status and
opcode are the module's and its value is, exactly for a setting; a value that moves (with the
axis, with time: positions, speeds, load, timers) matches when the simulator answers it at
some instant of the window the module could have answered in (docs/capture.md, "Judging"):

    [request - W - tolerance, reply + tolerance]

W is the round trip of the commands that set the present motion going (the module started
it somewhere inside theirs).  Reads are pure, so the replay answers each read at several
instants of its window, in time order across neighbouring reads, before the next command that
changes anything; that command then runs at its own request instant.  Program uploads (132,
the commands, 133) and runs (129) are replayed as such: the stored commands are not reads.

Exit status: 0 nothing diverged, 1 something did, 2 the capture (or an option) cannot be used
(one line naming it and why).  This module imports the simulator; ``tmcl`` loads it only for
this command (tmcl_server/tool/__init__.py).
"""

from __future__ import annotations

import argparse
import heapq
import json
import sys
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from itertools import pairwise
from pathlib import Path
from typing import Any, Literal, NoReturn

from tmcl_server.capture import NO_REPLY, REPLY, REQUEST, UNSOLICITED, Capture, CapturedFrame, open_capture
from tmcl_server.cli import DEFAULT_MODULE_TYPE, UsageError, add_model_options, check_model_options
from tmcl_server.decode import (
    CaptureError,
    Vocabulary,
    describe_outcome,
    describe_program_record,
    describe_request,
    describe_version_string,
    is_version_string,
    module_type_by_number,
    opcode_name,
)
from tmcl_server.protocol import (
    FRAME_LENGTH,
    ChecksumError,
    Reply,
    Request,
    decode_can_reply,
    decode_can_request,
    decode_reply,
)
from tmcl_server.server import ServerConfig, build_simulation
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import ApplicationStatus, Opcode, Status
from tmcl_spec.modules import ModuleType, module_type
from tmcl_spec.numbers import NS_PER_MS, NS_PER_S, to_int32
from tmcl_spec.package import add_version_option, doc, safe_console
from tmcl_spec.parameters import GP, Motion

#: How the module's answer may lag the simulator's, beyond the round trips (seconds): the
#: real module answers from its state some time inside its processing, and its chips update
#: on their own periods.  ``--tolerance`` overrides it.
DEFAULT_TOLERANCE_S = 0.002
#: A moving read is answered at instants this far apart across its window ...
SAMPLE_STEP_NS = 1_000_000
#: ... at most this many per read (spread evenly over a longer window).  A value that moves
#: one way across the window lies between the answers at its ends; the points between find
#: where it turns (a speed's peak, see _bounds) at little cost (each is a request).
MAX_SAMPLES = 16
#: Where a capture has no instants (a hex dump): requests this far apart.
UNTIMED_STEP_NS = NS_PER_MS

Judged = Literal["steady", "axis", "time", "access"]

#: How a read is judged, by how its parameter moves (the tables' ParamSpec.motion column):
#: exactly (a setting), over its window (moves with the axis, changes at its events or at the
#: firmware's pass, moves with time or the program), or read once (reading it changes it).
_JUDGED: dict[Motion, Judged] = {
    Motion.SETTING: "steady", Motion.EVENTS: "axis", Motion.AXIS: "axis", Motion.TASKS: "axis",
    Motion.TIME: "time", Motion.PROGRAM: "time", Motion.ACCESS: "access"}


def _how_it_moves(kind: ModuleType, opcode: int, type_: int, bank: int) -> Judged:
    """How a read's answer moves: ``steady`` (a setting: only a command changes it), ``axis``
    (moves with the axis or at its events), ``time`` (moves with time: the tick timer, a
    program's state) or ``access`` (reading it changes it: AP 207 clears the error flags,
    GP 133 draws a number): the parameter's row says (``ParamSpec.motion``)."""
    if opcode == Opcode.GAP:
        row = kind.axis_parameters.get(type_)
    elif opcode == Opcode.GGP:
        row = kind.global_parameters.get(bank, {}).get(type_)
    elif opcode == Opcode.GET_APPLICATION_STATUS:
        return "time"
    else:
        return "steady"
    return "steady" if row is None or row.motion is None else _JUDGED[row.motion]


#: Commands that only read: the replay may answer them at several instants.
_READS = frozenset({int(Opcode.GAP), int(Opcode.GGP), int(Opcode.GIO),
                    int(Opcode.GET_APPLICATION_STATUS), int(Opcode.GET_FIRMWARE_VERSION),
                    int(Opcode.READ_PROGRAM_MEMORY)})


# -- a capture as exchanges -------------------------------------------------------------------

@dataclass
class Exchange:
    """A request and what came back, as captured."""

    index: int
    t_ns: int | None
    reply_t_ns: int | None
    endpoint: str
    address: int | None
    data: bytes
    can_id: int | None
    #: The reply's bytes; None: the module did not answer.
    reply: bytes | None = None
    #: False for a last request whose outcome the capture did not get to.
    complete: bool = True

    def request(self) -> Request | None:
        """The request's fields (None: a frame that is no request, e.g. a wrong checksum)."""
        try:
            if self.can_id is not None:
                return decode_can_request(self.can_id, self.data)
            if len(self.data) != FRAME_LENGTH:
                return None
            return Request(self.data[0], self.data[1], self.data[2], self.data[3],
                           to_int32(int.from_bytes(self.data[4:8], "big")))
        except ValueError:
            return None


@dataclass
class Unasked:
    """A frame the module sent unasked (a 138 event)."""

    t_ns: int | None
    data: bytes
    can: bool


def exchanges(frames: Iterable[CapturedFrame]) -> Iterator[Exchange | Unasked]:
    """Pairs each request with the reply that follows it; unasked frames on their own."""
    pending: Exchange | None = None
    index = 0
    for frame in frames:
        if frame.direction == REQUEST:
            if pending is not None:
                yield pending
            index += 1
            pending = Exchange(index, frame.t_ns, None, frame.endpoint, frame.address, frame.data,
                               frame.can_id)
        elif frame.direction in (REPLY, NO_REPLY) and pending is not None:
            if frame.direction == REPLY:
                pending.reply, pending.reply_t_ns = frame.data, frame.t_ns
            yield pending
            pending = None
        elif frame.direction in (REPLY, UNSOLICITED):
            yield Unasked(frame.t_ns, frame.data, frame.can_id is not None)
    if pending is not None:  # the capture ended while the proxy waited for the reply
        pending.complete = False
        yield pending


# -- verdicts ---------------------------------------------------------------------------------

@dataclass
class Divergence:
    """One reply (or unasked frame) the simulator answers otherwise."""

    t: float | None
    request: str
    module: str
    simulator: str

    def line(self) -> str:
        when = f"{self.t:12.6f}" if self.t is not None else f"{'-':>12}"
        return f"{when}  {self.request}: module {self.module}; simulator {self.simulator}"

    def as_dict(self) -> dict[str, Any]:
        return {"t": self.t, "request": self.request, "module": self.module,
                "simulator": self.simulator}


@dataclass
class Summary:
    requests: int = 0
    matched: int = 0
    diverged: int = 0
    #: Moving values a capture without instants cannot judge (a hex dump).
    not_judged: int = 0
    #: Mnemonic -> [requests, diverged].
    by_command: dict[str, list[int]] = field(default_factory=dict)
    events_captured: int = 0
    events_simulated: int = 0
    events_diverged: int = 0
    notes: list[str] = field(default_factory=list)

    def count(self, mnemonic: str, outcome: str) -> None:
        self.requests += 1
        row = self.by_command.setdefault(mnemonic, [0, 0])
        row[0] += 1
        if outcome == "diverged":
            self.diverged += 1
            row[1] += 1
        elif outcome == "matched":
            self.matched += 1
        else:
            self.not_judged += 1

    def as_dict(self) -> dict[str, Any]:
        return {"requests": self.requests, "matched": self.matched, "diverged": self.diverged,
                "not_judged": self.not_judged,
                "by_command": {name: {"requests": n, "diverged": d}
                               for name, (n, d) in sorted(self.by_command.items())},
                "events": {"captured": self.events_captured, "simulated": self.events_simulated,
                           "diverged": self.events_diverged},
                "notes": self.notes}

    def lines(self, tolerance_s: float) -> list[str]:
        commands = ", ".join(f"{name} {d} of {n}" if d else f"{name} {n}"
                             for name, (n, d) in sorted(self.by_command.items()))
        judged = f", {self.not_judged} not judged (no instants)" if self.not_judged else ""
        lines = [f"{self.requests} requests: {self.matched} matched, {self.diverged} diverged"
                 f"{judged} ({commands or 'none'})"]
        if self.events_captured or self.events_simulated:
            lines.append(f"unasked frames: {self.events_captured} from the module, "
                         f"{self.events_simulated} from the simulator, {self.events_diverged} diverged")
        lines.append(f"moving values judged over [request - W - {tolerance_s:g} s, reply + "
                     f"{tolerance_s:g} s], W the round trip of the commands that set the motion "
                     "going (--tolerance)")
        return lines + [f"note: {note}" for note in self.notes]

    @property
    def exit_code(self) -> int:
        return 1 if self.diverged or self.events_diverged else 0


# -- the replay -------------------------------------------------------------------------------

class _Sink:
    """Catches what the simulated modules send unasked (138 events), with the instant."""

    def __init__(self, simulation: Simulation, can: bool) -> None:
        self.simulation = simulation
        self.can = can
        self.frames: list[tuple[int, bytes]] = []

    def send_unsolicited(self, reply: Reply) -> None:
        self.frames.append((self.simulation.now_ns,
                            reply.encode_can() if self.can else reply.encode()))


@dataclass(eq=False)
class _Pending:
    """A read waiting for its answers at the instants of its window."""

    exchange: Exchange
    request: Request | None
    #: Its answer moves: judged over the window (else at its request instant alone).
    judge_window: bool
    #: Its request instant on the simulation's clock.
    main_t: int = 0
    remaining: int = 0
    main: bytes | None = None
    answers: list[bytes | None] = field(default_factory=list)
    done: bool = False


class Replay:
    """Feeds a capture's exchanges to a simulation on the virtual clock and judges each reply."""

    def __init__(self, simulation: Simulation, kind: ModuleType, tolerance_s: float,
                 report: Callable[[Divergence], None]) -> None:
        self.simulation = simulation
        self.kind = kind
        self.words = Vocabulary(kind)
        self.tolerance_ns = round(tolerance_s * NS_PER_S)
        self.report = report
        self.summary = Summary()
        self._serial_sink = _Sink(simulation, can=False)
        self._can_sink = _Sink(simulation, can=True)
        self._origin: int | None = None
        self._last_t: int | None = None
        self._untimed = False
        #: The round trip of the commands that set the present motion going (see module doc).
        self._motion_ns = 0
        #: No sample before this instant: the last command that changed anything ran there.
        self._floor_ns = 0
        self._heap: list[tuple[int, int, _Pending]] = []
        self._sequence = 0
        self._order: deque[_Pending] = deque()
        self._tick_timer_set = False
        self._unasked: list[Unasked] = []

    # -- time ---------------------------------------------------------------------------------

    def _instant(self, t_ns: int | None) -> int:
        """Simulation time of a captured instant (the first request is 0)."""
        if t_ns is None:
            self._untimed = True
            self._last_t = 0 if self._last_t is None else self._last_t + UNTIMED_STEP_NS
            return self._last_t
        if self._origin is None:
            self._origin = t_ns
        return max(0, t_ns - self._origin)

    def _advance(self, t_ns: int) -> None:
        if t_ns > self.simulation.now_ns:
            self.simulation.advance_to_ns(t_ns)

    # -- feeding ------------------------------------------------------------------------------

    def feed(self, item: Exchange | Unasked) -> None:
        if isinstance(item, Unasked):
            self._unasked.append(item)
            return
        if not item.complete:
            self.summary.notes.append(f"the last request ({self._request_text(item, item.request())}) "
                                      "has no outcome: the capture ended first; left out")
            return
        t = self._instant(item.t_ns)
        reply_t = self._instant(item.reply_t_ns) if item.reply_t_ns is not None else t
        request = item.request()
        if request is not None and self._is_read(request):
            motion = _how_it_moves(self.kind, request.opcode, request.type, request.motor)
            if motion == "time" and self._first_tick_timer_read(request, item):
                self._set_tick_timer(item, request, t)
            earliest = max(self._floor_ns, t - self._motion_ns - self.tolerance_ns)
            self._run_before(earliest)
            windowed = motion in ("axis", "time") or (motion == "steady" and self._program_runs())
            pending = _Pending(item, request, windowed, t)
            instants = _window(earliest, reply_t + self.tolerance_ns, t) \
                if windowed and not self._untimed else [t]
            self._order.append(pending)
            pending.remaining = len(instants)
            for instant in instants:
                self._sequence += 1
                heapq.heappush(self._heap, (instant, self._sequence, pending))
            return
        self._command(item, request, t, reply_t)

    def _is_read(self, request: Request) -> bool:
        return request.opcode in _READS and not any(
            module.program.downloading for module in self.simulation.modules)

    def _program_runs(self) -> bool:
        return any(m.program.interpreter.status is ApplicationStatus.RUN
                   for m in self.simulation.modules)

    def _idle(self) -> bool:
        for module in self.simulation.modules:
            if module.program.interpreter.status is ApplicationStatus.RUN:
                return False
            for index in range(len(module.axes)):
                status = module.axis(index).status()
                if status.velocity or status.reference_search:
                    return False
        return True

    def _command(self, item: Exchange, request: Request | None, t: int, reply_t: int) -> None:
        """A command that changes something: the reads before it are answered first (up to
        its instant, no later: the module answered them before this was even sent)."""
        self._run_before(t, command=True)
        idle = self._idle()
        self._advance(t)
        answer = self._execute(item)
        round_trip = max(0, reply_t - t) if item.reply is not None else 0
        self._motion_ns = round_trip if idle else max(self._motion_ns, round_trip)
        self._floor_ns = t
        if request is not None and request.opcode == Opcode.SGP and request.type == GP.TICK_TIMER \
                and request.motor == 0:
            self._tick_timer_set = True
        pending = _Pending(item, request, False, t, main=answer, done=True)
        self._order.append(pending)
        self._emit()

    def _run_before(self, t_ns: int, command: bool = False) -> None:
        """Answer the reads' instants before ``t_ns`` in time order.  Before a ``command``
        (at ``t_ns``) those at its instant too, and the later ones are forgotten: the module
        answered those reads before the command was even sent."""
        heap = self._heap
        while heap and (heap[0][0] < t_ns or (command and heap[0][0] == t_ns)):
            instant, _, pending = heapq.heappop(heap)
            self._advance(instant)
            answer = self._execute(pending.exchange)
            if instant == pending.main_t:
                pending.main = answer
            pending.answers.append(answer)
            pending.remaining -= 1
        if command:
            for _, _, pending in heap:
                pending.remaining -= 1
            heap.clear()
        self._emit()

    def _execute(self, item: Exchange) -> bytes | None:
        simulation = self.simulation
        if item.can_id is not None:
            try:
                request = decode_can_request(item.can_id, item.data)
            except ValueError:
                return None
            routed = simulation.handle_can_request(request, self._can_sink)
            return routed[0][1].encode_can() if routed else None
        if len(item.data) != FRAME_LENGTH:
            return None
        routed = simulation.handle_serial_frame(item.data, self._serial_sink)
        return routed[0][1].encode() if routed else None

    # -- the tick timer -----------------------------------------------------------------------

    def _first_tick_timer_read(self, request: Request, item: Exchange) -> bool:
        return (not self._tick_timer_set and request.opcode == Opcode.GGP
                and request.type == GP.TICK_TIMER and request.motor == 0 and item.reply is not None)

    def _set_tick_timer(self, item: Exchange, request: Request, t: int) -> None:
        """The module had been on for a while: the simulator's tick timer takes its count at
        the first read (a capture cannot say since when), as if a host had set it (SGP 132)."""
        reply = _reply_fields(item.reply, item.can_id is not None)
        if reply is None or reply.status != Status.OK:
            return
        self._tick_timer_set = True
        self._run_before(t, command=True)
        self._advance(t)
        setting = Request(request.address, Opcode.SGP, GP.TICK_TIMER, 0, reply.value)
        self._execute(Exchange(0, None, None, "", request.address,
                               setting.encode_can() if item.can_id is not None else setting.encode(),
                               item.can_id))
        when = _seconds(item.t_ns, self._origin)
        self.summary.notes.append(f"GGP 132 (tick timer) set to the module's {to_int32(reply.value)} "
                                  f"at t={when} s: a capture does not say how long the module had "
                                  "been on")

    # -- judging ------------------------------------------------------------------------------

    def _emit(self) -> None:
        order = self._order
        while order and (order[0].done or order[0].remaining <= 0):
            pending = order.popleft()
            self._judge(pending)

    def _judge(self, pending: _Pending) -> None:
        item, request = pending.exchange, pending.request
        mnemonic = opcode_name(request.opcode) if request is not None else "bad frame"
        module, simulator = item.reply, pending.main
        can = item.can_id is not None
        if module == simulator or (pending.judge_window and not self._untimed
                                   and _within(module, pending.answers, can)):
            self.summary.count(mnemonic, "matched")
            return
        if pending.judge_window and self._untimed:  # no window to judge a moving value by
            self.summary.count(mnemonic, "not judged")
            return
        self.summary.count(mnemonic, "diverged")
        shown = self._outcome(request, simulator, can)
        spread = _spread(pending.answers, simulator, can) if pending.judge_window else ""
        self.report(Divergence(_seconds(item.t_ns, self._origin), self._request_text(item, request),
                               self._outcome(request, module, can), shown + spread))

    def _request_text(self, item: Exchange, request: Request | None) -> str:
        if request is None:
            return f"frame {item.data.hex(' ')}"
        text = describe_request(request.opcode, request.type, request.motor, request.value,
                                self.words)
        if item.can_id is None and len(item.data) == FRAME_LENGTH and \
                sum(item.data[:8]) & 0xFF != item.data[8]:
            text += " (wrong checksum)"
        return text

    def _outcome(self, request: Request | None, data: bytes | None, can: bool) -> str:
        """What a reply says, as ``tmcl send`` shows it."""
        if data is None:
            return "(no reply)"
        if request is not None and request.opcode == Opcode.GET_FIRMWARE_VERSION and \
                request.type == 0:
            frame = data if not can else b"\0" + data
            if is_version_string(frame):
                return describe_version_string(frame)
        if request is not None and request.opcode == Opcode.READ_PROGRAM_MEMORY and not can and \
                len(data) == FRAME_LENGTH and not (data[2] in Status._value2member_map_
                                                   and data[3] == Opcode.READ_PROGRAM_MEMORY):
            return describe_program_record(data, request.value, self.words)
        reply = _reply_fields(data, can)
        if reply is None:
            return f"{data.hex(' ')} (not a reply: wrong checksum or length)"
        return describe_outcome(reply.status, reply.opcode, request.type if request else 0,
                                reply.value)

    def finish(self) -> Summary:
        """The end of the capture: the reads still open, then the unasked frames."""
        self._run_before(1 << 62)
        self._emit()
        last = max((u.t_ns for u in self._unasked if u.t_ns is not None), default=None)
        if last is not None:
            self._advance(self._instant(last) + self.tolerance_ns)
        self._compare_unasked()
        return self.summary

    def _compare_unasked(self) -> None:
        simulated = sorted(self._serial_sink.frames + self._can_sink.frames)
        captured = self._unasked
        self.summary.events_captured = len(captured)
        self.summary.events_simulated = len(simulated)
        for index in range(max(len(captured), len(simulated))):
            mine = captured[index] if index < len(captured) else None
            theirs = simulated[index] if index < len(simulated) else None
            if mine is not None and theirs is not None and mine.data == theirs[1]:
                continue
            self.summary.events_diverged += 1
            can = mine.can if mine is not None else False
            when = _seconds(mine.t_ns, self._origin) if mine is not None and mine.t_ns is not None \
                else (theirs[0] / NS_PER_S if theirs is not None else None)
            self.report(Divergence(when, "(unasked frame)",
                                   self._outcome(None, mine.data, can) if mine else "(nothing)",
                                   self._outcome(None, theirs[1], can) if theirs else "(nothing)"))


def _window(start: int, end: int, main: int) -> list[int]:
    """The instants a moving read is answered at: its window's ends, its request instant, and
    every SAMPLE_STEP_NS between (at most MAX_SAMPLES)."""
    end = max(end, start)
    count = min(MAX_SAMPLES, (end - start) // SAMPLE_STEP_NS + 1)
    step = (end - start) / max(1, count - 1) if count > 1 else 0
    instants = {start + round(i * step) for i in range(count)} | {start, end, main}
    return sorted(instants)


def _reply_fields(data: bytes | None, can: bool) -> Reply | None:
    if data is None:
        return None
    try:
        if can:
            return decode_can_reply(data) if len(data) >= 7 else None
        return decode_reply(data) if len(data) == FRAME_LENGTH else None
    except ChecksumError:
        return None


def _within(module: bytes | None, answers: list[bytes | None], can: bool) -> bool:
    """Whether the module's reply is one the simulator gives somewhere in the window: the same
    header (addresses, status, opcode) as one of its answers, the value within their bounds
    (:func:`_bounds`: a moving value passes every value between)."""
    mine = _reply_fields(module, can)
    if mine is None:
        return module in answers
    values = [reply.value for reply in (_reply_fields(a, can) for a in answers)
              if reply is not None and reply[:4] == mine[:4]]
    if not values:
        return False
    low, high = _bounds(values)
    return low <= mine.value <= high


def _bounds(values: list[int]) -> tuple[int, int]:
    """The least and greatest value a moving quantity takes over the window, from its values
    at the window's instants (in time order).  Between two instants it lies between their
    values, except where it turns (a speed at its peak): past an answer greater (or less) than
    both its neighbours it may go on by up to the largest step between neighbouring answers,
    the change it makes in one interval at most (docs/capture.md)."""
    low, high = min(values), max(values)
    widest = max((abs(b - a) for a, b in pairwise(values)), default=0)
    for before, here, after in zip(values, values[1:], values[2:], strict=False):
        if here >= before and here >= after and (here > before or here > after):
            high = max(high, here + widest)
        if here <= before and here <= after and (here < before or here < after):
            low = min(low, here - widest)
    return low, high


def _spread(answers: list[bytes | None], main: bytes | None, can: bool) -> str:
    values = sorted({reply.value for reply in (_reply_fields(a, can) for a in answers)
                     if reply is not None})
    if len(values) > 1:
        return f" ({values[0]}..{values[-1]} over the window)"
    return ""


def _seconds(t_ns: int | None, origin: int | None) -> float | None:
    if t_ns is None:
        return None
    return round((t_ns - (origin or 0)) / NS_PER_S, 6)


# -- running it -------------------------------------------------------------------------------

@dataclass
class ReplayResult:
    divergences: list[Divergence]
    summary: Summary
    tolerance_s: float

    def report(self) -> str:
        return "\n".join([d.line() for d in self.divergences] + self.summary.lines(self.tolerance_s))


def _module_type_of(capture: Capture, chosen: str | None) -> ModuleType:
    if chosen is not None:
        try:
            return module_type(chosen)
        except ValueError as exc:
            raise UsageError(f"argument --module-type: {exc}") from None
    identity = capture.identity or {}
    number = identity.get("module_number")
    if number is None:
        return module_type(DEFAULT_MODULE_TYPE)
    kind = module_type_by_number(number) if isinstance(number, int) else None
    if kind is None:
        raise UsageError(f"{capture.path}: the module ({identity.get('version', number)}) is no type "
                         "the simulator has; choose one with --module-type")
    return kind


def _addresses(capture: Capture) -> list[int]:
    """The module addresses the capture's requests go to (one module each)."""
    requests = [frame.address for frame in capture.frames() if frame.direction == REQUEST]
    if not requests:
        raise CaptureError(f"{capture.path}: no TMCL request in it ({capture.kind})")
    return sorted({a for a in requests if a is not None and 1 <= a <= 255}) or [1]


def replay_capture(path: str | Path, *, module_type_name: str | None = None,
                   axis_core: str | None = None, world: str | None = None,
                   state_dir: str | None = None, tolerance_s: float = DEFAULT_TOLERANCE_S,
                   report: Callable[[Divergence], None] | None = None) -> ReplayResult:
    """Replay one capture; CaptureError (one line) if it cannot be read, UsageError for an
    option that does not fit it.  ``report`` hears each divergence as it is found."""
    capture = open_capture(path)
    kind = _module_type_of(capture, module_type_name)
    config = ServerConfig(addresses=_addresses(capture), endpoints={}, clock="virtual",
                          module_type=kind.key, axis_core=axis_core, world=world,
                          state_dir=state_dir)
    try:
        simulation = build_simulation(config)
    except (OSError, ValueError) as exc:
        raise UsageError(str(exc)) from None
    divergences: list[Divergence] = []

    def found(divergence: Divergence) -> None:
        divergences.append(divergence)
        if report is not None:
            report(divergence)

    replay = Replay(simulation, kind, tolerance_s, found)
    for item in exchanges(capture.frames()):
        replay.feed(item)
    summary = replay.finish()
    summary.notes[:0] = capture.notes
    return ReplayResult(divergences, summary, tolerance_s)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"tmcl replay: {message} (see tmcl replay --help)\n")


def _tolerance(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"seconds expected, got {text!r}") from None
    if not 0 <= value < 3600:
        raise argparse.ArgumentTypeError(f"seconds from 0 up to an hour expected, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="tmcl replay", description=(
        "Replay a capture (tmcl proxy --capture, a python-can log, a tmcl decode dump) against a "
        "fresh simulator on the virtual clock and list every reply that differs."),
        epilog=f"exit status: 0 nothing diverged, 1 something did, 2 the capture or an option "
               f"cannot be used.  Format and judging: {doc('capture.md')}")
    add_version_option(parser)
    parser.add_argument("capture", help="the capture file")
    add_model_options(parser, default_type=None,
                      default_said="default: the type the capture's identity names, else "
                                   f"{DEFAULT_MODULE_TYPE}")
    parser.add_argument("--tolerance", type=_tolerance, default=DEFAULT_TOLERANCE_S,
                        metavar="SECONDS", help="how far beyond its request-to-reply window a "
                        f"moving value may be matched (default {DEFAULT_TOLERANCE_S})")
    parser.add_argument("--json", action="store_true",
                        help="one JSON object per divergence, then the summary")
    return parser


def main(argv: list[str] | None = None) -> int:
    safe_console()
    args = build_parser().parse_args(argv)

    def show(divergence: Divergence) -> None:
        line = json.dumps(divergence.as_dict(), ensure_ascii=False) if args.json else divergence.line()
        sys.stdout.write(line + "\n")

    try:
        check_model_options(args)
        result = replay_capture(args.capture, module_type_name=args.module_type,
                                axis_core=args.axis_core, world=args.world,
                                state_dir=args.state_dir, tolerance_s=args.tolerance, report=show)
    except UsageError as exc:
        print(f"tmcl replay: {exc.message}", file=sys.stderr)
        return 2
    except CaptureError as exc:
        print(f"tmcl replay: {exc}", file=sys.stderr)
        return 2
    if args.json:
        sys.stdout.write(json.dumps({"summary": result.summary.as_dict()}) + "\n")
    else:
        sys.stdout.write("\n".join(result.summary.lines(result.tolerance_s)) + "\n")
    return result.summary.exit_code


if __name__ == "__main__":
    sys.exit(main())
