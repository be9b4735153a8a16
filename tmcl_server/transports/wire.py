"""Wire timing (``tmcl-server --wire-timing``): bytes and CAN frames take the real link's time.

Off by default: the simulator answers at once, which keeps CI fast.  On, a host's timeouts
meet the latencies of the real link (docs/faults.md has the figures):

* **serial** (``--pty``, ``--serial``): every byte takes :data:`BITS_PER_BYTE` bit times at the
  endpoint's baud rate (8N1: start bit, 8 data bits, stop bit).  A request is executed when its
  last byte has arrived; the reply's first byte starts :data:`DEFAULT_PROCESSING_S` (the
  module's processing time, ``--processing-time``) plus the GP 75 pause (RS-485 endpoints)
  later, and each reply byte leaves when the line would have carried it.  A GAP round trip at
  9600 baud: 18 bytes x 1.0417 ms + 0.2 ms = 18.95 ms.
* **CAN** (the simulated bus): every frame takes :func:`can_frame_bits` bit times at GP 69's
  bit rate (or the ``--can`` one) and the bus carries one frame at a time.

The event loop's own timers wake it to the millisecond at best (epoll waits whole
milliseconds; uvloop's clock ticks in them), while a byte at 115200 baud takes 87 µs.  So a
:class:`WireScheduler` thread sleeps until each instant (``time.sleep`` is precise to about
0.1 ms) and then writes the byte itself, or hands a callback to the loop
(``call_soon_threadsafe``).  Nothing here blocks the loop.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import logging
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from tmcl_server.delivery import Delivery
from tmcl_server.platform import tight_timer_slack
from tmcl_server.protocol import AnyReply
from tmcl_server.simulation import Simulation
from tmcl_server.transports.base import LinkMode, StreamSession, TransportHost
from tmcl_spec.parameters import GP

if TYPE_CHECKING:
    import can

    from tmcl_server.module import ModuleEvent, TMCLModule
    from tmcl_server.transports.can.bus import CanParty, SimulatedCanBus

log = logging.getLogger(__name__)

#: UART framing 8N1: a start bit, eight data bits, a stop bit.
BITS_PER_BYTE = 10
#: Rates without a module to ask (or a module type without the table): the slowest UART
#: setting and the fastest CAN one, the TMCL family's factory defaults.
FALLBACK_BAUD = 9600
FALLBACK_CAN_BIT_RATE = 1_000_000
#: A standard (11-bit id) CAN data frame without its data: SOF 1, id 11, RTR 1, IDE 1, r0 1,
#: DLC 4, CRC 15, CRC delimiter 1, ACK slot and delimiter 2, EOF 7, intermission 3.
CAN_FRAME_OVERHEAD_BITS = 47
#: The module's processing time between a request's last byte and its reply's first (a
#: choice: Trinamic publishes no figure; the firmware's main loop fetches a complete command,
#: executes it and starts the reply in a few hundred microseconds).
DEFAULT_PROCESSING_S = 0.0002
#: A scheduler thread with nothing to do for this long ends (the next instant starts a new one).
IDLE_EXIT_S = 2.0
NS_PER_S = 1_000_000_000


def byte_time_s(baud: int) -> float:
    """Seconds one byte takes on a UART line."""
    return BITS_PER_BYTE / baud


def can_frame_bits(data_length: int) -> int:
    """Bits of a standard CAN data frame with ``data_length`` bytes: the usual 47 + 8n (stuff
    bits left out: at most one per four bits after the first, so up to ~20 % more)."""
    return CAN_FRAME_OVERHEAD_BITS + 8 * data_length


def serial_round_trip_s(baud: int, processing_s: float = DEFAULT_PROCESSING_S,
                        request_bytes: int = 9, reply_bytes: int = 9, pause_s: float = 0.0) -> float:
    """What a host measures for one request and its reply on a serial line."""
    return (request_bytes + reply_bytes) * byte_time_s(baud) + processing_s + pause_s


def can_round_trip_s(bitrate: int, processing_s: float = DEFAULT_PROCESSING_S,
                     request_length: int = 8, reply_length: int = 8) -> float:
    """What a host measures for one request frame and its reply frame on an idle bus."""
    return (can_frame_bits(request_length) + can_frame_bits(reply_length)) / bitrate + processing_s


@dataclass(frozen=True)
class WireTiming:
    """The server's ``--wire-timing`` settings."""

    processing_s: float = DEFAULT_PROCESSING_S

    @classmethod
    def of(cls, host: TransportHost) -> WireTiming | None:
        """The settings a transport gets from its server; None while wire timing is off."""
        if not host.option("wire_timing"):
            return None
        return cls(host.option("processing_time"))


# == precise instants ==========================================================================


class WireScheduler:
    """Runs actions at precise wall instants (``time.monotonic_ns``) from a thread of its own:
    ``direct`` ones in that thread (a byte written to a file descriptor), the others on the
    event loop (they touch the simulation)."""

    def __init__(self, loop: asyncio.AbstractEventLoop, name: str = "wire") -> None:
        self._loop = loop
        self._name = name
        self._heap: list[tuple[int, int, bool, Callable[..., Any], tuple[Any, ...]]] = []
        self._order = itertools.count()
        self._condition = threading.Condition()
        self._thread: threading.Thread | None = None
        self._closed = False

    def at(self, when_ns: int, action: Callable[..., Any], *args: Any, direct: bool = False) -> None:
        with self._condition:
            if self._closed:
                return
            order = next(self._order)
            heapq.heappush(self._heap, (when_ns, order, direct, action, args))
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name=f"tmcl-{self._name}",
                                                daemon=True)
                self._thread.start()
            elif self._heap[0][1] == order:  # earlier than what the thread waits for
                self._condition.notify()

    def close(self) -> None:
        with self._condition:
            self._closed = True
            self._heap.clear()
            self._condition.notify()
            thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(1.0)

    def _run(self) -> None:
        tight_timer_slack()
        heap, condition = self._heap, self._condition
        while True:
            with condition:
                while not heap:
                    woken = not self._closed and condition.wait(IDLE_EXIT_S)
                    if not heap and (self._closed or not woken):  # closed, or idle for long
                        self._thread = None
                        return
                wait_ns = heap[0][0] - time.monotonic_ns()
                if wait_ns > 0:
                    # an earlier instant added meanwhile wakes this wait (notify in at())
                    condition.wait(wait_ns / NS_PER_S)
                    continue
                now = time.monotonic_ns()
                due = []
                while heap and heap[0][0] <= now:
                    due.append(heapq.heappop(heap))
            on_loop = []
            for _, _, direct, action, args in due:
                if direct:
                    try:
                        action(*args)
                    except Exception:  # a write to a vanished port must not end the thread
                        log.exception("wire action %r failed", action)
                else:
                    on_loop.append((action, args))
            if on_loop:
                try:
                    self._loop.call_soon_threadsafe(_run_all, on_loop)
                except RuntimeError:  # the loop is closed: the server has gone
                    with condition:
                        self._thread = None
                    return


def _run_all(actions: list[tuple[Callable[..., Any], tuple[Any, ...]]]) -> None:
    for action, args in actions:
        action(*args)


# == serial lines ===============================================================================


class LineRate:
    """A line's rate in bits per second: a module setting the firmware applies when it starts
    (GP 65 for the UART, GP 69 for CAN: SGP stores a new rate in the EEPROM, it takes effect at
    the next power-up, a restart by 137 or a power cycle), unless the endpoint fixes one."""

    def __init__(self, module: TMCLModule | None, parameter: int, table: Mapping[int, int],
                 fallback: int, fixed: int | None = None) -> None:
        self._module = module
        self._parameter = parameter
        self._table = table
        self._fallback = fallback
        self.bits_per_s = fixed or self._read()
        if fixed is None and module is not None:  # (runs of a timer's dispatches as one call)
            module.run_listeners.append(self._on_event)

    @classmethod
    def uart(cls, module: TMCLModule | None, fixed: int | None = None) -> LineRate:
        """GP 65 through the module type's baud-rate table."""
        table = module.type.baud_rates if module is not None else {}
        return cls(module, GP.BAUD_RATE, table, FALLBACK_BAUD, fixed)

    @classmethod
    def can(cls, module: TMCLModule | None, fixed: int | None = None) -> LineRate:
        """GP 69 through the module type's CAN bit-rate table."""
        table = module.type.can_bit_rates if module is not None else {}
        return cls(module, GP.CAN_BIT_RATE, table, FALLBACK_CAN_BIT_RATE, fixed)

    def _read(self) -> int:
        if self._module is None:
            return self._fallback
        return self._table.get(self._module.globals[0][self._parameter], self._fallback)

    def _on_event(self, event: ModuleEvent) -> None:
        if event.kind in ("power_cycle", "factory_reset"):
            self.bits_per_s = self._read()

    def close(self) -> None:
        if self._module is not None and self._on_event in self._module.run_listeners:
            self._module.run_listeners.remove(self._on_event)


def parse_baud(text: str | None, endpoint: str) -> int | None:
    """The ``baud=`` endpoint option: bits per second."""
    if text is None:
        return None
    if not text.isdigit() or int(text) <= 0:
        raise ValueError(f"{endpoint}: baud must be a positive number of bits per second, got {text!r}")
    return int(text)


class PacedStreamSession(StreamSession):
    """A byte stream at the line's pace: requests count as arrived when their last byte would
    have, replies leave byte by byte at the baud rate (docs/faults.md, "Wire timing")."""

    __slots__ = ("_baud", "_line_free_ns", "_processing_ns", "_rx_free_ns", "_scheduler")

    def __init__(self, simulation: Simulation, write: Callable[[bytes], None],
                 loop: asyncio.AbstractEventLoop, mode: LinkMode, endpoint: str, *,
                 baud: LineRate, timing: WireTiming) -> None:
        super().__init__(simulation, write, loop, mode, endpoint)
        self._baud = baud
        self._processing_ns = round(timing.processing_s * NS_PER_S)
        self._scheduler = WireScheduler(loop, endpoint.replace(" ", "-"))
        #: When the last byte received so far arrived, and when the line out is free again.
        self._rx_free_ns = 0
        self._line_free_ns = 0

    @property
    def byte_ns(self) -> int:
        return round(byte_time_s(self._baud.bits_per_s) * NS_PER_S)

    def feed(self, data: bytes) -> None:
        """Bytes the host wrote now reach the module one byte time apart, after those before."""
        byte_ns = self.byte_ns
        arrived = max(time.monotonic_ns(), self._rx_free_ns)
        assembler, tracer = self._assembler, self.simulation.tracer
        for index in range(len(data)):
            arrived += byte_ns
            if tracer is not None:  # a torn frame may be about to be dropped
                tracer.torn_frame(self.endpoint, assembler, arrived)
            for frame in assembler.feed(data[index:index + 1], arrived):
                self._scheduler.at(arrived, self._execute, frame, arrived)
        self._rx_free_ns = arrived

    def _execute(self, frame: bytes, arrived_ns: int) -> None:
        """The frame's last byte is in: the module runs it and its reply goes on the line."""
        if self.closed:
            return
        for module, reply in self._route(frame, self):
            pause_ns = round(module.reply_delay_s * NS_PER_S) if self.rs485 else 0
            self._transmit_reply(reply, arrived_ns + self._processing_ns + pause_ns)

    def _transmit_reply(self, reply: AnyReply | Delivery, start_ns: int) -> None:
        pieces = reply.stream_pieces() if isinstance(reply, Delivery) else ((0.0, reply.encode()),)
        for pause, data in pieces:
            start_ns = self._transmit(data, start_ns + round(pause * NS_PER_S))

    def _transmit(self, data: bytes, not_before_ns: int) -> int:
        """Put ``data`` on the line from ``not_before_ns`` (or when it is free); returns when
        its last byte is complete."""
        byte_ns = self.byte_ns
        at = max(not_before_ns, self._line_free_ns, time.monotonic_ns())
        for value in data:
            at += byte_ns
            self._scheduler.at(at, self._write_now, bytes((value,)), direct=True)
        self._line_free_ns = at
        return at

    def _send(self, data: bytes, delay_s: float = 0.0) -> None:
        """Unsolicited replies (138 events) queue on the line like every other byte."""
        if not self.closed:
            self._transmit(data, time.monotonic_ns() + round(delay_s * NS_PER_S))

    def close(self) -> None:
        super().close()
        self._scheduler.close()
        self._baud.close()


# == the CAN bus ================================================================================


class CanTiming:
    """The simulated bus at its bit rate: one frame at a time, each delivered when its last bit
    has gone (installed on the bus as :attr:`SimulatedCanBus.timing`)."""

    def __init__(self, bitrate: LineRate, processing_s: float = DEFAULT_PROCESSING_S) -> None:
        self.rate = bitrate
        self.processing_s = processing_s
        self._free_ns = 0
        self._scheduler: WireScheduler | None = None

    def frame_ns(self, frame: can.Message) -> int:
        length = 0 if frame.is_remote_frame else len(frame.data)
        bits = can_frame_bits(length) + (20 if frame.is_extended_id else 0)  # SRR, r1, 18 id bits
        return bits * NS_PER_S // self.rate.bits_per_s

    def transmit(self, bus: SimulatedCanBus, frame: can.Message, sender: CanParty | None,
                 after_s: float = 0.0) -> None:
        if self._scheduler is None:
            self._scheduler = WireScheduler(asyncio.get_running_loop(), f"can-{bus.name}")
        start = max(time.monotonic_ns() + round(after_s * NS_PER_S), self._free_ns)
        self._free_ns = done = start + self.frame_ns(frame)
        self._scheduler.at(done, bus.deliver_now, frame, sender)

    def close(self) -> None:
        self.rate.close()
        if self._scheduler is not None:
            self._scheduler.close()


def can_timing(simulation: Simulation, processing_s: float = DEFAULT_PROCESSING_S) -> CanTiming:
    """Timing for a server's bus: the first module's GP 69 bit rate (one bus, one rate)."""
    return CanTiming(LineRate.can(simulation.modules[0] if simulation.modules else None), processing_s)
