"""What the dashboard shows and does, independent of the web server (tests drive it directly).

:class:`Dashboard` keeps, while at least one page is open (:meth:`Dashboard.watch`):

* samples of the axes on simulated time (:meth:`Dashboard.sample`, called at a wall-clock
  rate by the web layer), so each page plots the last seconds of position and velocity;
* the decoded wire: the lines of the telegram trace (tmcl_server/trace.py), the same decoder
  as ``--trace``, through a :class:`~tmcl_server.trace.Tracer` listener;
* what each page has seen (a :class:`Viewer`), so a frame carries only what is new.

It builds the JSON a page gets (:meth:`Dashboard.hello`, :meth:`Dashboard.frame`) and carries
out what a page asks (:meth:`Dashboard.act`): switches, load and inputs change the world as the
MQTT ``sim/`` topics do; commands (parameter writes, program control) go through the router
like a host's, so they are validated, answered and traced the same way (endpoint ``http ...``);
breakpoints go to the interpreter.  docs/dashboard.md has the protocol and the choices.
"""

from __future__ import annotations

import asyncio
import json
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from axes.reference_search import reference_plan
from axes.world import INFINITY, LOAD_MAX, Switch
from interpreter.disassembler import labelled
from interpreter.interrupts import vector_table
from tmcl_server.decode import describe_outcome, describe_request, status_name, vocabulary
from tmcl_server.dispatch import Interface
from tmcl_server.protocol import RawReply, Reply
from tmcl_server.sidechannel import SideChannel
from tmcl_server.transports.mqtt.requests import RequestError, request_from_json
from tmcl_spec.commands import ApplicationStatus, CodeProtection, Condition, WaitCondition
from tmcl_spec.names import names_of
from tmcl_spec.numbers import NS_PER_S, to_int32
from tmcl_spec.parameters import AP, GP, SWITCH_NAMES, ParamSpec

if TYPE_CHECKING:
    from tmcl_server.module import TMCLModule
    from tmcl_server.simulation import Simulation
    from tmcl_server.trace import TraceNote, Tracer

#: Samples are kept this many simulated seconds back (the page plots up to this window) ...
KEEP_SAMPLES_S = 120.0
#: ... and at most this many per module.
MAX_SAMPLES = 6000
#: Telegrams (trace notes) kept for pages ...
WIRE_KEPT = 1000
#: ... and at most this many of the newest ones new to a page go out with a frame, decoded (a
#: flood of requests is counted, not shown: nobody reads 10,000 lines a second).
WIRE_PER_FRAME = 100
#: Reads with a side effect: the page shows the value without the effect (AP 207 clears the
#: error flags when read: the status shows them; GP 133 draws the next random number).
_ERROR_FLAGS = AP.ERROR_FLAGS
_NOT_READ_GLOBALS = frozenset({(0, GP.RANDOM_NUMBER)})
_PROGRAM_STATES = {int(s): s.name for s in ApplicationStatus}


class ActionError(ValueError):
    """A page asked for something the simulator does not have or cannot do."""


@dataclass
class Viewer:
    """One open page: which module it shows, and what it has been sent already."""

    endpoint: str
    slot: int
    #: The page's Parameters section is open: send parameter values (at a lower rate).
    parameters: bool = False
    samples_seen: int = 0
    wire_seen: int = 0
    listing_revision: int = -1

    def show(self, slot: int) -> None:
        """Switch to another module: its whole history is new to this page."""
        if slot != self.slot:
            self.slot = slot
            self.samples_seen = 0
            self.listing_revision = -1


class _PageSink:
    """The reply sink of a page's commands: names the page in the trace (``http HOST:PORT``)."""

    def __init__(self, endpoint: str) -> None:
        self.endpoint = endpoint

    def send_unsolicited(self, reply: Reply) -> None:
        """A page asks for no 138 events; nothing to deliver."""


@dataclass(slots=True)
class _Sample:
    seq: int
    t: float
    position: list[int]
    velocity: list[int]
    target: list[int]


def _switch_placement(switch: Switch) -> tuple[int | None, int | None, str]:
    """(position, width, side) that :meth:`TMCLModule.set_switch` turns back into ``switch``."""
    if switch.low == -INFINITY:
        return int(switch.high), None, "below"
    if switch.high == INFINITY:
        return int(switch.low), None, "above"
    return int(switch.low), int(switch.high - switch.low), "above"


def _parameter_row(spec: ParamSpec, compact: str) -> dict[str, Any]:
    return {"number": spec.number, "name": compact, "title": spec.name, "access": spec.access,
            "min": spec.minimum, "max": spec.maximum}


class Dashboard:
    """The dashboard of one simulation (any number of pages)."""

    def __init__(self, simulation: Simulation) -> None:
        self.simulation = simulation
        self.modules: dict[int, TMCLModule] = {m.slot: m for m in simulation.modules}
        #: (slot, axis, switch) -> the world's switch before the page pressed it.
        self.held: dict[tuple[int, int, str], Switch | None] = {}
        self._samples: dict[int, deque[_Sample]] = {slot: deque(maxlen=MAX_SAMPLES)
                                                    for slot in self.modules}
        self._sample_seq = 0
        self._wire: deque[tuple[int, TraceNote]] = deque(maxlen=WIRE_KEPT)
        self._wire_seq = 0
        self._watchers = 0
        self._tracer: Tracer | None = None
        #: The wire view is a side channel: a failure in it stops it, never a request.
        self.channel = SideChannel("the dashboard's wire view", self._stop_wire)
        self._trace_listener = self.channel.guard(self._on_trace, "taking the trace")

    def module(self, slot: Any) -> TMCLModule:
        module = self.modules.get(slot) if isinstance(slot, int) else None
        if module is None:
            raise ActionError(f"no module {slot!r} (modules: {', '.join(map(str, self.modules))})")
        return module

    # == watching: only while a page is open ===================================================

    def watch(self, loop: asyncio.AbstractEventLoop | None = None) -> None:
        """A page opened: the first one starts taking the wire from the trace."""
        self._watchers += 1
        if self._watchers > 1:
            return
        from tmcl_server.trace import Tracer

        tracer = self.simulation.tracer
        if tracer is None:  # no --trace: a tracer without a stream, only for listeners
            tracer = Tracer(None).attach(self.simulation, loop)
        assert isinstance(tracer, Tracer)  # the one tracer there is (a hook may be another)
        tracer.listeners.append(self._trace_listener)
        self._tracer = tracer

    def unwatch(self) -> None:
        """A page closed: after the last one the dashboard costs nothing any more."""
        self._watchers = max(0, self._watchers - 1)
        if self._watchers or self._tracer is None:
            return
        self._stop_wire()
        for samples in self._samples.values():
            samples.clear()

    def _stop_wire(self) -> None:
        tracer, self._tracer = self._tracer, None
        if tracer is None:
            return
        if self._trace_listener in tracer.listeners:
            tracer.listeners.remove(self._trace_listener)
        if tracer.stream is None and not tracer.listeners:  # nobody else reads it (--trace does)
            tracer.detach()

    @property
    def watched(self) -> bool:
        return self._watchers > 0

    def _on_trace(self, notes: list[TraceNote]) -> None:
        """Keep the notes as they are: only those a page is sent are ever decoded."""
        wire = self._wire
        seq = self._wire_seq
        for note in notes:
            seq += 1
            wire.append((seq, note))
        self._wire_seq = seq

    # == what a page gets ======================================================================

    def hello(self) -> dict[str, Any]:
        """What does not change: the modules, their tables and I/O, the clock."""
        clock = self.simulation.clock
        kind = "lockstep" if clock.request_ns else "virtual" if clock.virtual else "real"
        return {"type": "hello", "clock": kind, "speed": getattr(clock, "speed", None),
                "modules": [self._describe(m) for m in self.modules.values()]}

    @staticmethod
    def _describe(module: TMCLModule) -> dict[str, Any]:
        kind = module.type
        axis_names = names_of(kind.axis_parameters)
        banks = {}
        for bank, table in kind.global_parameters.items():
            names = names_of(table)
            banks[str(bank)] = [_parameter_row(spec, names.by_number[n]) for n, spec in table.items()]
        return {
            "slot": module.slot, "type": kind.name, "axes": len(module.axes),
            "inputs": kind.digital_inputs, "analog_inputs": kind.analog_inputs,
            "outputs": kind.outputs, "analog_full_scale": kind.analog_full_scale,
            "load_max": LOAD_MAX, "switches": list(SWITCH_NAMES),
            "axis_parameters": [_parameter_row(spec, axis_names.by_number[n])
                                for n, spec in kind.axis_parameters.items()],
            "banks": banks,
            "vectors": {str(n): symbol for n, (symbol, _) in
                        vector_table(len(module.axes), kind.digital_inputs).items()},
        }

    def sample(self, slots: set[int]) -> None:
        """Take one sample of every axis of the modules ``slots`` at the present simulated time
        (skipped when time has not moved since the last one, as on a virtual clock at rest)."""
        for slot in slots:
            module = self.modules.get(slot)
            if module is None:
                continue
            self.simulation.sync_module(module)
            t = module.now_ns / NS_PER_S
            samples = self._samples[slot]
            if samples and samples[-1].t >= t:
                continue
            statuses = [module.axis(i).status() for i in range(len(module.axes))]
            self._sample_seq += 1
            samples.append(_Sample(self._sample_seq, t, [s.position for s in statuses],
                                   [s.velocity for s in statuses], [s.target for s in statuses]))
            while samples[0].t < t - KEEP_SAMPLES_S:
                samples.popleft()

    def frame(self, viewer: Viewer, parameters: bool = False) -> dict[str, Any]:
        """The module a page shows, now, and what is new for it (samples, wire, listing)."""
        module = self.module(viewer.slot)
        self.simulation.sync_module(module)
        interp = module.program.interpreter
        out: dict[str, Any] = {
            "type": "frame", "t": self.simulation.now_ns / NS_PER_S, "module": module.slot,
            "address": module.address, "axes": self._axes(module), "io": self._io(module),
            "program": self._program(module), "samples": self._new_samples(viewer),
        }
        out["wire"], out["wire_skipped"] = self._new_wire(viewer)
        if interp.memory_revision != viewer.listing_revision:
            viewer.listing_revision = interp.memory_revision
            out["listing"] = [list(line) for line in labelled(interp.program())]
        if parameters:
            out["parameters"] = self.parameters(module)
        return out

    def _axes(self, module: TMCLModule) -> list[dict[str, Any]]:
        rows = []
        for index in range(len(module.axes)):
            axis = module.axis(index)
            s = axis.status()
            rows.append({
                "position": s.position, "target": s.target, "velocity": s.velocity,
                "mode": s.mode, "reached": s.position_reached, "left": s.left_switch,
                "right": s.right_switch, "home": s.home_switch,
                "held": [name for name in SWITCH_NAMES if (module.slot, index, name) in self.held],
                "load": s.load, "free_load": axis.world.free_load, "errors": s.error_flags,
                "current": s.current, "standby": s.standby,
                "run_current": axis.get_parameter(AP.MAX_CURRENT),
                "standby_current": axis.get_parameter(AP.STANDBY_CURRENT),
                "max_speed": axis.get_parameter(AP.MAX_SPEED),
                "rfs": s.reference_search, "rfs_phase": self._rfs_phase(axis, s.reference_search),
            })
        return rows

    @staticmethod
    def _rfs_phase(axis: Any, phase: int) -> str:
        """The running reference search's phase by name (``2/3 leave left``), or ''."""
        if not phase:
            return ""
        try:
            plan, _ = reference_plan(axis.get_parameter(AP.RFS_MODE))
        except ValueError:
            return str(phase)
        if not 0 < phase <= len(plan):
            return str(phase)
        step = plan[phase - 1]
        return f"{phase}/{len(plan)} {step.kind} {step.switch}".rstrip()

    @staticmethod
    def _io(module: TMCLModule) -> dict[str, Any]:
        return {"inputs": [module.digital_input(p) for p in range(module.type.digital_inputs)],
                "analog": list(module.analog_inputs), "outputs": list(module.outputs),
                "supply": module.supply_voltage}

    @staticmethod
    def _program(module: TMCLModule) -> dict[str, Any]:
        program = module.program
        interp = program.interpreter
        wait = interp.wait
        if wait is not None:
            waiting = f"WAIT {WaitCondition(wait.condition).name} m{wait.motor}"
            if wait.deadline_ns is not None:
                waiting += f" until {wait.deadline_ns / NS_PER_S:.3f} s"
        else:
            waiting = None
        return {
            "state": "DOWNLOAD" if program.downloading else _PROGRAM_STATES.get(int(interp.status), "?"),
            "pc": interp.pc, "accumulator": interp.accumulator, "x": interp.x,
            "flags": {c.name: interp.flag(c) for c in Condition},
            "stack": list(interp.stack), "wait": waiting, "executed": interp.executed,
            "interrupts": {
                "global": interp.globally_enabled, "in_handler": interp.in_interrupt,
                "enabled": [v for v in range(64) if interp.enabled >> v & 1],
                "pending": [v for v in range(64) if interp.pending >> v & 1],
                "vectors": {str(v): a for v, a in sorted(interp.vectors.items())},
            },
            "breakpoints": sorted(interp.breakpoints),
            "protected": bool(module.globals[0].get(GP.CODE_PROTECTION, 0) & CodeProtection.READ),
        }

    def parameters(self, module: TMCLModule) -> dict[str, Any]:
        """Every readable parameter's value: axis parameters per axis, global ones per bank."""
        kind = module.type
        axis_values: dict[str, list[int | None]] = {}
        axes = [module.axis(i) for i in range(len(module.axes))]
        statuses = [axis.status() for axis in axes]
        for number, spec in kind.axis_parameters.items():
            if not spec.readable:
                continue
            if number == _ERROR_FLAGS:
                axis_values[str(number)] = [s.error_flags for s in statuses]
                continue
            axis_values[str(number)] = [self._read(axis.get_parameter, number) for axis in axes]
        banks: dict[str, dict[str, int | None]] = {}
        for bank, table in kind.global_parameters.items():
            banks[str(bank)] = {
                str(number): (None if (bank, number) in _NOT_READ_GLOBALS
                              else self._read(module.read_global, number, bank))
                for number, spec in table.items() if spec.readable}
        return {"axis": axis_values, "banks": banks}

    @staticmethod
    def _read(reader: Any, *args: int) -> int | None:
        try:
            return int(reader(*args))
        except (KeyError, ValueError, IndexError):
            return None

    def _new_samples(self, viewer: Viewer) -> dict[str, Any]:
        samples = self._samples[viewer.slot]
        new: list[_Sample] = []
        for sample in reversed(samples):
            if sample.seq <= viewer.samples_seen:
                break
            new.append(sample)
        new.reverse()
        if new:
            viewer.samples_seen = new[-1].seq
        return {"t": [s.t for s in new],
                "position": [list(axis) for axis in zip(*(s.position for s in new), strict=True)],
                "velocity": [list(axis) for axis in zip(*(s.velocity for s in new), strict=True)],
                "target": [list(axis) for axis in zip(*(s.target for s in new), strict=True)]}

    def _new_wire(self, viewer: Viewer) -> tuple[list[list[Any]], int]:
        """The newest telegrams this page has not seen, decoded (at most WIRE_PER_FRAME), and
        how many newer than its last frame it does not get."""
        new = self._wire_seq - viewer.wire_seen  # some may have left the ring already
        viewer.wire_seen = self._wire_seq
        if new <= 0 or self._tracer is None:
            return [], 0
        wire = self._wire
        shown = min(new, len(wire), WIRE_PER_FRAME)
        decode = self._tracer.decode
        lines = [[round(sim_ns / NS_PER_S, 6), round(wall, 6), endpoint, address, kind, text]
                 for index in range(len(wire) - shown, len(wire))
                 for wall, sim_ns, kind, endpoint, address, text in decode(wire[index][1])]
        return lines, new - shown

    # == what a page does ======================================================================

    def act(self, message: dict[str, Any], viewer: Viewer) -> dict[str, Any] | None:
        """Carry out one message of a page; a reply for it, or None."""
        op = message.get("op")
        if op == "view":
            viewer.show(self.module(message.get("module", viewer.slot)).slot)
            viewer.parameters = bool(message.get("parameters", viewer.parameters))
            return None
        if op in ("fault", "remove_fault", "clear_faults", "faults"):
            return self.faults(op, message)
        module = self.module(message.get("module", viewer.slot))
        if op == "command":
            return self.command(module, message, viewer.endpoint)
        if op == "breakpoint":
            address = message.get("address")
            if not isinstance(address, int) or not 0 <= address < module.program.memory_size:
                raise ActionError(f"no program address {address!r}")
            breakpoints = module.program.interpreter.breakpoints
            if message.get("set", address not in breakpoints):
                breakpoints.add(address)
            else:
                breakpoints.discard(address)
            return None
        if op == "switch":
            self.toggle_switch(module, self._index(message, "axis", len(module.axes)),
                               str(message.get("name")))
        elif op == "load":
            self.set_free_load(module, self._index(message, "axis", len(module.axes)),
                               self._number(message, "value", 0, LOAD_MAX))
        elif op == "input":
            module.set_digital_input(self._index(message, "port", module.type.digital_inputs),
                                     bool(message.get("active")))
        elif op == "analog":
            module.set_analog_input(self._index(message, "port", module.type.analog_inputs),
                                    self._number(message, "value", 0, module.type.analog_full_scale))
        else:
            raise ActionError(f"unknown op {op!r}")
        self.simulation.notify_changed()  # the world changed: events may have moved
        return None

    def faults(self, op: str, message: dict[str, Any]) -> dict[str, Any]:
        """Faults on purpose, in the fault language (docs/faults.md): ``fault`` installs
        ``message["fault"]`` (a spec such as ``noreply:opcode=GAP,count=1``, or a table with a
        ``kind``), ``remove_fault`` takes one away by its id, ``clear_faults`` all, ``faults``
        lists them.  The one parser and injector the command line and MQTT use."""
        from tmcl_server.faults import FaultInjector, FaultSpecError

        injector = FaultInjector.of(self.simulation)
        answer: dict[str, Any] = {"type": "faults", "id": message.get("id")}
        try:
            if op == "fault":
                fault = message.get("fault")
                if not isinstance(fault, (str, dict)):
                    raise ActionError('"fault" must be a fault spec (a string) or a table with a "kind"')
                answer["installed"] = injector.add(fault).describe()
            elif op == "remove_fault":
                number = message.get("fault")
                if isinstance(number, bool) or not isinstance(number, int) or number not in injector.faults:
                    raise ActionError(f"no fault {number!r} installed "
                                      f"(ids: {', '.join(map(str, injector.faults)) or 'none'})")
                injector.remove(number)
            elif op == "clear_faults":
                injector.clear()
        except FaultSpecError as exc:
            raise ActionError(str(exc)) from None
        answer["faults"] = injector.describe()
        return answer

    @staticmethod
    def _index(message: dict[str, Any], key: str, count: int) -> int:
        value = message.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < count:
            raise ActionError(f"{key} must be 0..{count - 1}, got {value!r}")
        return value

    @staticmethod
    def _number(message: dict[str, Any], key: str, lo: int, hi: int) -> int:
        value = message.get(key)
        if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
            raise ActionError(f"{key} must be an integer {lo}..{hi}, got {value!r}")
        return value

    def toggle_switch(self, module: TMCLModule, axis: int, name: str) -> bool:
        """Press a switch (held active wherever the axis is), or let go of one the page holds:
        the world gets back what it had (a placed cam, or no switch).  Returns held or not."""
        if name not in SWITCH_NAMES:
            raise ActionError(f"switch must be one of {', '.join(SWITCH_NAMES)}, got {name!r}")
        key = (module.slot, axis, name)
        if key not in self.held:
            self.held[key] = module.axis_world(axis).switches.get(name)
            module.force_switch(axis, name, True)
            return True
        original = self.held.pop(key)
        if original is None:
            module.force_switch(axis, name, False)
        elif original.low == -INFINITY and original.high == INFINITY:
            module.force_switch(axis, name, True)
        else:
            position, width, side = _switch_placement(original)
            module.set_switch(axis, name, position, width, side, original.normally_closed)
        return False

    @staticmethod
    def set_free_load(module: TMCLModule, axis: int, value: int) -> None:
        """The load where no load zone lies (the zones of the world stay)."""
        zones = [(z.low, z.high, z.load, z.blocked) for z in module.axis_world(axis).load_zones]
        module.set_load(axis, zones, value)

    def command(self, module: TMCLModule, message: dict[str, Any], endpoint: str) -> dict[str, Any]:
        """A TMCL command from the page, through the router like a host's (validated, traced)."""
        body = {key: message[key] for key in ("cmd", "type", "motor", "value") if key in message}
        try:
            request = request_from_json(json.dumps(body), module.address)
        except RequestError as exc:
            raise ActionError(str(exc)) from None
        routed = self.simulation.execute_on([module], request, Interface.SERIAL, _PageSink(endpoint))
        words = vocabulary(module.type)
        text = describe_request(request.opcode, request.type, request.motor, request.value, words)
        answer: dict[str, Any] = {"type": "reply", "id": message.get("id"), "module": module.slot,
                                  "request": text}
        if not routed:
            answer.update(status=None, text=f"{text}: no reply")
            return answer
        (_, reply), = routed
        if isinstance(reply, RawReply):
            answer.update(status=100, status_name="OK", text=f"{text} → {reply.data.hex(' ')}")
            return answer
        outcome = describe_outcome(reply.status, reply.opcode, request.type, reply.value)
        answer.update(status=reply.status, status_name=status_name(reply.status),
                      value=to_int32(reply.value), text=f"{text} {outcome}")
        return answer
