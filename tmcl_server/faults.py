"""Faults on purpose (issue 17): what a real link and a real module do to a host, on demand.

A fault is one line of a small language (docs/faults.md has the whole of it)::

    KIND[:KEY=VALUE[,KEY=VALUE]...]
    noreply:opcode=GAP,rate=0.1,seed=7        every GAP has a 10 % chance of losing its reply
    delay:ms=20..80,module=2                  module 2 answers 20 to 80 ms late
    stuck:axis=0                              axis 0's motor stops following its steps

or the same as a TOML/JSON table (``{"kind": "noreply", "opcode": "GAP"}``).  KIND says what
happens, the other keys say to which requests (``endpoint``, ``module``, ``opcode``, ``type``,
``motor``), how often (``rate`` with ``seed``, ``count``, ``after``) and how (the kind's own
parameters, :data:`~tmcl_server.fault_language.KINDS`); the language itself is
tmcl_server/fault_language.py.

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
:meth:`FaultInjector.describe`).
"""

from __future__ import annotations

import random
import weakref
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from tmcl_server.delivery import Delivery
from tmcl_server.dispatch import Interface, ReplySink
from tmcl_server.fault_language import (
    MAX_FAULTS,
    REQUEST,
    STATE,
    FaultKind,
    FaultSpec,
    FaultSpecError,
    fault_spec,
)
from tmcl_server.protocol import Reply, Request

if TYPE_CHECKING:
    from tmcl_server.module import TMCLModule
    from tmcl_server.simulation import Routed, Simulation

#: How many injections :attr:`FaultInjector.history` keeps.
HISTORY = 10_000

#: What the trace calls an endpoint nobody named.
UNNAMED = "-"


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
