"""The simulation: modules on one clock, and the request router every transport feeds.

This is the server-independent core (like pymodbus's datastore context): it owns no sockets.
Transports hand it frames and get replies back; tests and the embedding API move time with
:meth:`Simulation.advance` when the clock is virtual.

Scheduling (docs/scheduling.md): every module says when it next changes by itself; the
simulation keeps those times in a heap, so the work per request does not grow with the number
of modules.  A request brings only the modules it addresses up to the clock; modules with an
event due are run by :meth:`run_due` (the server's timer on a real clock, :meth:`advance` on
a virtual one).  A busy TMCL program on a real clock runs in chunks of simulated time, so the
transports get a turn between chunks, and is allowed to fall at most :data:`MAX_LAG_NS`
behind the clock.
"""

from __future__ import annotations

import heapq
import logging
from collections.abc import Callable, Iterable
from typing import Any, Protocol

from tmcl_server.clock import Clock, VirtualClock, seconds_to_ns
from tmcl_server.dispatch import Interface, ReplySink
from tmcl_server.module import READ_ONLY_OPCODES, TMCLModule
from tmcl_server.protocol import AnyReply, ChecksumError, FrameAssembler, Request, decode_request
from tmcl_spec.numbers import NS_PER_MS, NS_PER_S

log = logging.getLogger(__name__)

Routed = tuple[TMCLModule, AnyReply]


# -- the hooks the simulation calls (their implementations live in the layers above) ----------


class RequestTracer(Protocol):
    """Told of every frame and exchange (tmcl_server/trace.py's :class:`Tracer`)."""

    def requested(self, request: Request, interface: Interface, targets: list[TMCLModule],
                  sink: ReplySink | None) -> ReplySink | None:
        """A request is about to run on ``targets``; returns the sink the modules should keep."""
        ...

    def replied(self, request: Request, interface: Interface, targets: list[TMCLModule],
                routed: list[Routed], sink: ReplySink | None) -> None:
        """The request ran; ``routed`` holds the replies."""
        ...

    def foreign(self, frame: bytes, sink: ReplySink | None) -> None:
        """A serial frame no module answers to."""
        ...

    def bad_checksum(self, frame: bytes, sink: ReplySink | None, routed: list[Routed]) -> None:
        """A frame with a wrong checksum and the replies it got."""
        ...

    # What the transports and the fault injector report through the simulation's tracer:

    def torn_frame(self, endpoint: str, assembler: FrameAssembler, now_ns: int) -> None:
        """Bytes of an incomplete frame about to be dropped after the pause."""
        ...

    def can_ignored(self, bus: str, can_id: int, data: bytes, reason: str) -> None:
        """A CAN frame the modules did not act on."""
        ...

    def injected(self, endpoint: str, module: TMCLModule, request: Request | None, what: str,
                 fields: dict[str, Any]) -> None:
        """A fault was injected on purpose."""
        ...


class SampleRecorder(Protocol):
    """Samples the axes at fixed instants whenever time moves (tmcl_server/record.py)."""

    #: The next instant it samples.
    next_ns: int

    def catch_up(self, t_ns: int, max_samples: int | None = None) -> int:
        """Take the samples due up to ``t_ns`` (at most ``max_samples``); the time reached."""
        ...

    def skip_to(self, t_ns: int) -> None:
        """Leave out the instants before ``t_ns`` (a real clock ran away)."""
        ...


class RequestFaults(Protocol):
    """Faults injected on purpose around each request (tmcl_server/faults.py)."""

    def before(self, request: Request, interface: Interface, targets: list[TMCLModule],
               sink: ReplySink | None) -> list[TMCLModule]:
        """The modules that still get the request."""
        ...

    def after(self, request: Request, interface: Interface, routed: list[Routed]) -> list[Routed]:
        """The replies as they leave (some lost or altered)."""
        ...

#: On a real clock a busy program runs this much simulated time (about 50 instructions) before
#: the server looks at the wall clock again: smaller chunks cost more in bookkeeping.
PROGRAM_CHUNK_NS = 500_000
#: On a real clock the recorder takes at most this many sample instants per turn (a request,
#: a timer slice): it catches up over several, like a busy program.
RECORDER_SAMPLES_PER_TURN = 16
#: On a virtual clock a running program asks to be run this often (its instructions and events
#: happen at the same instants whatever the turn; a real clock's turns are 10 ms).
VIRTUAL_PROGRAM_SLICE_NS = 60 * NS_PER_S
#: On a real clock a busy program runs this much before a request is served: one TMCL
#: instruction (docs/interpreter.md), as a module's main loop between two host requests.
REQUEST_TURN_NS = 10_000
#: On a real clock a program may fall this far behind before the rest is skipped, as on a
#: CPU too slow for its work.
MAX_LAG_NS = 50 * NS_PER_MS


class Simulation:
    def __init__(self, modules: Iterable[TMCLModule], clock: Clock) -> None:
        self.modules = list(modules)
        self.clock = clock
        #: Called after every command and every time step, so a server can reschedule its
        #: timer when a command created an earlier event.
        self.on_change: Callable[[], None] | None = None
        self._serial_map: dict[int, list[TMCLModule]] | None = None
        self._can_map: dict[int, list[TMCLModule]] | None = None
        self._index = {module: i for i, module in enumerate(self.modules)}
        #: Each module's next event as last planned, and a heap of (time, module index).
        self._due: list[int | None] = [None] * len(self.modules)
        self._queue: list[tuple[int, int]] = []
        #: Program time skipped on a real clock because a module could not keep up (per index).
        self.skipped_ns = [0] * len(self.modules)
        #: The telegram trace (tmcl_server/trace.py); None: tracing off, and it costs nothing.
        self.tracer: RequestTracer | None = None
        #: Samples the axes at its instants whenever time moves (tmcl_server/record.py); or None.
        self.recorder: SampleRecorder | None = None
        #: Faults injected on purpose (tmcl_server/faults.py), set while one watches requests.
        self.faults: RequestFaults | None = None
        #: Requests served so far (the server's timer tells traffic from quiet by it).
        self.requests = 0
        #: How far the modules the last :meth:`run_due` ran are still behind its time (a busy
        #: program on a real clock catching up).
        self.lag_ns = 0
        #: Per module: the timer's last turn left its program behind the clock (it cannot
        #: keep up), so a request gives it no extra turn (sync_module).
        self._behind = [False] * len(self.modules)
        #: A lockstep clock's time per request (0 for the others): see _execute.
        self._request_ns = clock.request_ns
        #: Called before a request runs and before the clock moves: applies the time another
        #: thread advanced the clock by (tmcl_server/embed.py, ``SimulatorThread.advance``).
        self.settle: Callable[[], None] | None = None
        for module in self.modules:
            module.on_address_change = self._forget_addresses
            if clock.virtual:  # nothing lags a virtual clock: a busy program runs in long turns
                module.program.on_virtual_clock(VIRTUAL_PROGRAM_SLICE_NS)
            module.advance_to(clock.now_ns())
        self.replan()

    def module(self, address: int) -> TMCLModule:
        """The module that currently answers to a serial address."""
        for module in self.modules:
            if module.address == address:
                return module
        raise KeyError(f"no module answers to address {address}")

    # -- planning -----------------------------------------------------------------------------

    @property
    def now_ns(self) -> int:
        return self.clock.now_ns()

    def replan(self, module: TMCLModule | None = None) -> None:
        """Ask ``module`` (default: every module) again when it next changes by itself.

        The simulation asks after everything it does itself; whoever changes a module from
        outside (tests, the embedding API, the world topics) calls this afterwards.
        """
        for index in range(len(self.modules)) if module is None else (self._index[module],):
            due = self.modules[index].next_event_ns()
            if due != self._due[index]:
                self._due[index] = due
                if due is not None:
                    heapq.heappush(self._queue, (due, index))

    def next_event_ns(self) -> int | None:
        queue, due = self._queue, self._due
        while queue and due[queue[0][1]] != queue[0][0]:
            heapq.heappop(queue)  # an entry that was planned again since
        return queue[0][0] if queue else None

    # -- time ---------------------------------------------------------------------------------

    def run_due(self, chunk_ns: int | None = None, t_ns: int | None = None) -> bool:
        """Run every module with an event due by ``t_ns`` (default: the clock) up to it.

        With ``chunk_ns`` a busy program advances at most that much (it catches up over
        several calls; 0: not at all, only the lag bound applies).  Returns True if a module
        is still behind ``t_ns``.
        """
        if self.settle is not None and t_ns is None:
            self.settle()
        t = self.clock.now_ns() if t_ns is None else t_ns
        recording = self.recorder is not None and chunk_ns is not None
        if self.recorder is not None:  # it steps its modules to each sample instant up to t
            t = self._record_up_to(t, RECORDER_SAMPLES_PER_TURN if chunk_ns is not None else None)
        queue, due = self._queue, self._due
        ran: list[int] = []
        while queue and queue[0][0] <= t:
            when, index = heapq.heappop(queue)
            if due[index] == when:
                due[index] = None
                ran.append(index)
        lag = 0
        behind = self._behind
        for index in ran:
            module = self.modules[index]
            self._bring(module, index, t, chunk_ns)
            self.replan(module)
            behind[index] = module.now_ns < t
            if t - module.now_ns > lag:
                lag = t - module.now_ns
        self.lag_ns = lag
        if ran:
            self._changed()
        return lag > 0 or (recording and t < self.clock.now_ns())

    def sync_module(self, module: TMCLModule) -> None:
        """Bring one module to the clock (before a request to it, or a look at it).

        On a real clock a busy program runs one instruction's time here and the request is
        served at the program's present (it is behind the clock by less than the lag bound),
        the way a module's main loop executes an instruction between two host requests (a host
        that polls right after command 129 sees the first instruction done); the server's
        timer keeps the program going.  A program the timer left behind the clock (it cannot
        keep up) gets no such turn: one instruction may cost far more CPU than
        its 10 us, and every request would pay for it (issue 36, N11); it is served at the
        program's present, behind the clock by at most the lag bound plus the hosts' share
        of the timer (Server's PROGRAM_SHARE_TRAFFIC).
        """
        index = self._index[module]
        t = self.clock.now_ns()
        if self.recorder is not None:  # it steps its modules to each sample instant up to t
            t = self._record_up_to(t, None if self.clock.virtual else RECORDER_SAMPLES_PER_TURN)
        if self.clock.virtual:
            self._bring(module, index, t, None)
        elif not (self._behind[index] and module.program.busy):
            self._bring(module, index, t, REQUEST_TURN_NS)
        # else a program the timer left behind the clock: the request is served at its
        # present, and the timer alone runs it and keeps its lag bound (a skip here would
        # execute an instruction per request too)
        due = self._due[index]
        if (due is not None and due <= t) or module.program.busy:
            self.replan(module)  # events were handled or a program ran: its plan moved

    def _record_up_to(self, t: int, max_samples: int | None) -> int:
        """Let the recorder sample up to ``t`` (bounded on a real clock, where it may lag
        like a busy program, at most :data:`MAX_LAG_NS`); the time it reached."""
        recorder = self.recorder
        assert recorder is not None
        if max_samples is not None and t - recorder.next_ns > MAX_LAG_NS:
            recorder.skip_to(t - MAX_LAG_NS)
        return recorder.catch_up(t, max_samples)

    def sync(self) -> None:
        """Bring every module up to the clock's current time."""
        for module in self.modules:
            self.sync_module(module)

    def _bring(self, module: TMCLModule, index: int, t: int, chunk_ns: int | None) -> None:
        if chunk_ns is None or not module.program.busy:
            module.advance_to(t)
            return
        if t - module.now_ns > MAX_LAG_NS:
            resume = t - MAX_LAG_NS
            self.skipped_ns[index] += resume - module.now_ns
            log.debug("module %d: the TMCL program fell behind; %d ms skipped so far",
                      module.slot, self.skipped_ns[index] // NS_PER_MS)
            module.skip_program_to(resume)
        if chunk_ns:
            module.advance_to(min(t, module.now_ns + chunk_ns))

    def advance(self, seconds: float) -> None:
        """Virtual clock only: move time forward, stepping through every event in order."""
        self.advance_to_ns(self.clock.now_ns() + seconds_to_ns(seconds))

    def advance_to_ns(self, target_ns: int) -> None:
        clock = self._virtual_clock()
        self.replan()  # the caller may have changed modules since
        while True:
            nxt = self.next_event_ns()
            step = target_ns if nxt is None or nxt > target_ns else max(nxt, clock.now_ns())
            clock.set(step)
            self.run_due(None, step)
            if step >= target_ns:
                break
        for module in self.modules:  # the rest catch up (cheap: no event is due)
            module.advance_to(target_ns)
        self._changed()

    def advance_until(self, condition: Callable[[], bool], timeout: float,
                      resolution: float = 0.001) -> bool:
        """Virtual clock only: advance until ``condition()`` holds or ``timeout`` seconds pass.

        The condition is checked at every event and at least every ``resolution`` seconds.
        Returns whether it held.
        """
        clock = self._virtual_clock()
        deadline = clock.now_ns() + seconds_to_ns(timeout)
        step = max(1, seconds_to_ns(resolution))
        while not condition():
            now = clock.now_ns()
            if now >= deadline:
                return False
            self.replan()
            nxt = self.next_event_ns()
            target = min(deadline, now + step)
            if nxt is not None and now < nxt < target:
                target = nxt
            self.advance_to_ns(target)
        return True

    def _virtual_clock(self) -> VirtualClock:
        if not isinstance(self.clock, VirtualClock):
            raise RuntimeError("time can only be advanced by hand on a virtual clock")
        return self.clock

    def _changed(self) -> None:
        if self.on_change is not None:
            self.on_change()

    # -- routing ------------------------------------------------------------------------------

    def _forget_addresses(self) -> None:
        self._serial_map = self._can_map = None

    def _address_map(self, accepts: Callable[[TMCLModule, int], bool],
                     ids: range) -> dict[int, list[TMCLModule]]:
        """Address -> modules answering it (rebuilt when a module's address changes)."""
        table: dict[int, list[TMCLModule]] = {}
        for address in ids:
            answering = [m for m in self.modules if accepts(m, address)]
            if answering:
                table[address] = answering
        return table

    def handle_serial_frame(self, frame: bytes, sink: ReplySink | None = None) -> list[Routed]:
        """Route one 9-byte frame like an RS-485 bus: every module with that address acts."""
        serial_map = self._serial_map
        if serial_map is None:
            serial_map = self._serial_map = self._address_map(TMCLModule.accepts_serial, range(256))
        targets = serial_map.get(frame[0])
        if not targets:
            if self.tracer is not None:
                self.tracer.foreign(frame, sink)
            return []
        try:
            request = decode_request(frame)
        except ChecksumError:
            routed: list[Routed] = [(m, m.checksum_error_reply()) for m in targets]
            if self.tracer is not None:
                self.tracer.bad_checksum(frame, sink, routed)
            return routed
        return self._execute(targets, request, Interface.SERIAL, sink)

    def handle_frame_for(self, module: TMCLModule, frame: bytes,
                         sink: ReplySink | None = None) -> list[Routed]:
        """One frame on a module's own port (USB): it answers whatever the address byte says."""
        self.sync()
        try:
            request = decode_request(frame)
        except ChecksumError:
            routed: list[Routed] = [(module, module.checksum_error_reply())]
            if self.tracer is not None:
                self.tracer.bad_checksum(frame, sink, routed)
            return routed
        return self._execute([module], request, Interface.SERIAL, sink)

    def handle_can_request(self, request: Request, sink: ReplySink | None = None) -> list[Routed]:
        """Route one CAN request (``request.address`` is the frame's CAN id)."""
        can_map = self._can_map
        if can_map is None:
            can_map = self._can_map = self._address_map(TMCLModule.accepts_can, range(2048))
        targets = can_map.get(request.address)
        if not targets:
            return []
        return self._execute(targets, request, Interface.CAN, sink)

    def accepts_can(self, can_id: int) -> bool:
        """Whether a module answers to ``can_id`` (a CAN node filters before decoding)."""
        if self._can_map is None:
            self._can_map = self._address_map(TMCLModule.accepts_can, range(2048))
        return can_id in self._can_map

    def execute_on(self, targets: list[TMCLModule], request: Request, interface: Interface,
                   sink: ReplySink | None = None) -> list[Routed]:
        """Run a request on given modules, whatever its address (topic-addressed hosts)."""
        return self._execute(targets, request, interface, sink)

    def notify_changed(self) -> None:
        """Something outside a command changed the world: internal events may have moved."""
        for module in self.modules:
            module.invalidate_schedule()
        self.replan()
        self._changed()

    def _execute(self, targets: list[TMCLModule], request: Request, interface: Interface,
                 sink: ReplySink | None) -> list[Routed]:
        if self.settle is not None:
            self.settle()
        self.requests += 1
        if self._request_ns:  # a lockstep clock: the telegram's time on the wire passes first
            self.advance_to_ns(self.clock.now_ns() + self._request_ns)
        faults = self.faults
        if faults is not None:  # a request lost on the way, or a module that resets
            targets = faults.before(request, interface, targets, sink)
            if not targets:
                return []
        for module in targets:  # first, so the tracer stamps the time the request runs at
            self.sync_module(module)
        tracer = self.tracer
        if tracer is not None:
            sink = tracer.requested(request, interface, targets, sink)
        routed: list[Routed] = []
        for module in targets:
            reply = module.execute(request, interface, sink)
            if reply is not None:
                routed.append((module, reply))
        if tracer is not None:
            tracer.replied(request, interface, targets, routed, sink)
        if faults is not None:  # replies lost or altered (faults.Delivery), faults triggered
            routed = faults.after(request, interface, routed)
        if request.opcode not in READ_ONLY_OPCODES:
            for module in targets:
                self._behind[self._index[module]] = False  # e.g. a new program: a turn again
                self.replan(module)
            self._changed()
        return routed
