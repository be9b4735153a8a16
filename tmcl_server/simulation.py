"""The simulation: modules on one clock, and the request router every transport feeds.

This is the server-independent core (like pymodbus's datastore context): it owns no sockets.
Transports hand it frames and get replies back; tests and the embedding API move time with
:meth:`Simulation.advance` when the clock is virtual.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from tmcl_server.clock import Clock, VirtualClock, seconds_to_ns
from tmcl_server.dispatch import Interface, ReplySink
from tmcl_server.module import READ_ONLY_OPCODES, TMCLModule
from tmcl_server.protocol import AnyReply, ChecksumError, Request, decode_request

Routed = tuple["TMCLModule", AnyReply]


class Simulation:
    def __init__(self, modules: Iterable[TMCLModule], clock: Clock) -> None:
        self.modules = list(modules)
        self.clock = clock
        #: Called after every command and every time step, so a server can reschedule its
        #: timer when a command created an earlier event.
        self.on_change: Callable[[], None] | None = None
        self._serial_map: dict[int, list[TMCLModule]] | None = None
        for module in self.modules:
            module.on_address_change = self._forget_addresses
            module.advance_to(clock.now_ns())

    def module(self, address: int) -> TMCLModule:
        """The module that currently answers to a serial address."""
        for module in self.modules:
            if module.address == address:
                return module
        raise KeyError(f"no module answers to address {address}")

    # -- time ---------------------------------------------------------------------------------

    @property
    def now_ns(self) -> int:
        return self.clock.now_ns()

    def sync(self) -> None:
        """Bring every module up to the clock's current time."""
        t = self.clock.now_ns()
        for module in self.modules:
            due = module.next_event_ns()
            # Also when the module is up to date but a command left an event due now.
            if module.now_ns < t or (due is not None and due <= t):
                module.advance_to(t)

    def next_event_ns(self) -> int | None:
        times = [t for t in (m.next_event_ns() for m in self.modules) if t is not None]
        return min(times) if times else None

    def advance(self, seconds: float) -> None:
        """Virtual clock only: move time forward, stepping through every event in order."""
        self.advance_to_ns(self.clock.now_ns() + seconds_to_ns(seconds))

    def advance_to_ns(self, target_ns: int) -> None:
        clock = self._virtual_clock()
        while True:
            nxt = self.next_event_ns()
            step = target_ns if nxt is None or nxt > target_ns else max(nxt, clock.now_ns())
            clock.set(step)
            self.sync()
            if step >= target_ns:
                break
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
        self._serial_map = None

    def _build_serial_map(self) -> dict[int, list[TMCLModule]]:
        """Serial address -> modules answering it (rebuilt when a module's address changes)."""
        table: dict[int, list[TMCLModule]] = {}
        for address in range(256):
            answering = [m for m in self.modules if m.accepts_serial(address)]
            if answering:
                table[address] = answering
        return table

    def handle_serial_frame(self, frame: bytes, sink: ReplySink | None = None) -> list[Routed]:
        """Route one 9-byte frame like an RS-485 bus: every module with that address acts."""
        serial_map = self._serial_map
        if serial_map is None:
            serial_map = self._serial_map = self._build_serial_map()
        targets = serial_map.get(frame[0])
        if not targets:
            return []
        self.sync()
        try:
            request = decode_request(frame)
        except ChecksumError:
            return [(m, m.checksum_error_reply()) for m in targets]
        return self._execute(targets, request, Interface.SERIAL, sink)

    def handle_frame_for(self, module: TMCLModule, frame: bytes,
                         sink: ReplySink | None = None) -> list[Routed]:
        """One frame on a module's own port (USB): it answers whatever the address byte says."""
        self.sync()
        try:
            request = decode_request(frame)
        except ChecksumError:
            return [(module, module.checksum_error_reply())]
        return self._execute([module], request, Interface.SERIAL, sink)

    def handle_can_request(self, request: Request, sink: ReplySink | None = None) -> list[Routed]:
        """Route one CAN request (``request.address`` is the frame's CAN id)."""
        targets = [m for m in self.modules if m.accepts_can(request.address)]
        if not targets:
            return []
        self.sync()
        return self._execute(targets, request, Interface.CAN, sink)

    def execute_on(self, targets: list[TMCLModule], request: Request, interface: Interface,
                   sink: ReplySink | None = None) -> list[Routed]:
        """Run a request on given modules, whatever its address (topic-addressed hosts)."""
        self.sync()
        return self._execute(targets, request, interface, sink)

    def notify_changed(self) -> None:
        """Something outside a command changed the world: internal events may have moved."""
        for module in self.modules:
            module.invalidate_schedule()
        self._changed()

    def _execute(self, targets: list[TMCLModule], request: Request, interface: Interface,
                 sink: ReplySink | None) -> list[Routed]:
        routed: list[Routed] = []
        for module in targets:
            reply = module.execute(request, interface, sink)
            if reply is not None:
                routed.append((module, reply))
        if request.opcode not in READ_ONLY_OPCODES:
            self._changed()
        return routed
