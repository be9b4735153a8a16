"""Run a simulator in-process from blocking code (tests, scripts, notebooks).

    from tmcl_server.embed import SimulatorThread
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
        port = sim.endpoints["tcp"][0]          # hand this to pytrinamic
        ...
        sim.advance(2.0)                        # two simulated seconds, in microseconds

The server runs on its own event loop in a background thread; :meth:`SimulatorThread.call`
runs a function on that loop, so the models are only ever touched from one thread.

:meth:`SimulatorThread.advance` with a transport endpoint waits for that thread, as a call
does (so a frame the test sent before it is served first, as it always was), but without
``call``'s re-planning of every module.  ``advance(s, wait=False)`` does not wait (issue 33,
item 6: a hand-off costs tens of µs of CPU, so a test advancing in 1 ms steps ran at 11 x
real time whatever the simulation had to do): it adds the time to what is owed and returns,
and the loop applies all that is owed in one ``advance`` before anything else reaches the
simulation: a :meth:`call`, a request on any transport (``Simulation.settle``), a
recording's rows, the stop.  One advance of the sum ends as the steps would (virtual time is exact
however it is cut, docs/scheduling.md), and whatever the test does next sees it applied;
what it cannot order is a frame sent before the call that the loop has not read yet (a
fire-and-forget frame): it may be served after the time owed.  Without any transport (no
endpoint, no CAN bus) no frame can be in flight, so there the default does not wait either:
only what goes through :meth:`call` reaches the simulation, and it applies what is owed
first.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import fields
from typing import Any, TypeVar

from tmcl_server.clock import VirtualClock, seconds_to_ns
from tmcl_server.faults import FaultHandle, FaultInjector
from tmcl_server.loops import new_event_loop
from tmcl_server.module import TMCLModule
from tmcl_server.record import DEFAULT_RESOLUTION_S, Recorder, Recording
from tmcl_server.server import Server, ServerConfig
from tmcl_server.simulation import Simulation

T = TypeVar("T")
#: Keywords that set a ServerConfig field rather than name an endpoint kind.
_CONFIG_FIELDS = frozenset(f.name for f in fields(ServerConfig)) - {"endpoints"}


class SimulatorThread:
    def __init__(self, config: ServerConfig | None = None, *, modules: int | None = None,
                 addresses: list[int] | None = None, clock: str | None = None,
                 speed: float | None = None, state_dir: str | None = None,
                 world: str | None = None, module_type: str | None = None,
                 axis_core: str | None = None, can_bus: str | list[str] | None = None,
                 loop: str = "asyncio", **endpoints: list[str]) -> None:
        config = config or ServerConfig(endpoints={})
        if modules is not None:
            config.addresses = list(range(1, modules + 1))
        if addresses is not None:
            config.addresses = list(addresses)
        if clock is not None:
            config.clock = clock
        if speed is not None:
            config.speed = speed
        if state_dir is not None:
            config.state_dir = state_dir
        if world is not None:
            config.world = str(world)
        if module_type is not None:
            config.module_type = module_type
        if axis_core is not None:
            config.axis_core = axis_core
        if can_bus is not None:  # the bus's name (a one-element list, as the ready file has it)
            config.can_bus_name = can_bus if isinstance(can_bus, str) else can_bus[0]
        for kind, arguments in endpoints.items():
            if kind in _CONFIG_FIELDS:  # any other ServerConfig setting (trace=..., record=...)
                setattr(config, kind, arguments)
            else:
                config.endpoints[kind] = list(arguments)
        self.config = config
        #: The event loop to run on: "asyncio", "uvloop" or "auto" (tmcl_server/loops.py).
        self.loop_kind = loop
        self.server: Server | None = None
        self.endpoints: dict[str, list[str]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._ready = concurrent.futures.Future[None]()
        #: Simulated time advance() owes, not yet applied on the loop, whether a callback
        #: to apply it is queued, and what went wrong applying it (raised at the next call).
        self._owed_lock = threading.Lock()
        self._owed_ns = 0
        self._owed_queued = False
        self._owed_error: BaseException | None = None
        #: A transport (an endpoint, the CAN bus) could carry a frame the test sent before an
        #: advance, which waiting serves first (set once started).
        self._carries_frames = True

    # -- lifecycle ----------------------------------------------------------------------------

    def start(self) -> SimulatorThread:
        self._thread = threading.Thread(target=self._run, name="tmcl-sim", daemon=True)
        self._thread.start()
        self._ready.result(timeout=30)
        return self

    def _run(self) -> None:
        loop = new_event_loop(self.loop_kind)
        self._loop = loop
        try:
            loop.run_until_complete(self._main())
        finally:
            loop.close()

    async def _main(self) -> None:
        try:
            self.server = Server(self.config)
            self.server.simulation.settle = self._pay
            self.endpoints = await self.server.start()
            self._carries_frames = bool(self.server.transports) or bool(self.endpoints)
        except BaseException as exc:
            self._ready.set_exception(exc)
            return
        self._ready.set_result(None)
        await self.server.wait_stopped()
        await self.server.stop()

    def stop(self) -> None:
        """Apply the time :meth:`advance` owes (a program may store to the EEPROM in it),
        stop the server and its thread; an error applying that time is raised here."""
        if self._loop is not None and self.server is not None and self._thread is not None:
            if self._thread.is_alive():
                server = self.server

                def pay_and_stop() -> None:
                    self._pay()
                    server.request_stop()

                self._loop.call_soon_threadsafe(pay_and_stop)
            self._thread.join(timeout=30)
        self._thread = None
        self._raise_owed_error()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> SimulatorThread:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- access from the calling thread -------------------------------------------------------

    def call(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> T:
        """Run ``fn`` on the simulator's loop thread and return its result.

        ``fn`` may change modules (inputs, switches, programs): their next events are asked
        again afterwards, so the server's timer follows.
        """
        assert self._loop is not None, "simulator not started"
        if threading.current_thread() is self._thread:  # already there (nested call)
            return fn(*args, **kwargs)

        def run() -> T:
            self._pay()
            try:
                return fn(*args, **kwargs)
            finally:
                if self.server is not None:
                    self.server.simulation.notify_changed()

        result = self._on_loop(run)
        self._raise_owed_error()
        return result

    def _on_loop(self, fn: Callable[[], T]) -> T:
        """``fn()`` on the loop thread; its result (or exception) here.

        One hand-off: the loop releases a lock this thread waits on (a third of the CPU of
        ``run_coroutine_threadsafe``'s task and futures, which a test advancing in 1 ms steps
        pays at each step).  ``fn`` runs a pass of the loop later, as a task's first step
        did: a frame the test sent before the call, readable by then, is served first.
        """
        loop = self._loop
        assert loop is not None, "simulator not started"
        done = threading.Lock()
        done.acquire()
        outcome: list[tuple[bool, Any]] = []

        def run() -> None:
            try:
                outcome.append((True, fn()))
            except BaseException as exc:  # handed to the caller, whatever it is
                outcome.append((False, exc))
            finally:
                done.release()

        loop.call_soon_threadsafe(loop.call_soon, run)
        if not done.acquire(timeout=60):
            raise TimeoutError("the simulator's loop did not run the call within 60 s")
        ok, value = outcome[0]
        if not ok:
            raise value
        return value

    @property
    def simulation(self) -> Simulation:
        assert self.server is not None
        return self.server.simulation

    def module(self, address: int = 1) -> TMCLModule:
        """The module object itself: only touch it through :meth:`call`."""
        return self.call(self.simulation.module, address)

    def advance(self, seconds: float, wait: bool | None = None) -> None:
        """Move the virtual clock forward, handling every event on the way.

        ``wait=False`` (from the test's thread) returns at once: the time is owed, and
        applied on the loop before anything else reaches the simulation (the module
        docstring); a frame the test sent before the call that the loop has not read yet is
        then served after that time, where waiting serves it first.  ``wait=None`` (the
        default) waits where a transport could carry such a frame (an endpoint, the CAN
        bus), and does not where none can."""
        loop = self._loop
        assert loop is not None, "simulator not started"
        simulation = self.simulation
        if threading.current_thread() is self._thread:
            simulation.advance(seconds)
            return
        if not isinstance(simulation.clock, VirtualClock):
            raise RuntimeError("time can only be advanced by hand on a virtual clock")
        step = seconds_to_ns(seconds)
        if step < 0:
            raise ValueError("virtual time cannot go backwards")
        self._raise_owed_error()
        if wait is None:
            wait = self._carries_frames
        if wait:  # (no notify_changed, as call() does: advancing changes nothing outside)
            def run() -> None:
                self._pay()
                simulation.advance_to_ns(simulation.clock.now_ns() + step)

            self._on_loop(run)
            return
        with self._owed_lock:
            self._owed_ns += step
            if self._owed_queued:
                return
            self._owed_queued = True
        loop.call_soon_threadsafe(self._pay)

    def settle(self) -> None:
        """Wait until the time :meth:`advance` owes is applied (what reads the simulation
        through :meth:`call` or a transport need not: they are applied first)."""
        if self._owed_ns or self._owed_queued:
            self.call(lambda: None)
        self._raise_owed_error()

    def _pay(self) -> None:
        """On the loop: apply the time owed, in one advance."""
        if not self._owed_ns and not self._owed_queued:
            return  # (every request asks: the usual answer, without the lock)
        with self._owed_lock:
            owed, self._owed_ns, self._owed_queued = self._owed_ns, 0, False
        if owed and self.server is not None:
            simulation = self.server.simulation
            try:
                simulation.advance_to_ns(simulation.clock.now_ns() + owed)
            except Exception as exc:  # the test learns it at its next call
                self._owed_error = exc

    def _raise_owed_error(self) -> None:
        error, self._owed_error = self._owed_error, None
        if error is not None:
            raise error

    def advance_until(self, condition: Callable[[], bool], timeout: float,
                      resolution: float = 0.001) -> bool:
        """Advance until ``condition()`` (run on the loop thread) holds; False on timeout."""
        return self.call(self.simulation.advance_until, condition, timeout, resolution)

    def record(self, resolution: float = DEFAULT_RESOLUTION_S, axes: Iterable[int] | None = None,
               modules: Iterable[int] | None = None) -> Recording:
        """Start recording the axes every ``resolution`` simulated seconds (record.py).

        ``rows`` fill as time passes; ``stop()`` or the end of a ``with`` block ends it.
        """
        recorder = self.call(lambda: Recorder(self.simulation, resolution, modules, axes).start())
        return Recording(recorder, self.call, self.settle)

    # -- faults on purpose (tmcl_server/faults.py, docs/faults.md) ------------------------------

    def fault(self, fault: str | Mapping[str, Any], **params: Any) -> FaultHandle:
        """Inject a fault now, e.g. ``with sim.fault("noreply", opcode="GAP"): ...``; it goes
        at the end of the block (or by ``remove()``).  ``fault``: a kind, or a whole spec
        (``"delay:ms=50,module=2"``); keywords add keys."""
        injector = self.call(FaultInjector.of, self.simulation)
        return FaultHandle(self.call, injector, self.call(injector.add, fault, **params))

    def faults(self) -> list[dict[str, Any]]:
        """The faults installed now: id, spec, how often each struck."""
        return self.call(lambda: FaultInjector.of(self.simulation).describe())

    def clear_faults(self) -> None:
        self.call(lambda: FaultInjector.of(self.simulation).clear())

    def power_cycle(self, address: int = 1) -> None:
        """Switch the module at ``address`` off and on: RAM as after power-on, EEPROM kept."""
        self.call(lambda: FaultInjector.of(self.simulation).power_cycle(self.simulation.module(address)))

    @property
    def tcp(self) -> str:
        """The first TCP endpoint as ``host:port``."""
        return self.endpoints["tcp"][0]

    @property
    def pty(self) -> str:
        return self.endpoints["pty"][0]
