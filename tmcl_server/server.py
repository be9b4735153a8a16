"""The asyncio server: one simulation, many transports, one event loop.

Use it from asyncio code (``async with Server(config) as server``), from blocking code and
tests through :class:`tmcl_server.embed.SimulatorThread`, or from the shell with
``tmcl-server`` (tmcl_server/cli.py).
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from axes.cores import CHIP_CORES
from axes.world import World, load_world
from tmcl_server.clock import Clock, LockstepClock, RealClock, VirtualClock
from tmcl_server.eeprom import Eeprom
from tmcl_server.lograte import limit_repeats
from tmcl_server.module import TMCLModule
from tmcl_server.observe import DEFAULT_RECORD_MAX, DEFAULT_TRACE_MAX, Observers
from tmcl_server.simulation import PROGRAM_CHUNK_NS, Simulation
from tmcl_server.transports import transport_class
from tmcl_server.transports.base import Transport
from tmcl_server.transports.can import DEFAULT_BUS_NAME
from tmcl_server.transports.mqtt import DEFAULT_RATE_HZ
from tmcl_spec.modules import DEFAULT_MODULE_TYPE, module_type
from tmcl_spec.numbers import seconds_to_ns

if TYPE_CHECKING:
    from tmcl_server.transports.can.bus import SimulatedCanBus

log = logging.getLogger(__name__)

#: Wall time the server's timer spends on simulation work before the loop gets a turn.
SLICE_WALL_S = 0.0002
#: While hosts are sending (a request came since the last slice) a busy program runs in
#: slices this short, of chunks at most this long, so a request waits less for the slice in
#: progress; with nobody asking, the longer ones above cost less bookkeeping
#: (docs/scheduling.md).
SLICE_WALL_TRAFFIC_S = 0.00005
PROGRAM_CHUNK_TRAFFIC_NS = 100_000
#: A program this far behind the clock gets the long slices even while hosts send: it must
#: keep real time (beyond MAX_LAG_NS it would lose time), the requests get what is left.  A
#: busy program is woken at least every 10 ms (interpreter.SLICE_NS), so lags below that are
#: its normal rhythm, not a sign that it falls behind.
PROGRAM_PRIORITY_LAG_NS = 20_000_000
#: ... unless it lost time anyway (it skipped, MAX_LAG_NS) within this many wall seconds: such
#: a program needs more CPU than its instructions' simulated time (an AAP that moves a ramp
#: costs 100-300 us of Python against its 10 us), and priority would starve the hosts without
#: saving it.  While hosts send, it gets at most PROGRAM_SHARE_TRAFFIC of the loop's wall
#: time: after each slice the timer waits (1 - share) / share times as long, the hosts have
#: the loop meanwhile, and direct mode keeps >= 0.7 x its idle rate (issue 36, N11).
HOPELESS_HOLD_S = 1.0
PROGRAM_SHARE_TRAFFIC = 0.25


@dataclass
class ServerConfig:
    """Everything the command line can say, as data (also the embedding API's input)."""

    addresses: list[int] = field(default_factory=lambda: [1])
    #: Endpoint arguments per transport kind (tmcl_server.transports.TRANSPORTS), e.g.
    #: {"tcp": ["127.0.0.1:2323"]}.
    endpoints: dict[str, list[str]] = field(default_factory=lambda: {"tcp": ["127.0.0.1:2323"]})
    state_dir: str | None = None
    #: "real" (wall clock x speed) or "virtual" (moves only when advanced).
    clock: str = "real"
    speed: float = 1.0
    ready_file: str | None = None
    #: Highest rate of MQTT state messages per module (Hz).
    mqtt_rate: float = DEFAULT_RATE_HZ
    #: Name of the simulated CAN bus (socketcand clients open it by name).
    can_bus_name: str = DEFAULT_BUS_NAME
    #: TOML world file (switches, load, encoder slip, inputs) applied to every module.
    world: str | None = None
    #: Which module every slot holds (tmcl_spec.modules.MODULE_TYPES).
    module_type: str = DEFAULT_MODULE_TYPE
    #: The chip core of the axes (axes.cores.CHIP_CORES); None: the module type's own.
    axis_core: str | None = None
    #: clock "lockstep": simulated seconds each request takes (tmcl_server.clock.LockstepClock).
    request_time: float = 0.001
    #: Telegram trace: a file, "-" for stderr, None for none; "text" or "jsonl" (trace.py).
    trace: str | None = None
    trace_format: str = "text"
    #: Record the axes to a .csv or .jsonl file every record_resolution simulated seconds.
    record: str | None = None
    record_resolution: float = 0.01
    record_axes: list[int] | None = None
    #: Faults injected from the start: specs (``noreply:opcode=GAP``) or tables (faults.py).
    faults: list[Any] = field(default_factory=list)
    #: Bytes and CAN frames take the real link's time (transports/wire.py); the module's
    #: processing time between a request and its reply then.
    wire_timing: bool = False
    processing_time: float = 0.0002
    #: Clients one TCP endpoint serves at once; a new one past it closes the one silent
    #: longest (docs/robustness.md).
    max_connections: int = 256
    #: Skip the passes of program loops that change nothing (docs/scheduling.md); False: the
    #: stepping reference, every instruction executed (same results, slower).
    skip_loops: bool = True
    #: Trace and record files: rotated to FILE.1 past this many bytes (0: no limit).
    trace_max: int = DEFAULT_TRACE_MAX
    record_max: int = DEFAULT_RECORD_MAX
    #: The dashboard (``--http``): origins besides its own whose pages may drive it ("*": any),
    #: and the token it requires beyond loopback (None: drawn at start, or TMCL_HTTP_TOKEN).
    http_allow_origins: list[str] = field(default_factory=list)
    http_token: str | None = None
    #: MQTT clients may inject faults (``sim/fault``, ``sim/power_cycle``): off unless asked.
    mqtt_faults: bool = False
    #: MQTT clients may send commands that change the module (SAP, STAP, MVP, programs, 137,
    #: ...): off unless asked; reads (GAP, GGP, GIO, the version) are always served.
    mqtt_commands: bool = False

    def make_clock(self) -> Clock:
        if self.clock == "virtual":
            return VirtualClock()
        if self.clock == "lockstep":
            return LockstepClock(seconds_to_ns(self.request_time))
        if self.clock == "real":
            return RealClock(self.speed)
        raise ValueError(f"unknown clock {self.clock!r}")


def module_state_dir(state_dir: str | os.PathLike[str], slot: int) -> Path:
    return Path(state_dir) / f"module-{slot}"


def build_simulation(config: ServerConfig) -> Simulation:
    clock = config.make_clock()
    kind = module_type(config.module_type)
    modules = []
    for slot in config.addresses:
        directory = module_state_dir(config.state_dir, slot) if config.state_dir else None
        # each module gets its own copy: the simulator API changes worlds per module
        world = (load_world(config.world, kind.number_of_axes, kind.analog_inputs,
                            kind.analog_full_scale, CHIP_CORES) if config.world else World())
        module = TMCLModule(slot, Eeprom(directory), start_ns=clock.now_ns(), world=world,
                            kind=kind, chip_core=config.axis_core)
        module.program.skip_loops = config.skip_loops
        modules.append(module)
    return Simulation(modules, clock)


#: Endpoint kind -> the tmcl-server option that names it (for error messages).
OPTION_NAMES = {"tcp": "--tcp", "pty": "--pty", "serial": "--serial", "can": "--can",
                "slcan": "--slcan-pty", "socketcand": "--socketcand", "mqtt": "--mqtt",
                "http": "--http"}


def write_atomically(path: str | os.PathLike[str], text: str) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    import tempfile  # only for the ready file

    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.replace(tmp, target)


class Server:
    """Owns the simulation, the transports and what they share (the CAN bus)."""

    def __init__(self, config: ServerConfig | None = None,
                 simulation: Simulation | None = None) -> None:
        self.config = config or ServerConfig()
        self.simulation = simulation or build_simulation(self.config)
        self._can_bus: SimulatedCanBus | None = None
        self.transports: list[Transport] = []
        self.endpoints: dict[str, list[str]] = {}
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.Handle | None = None
        self._timer_when = 0.0
        #: Loop time before which no slice runs: the hosts' share (PROGRAM_SHARE_TRAFFIC).
        self._hosts_until = 0.0
        self._running_due = False
        #: Requests the simulation had served when the timer last ran (traffic or quiet).
        self._requests_seen = 0
        #: Program time skipped so far (all modules), and when it last grew (wall seconds).
        self._skipped_seen = 0
        self._skipped_at = float("-inf")
        #: The wall clock the timer measures its slices with (tests hold it still).
        self.wall_s: Callable[[], float] = time.perf_counter
        self._stopped = asyncio.Event()
        #: The trace and the recorder, when the configuration asks for them.
        self.observers = Observers(self.simulation, self.config)

    @property
    def clock(self) -> Clock:
        return self.simulation.clock

    # -- what transports get (transports.base.TransportHost) ----------------------------------

    def option(self, name: str) -> Any:
        return getattr(self.config, name)

    def can_bus(self) -> SimulatedCanBus:
        """The simulated CAN bus, created with the modules on it when a transport first asks."""
        if self._can_bus is None:
            from tmcl_server.transports.can.bus import open_can_bus  # imports python-can

            self._can_bus = open_can_bus(self.simulation, self.config.can_bus_name)
            if self.config.wire_timing:
                from tmcl_server.transports.wire import can_timing

                self._can_bus.timing = can_timing(self.simulation, self.config.processing_time)
        return self._can_bus

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> dict[str, list[str]]:
        self._loop = asyncio.get_running_loop()
        self.simulation.on_change = self._reschedule
        for module in self.simulation.modules:  # stores: a journal append, snapshots in a thread
            module.eeprom.start_journal(self._loop.call_later)
        limit_repeats()  # what a host can make us log, at most one line per call site in 5 s
        try:
            self.observers.start(self._loop)
            if self.config.faults:
                from tmcl_server.faults import FaultInjector

                FaultInjector.of(self.simulation).add_all(self.config.faults)
            for kind, arguments in self.config.endpoints.items():
                for argument in arguments:
                    try:
                        transport = transport_class(kind).build(self, argument)
                        self.transports.append(transport)
                        started = await transport.start()
                    except Exception as exc:  # the command line can name the endpoint
                        exc.add_note(f"{OPTION_NAMES.get(kind, kind)} {argument}")
                        raise
                    self.endpoints.setdefault(transport.kind, []).extend(started)
        except BaseException:
            await self.stop()
            raise
        if self._can_bus is not None:
            self.endpoints["can_bus"] = [self._can_bus.name]
        self._reschedule()
        if self.config.ready_file:
            write_atomically(self.config.ready_file, json.dumps(self.endpoints) + "\n")
        return self.endpoints

    async def stop(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
            self._timer = None
        for transport in reversed(self.transports):
            try:
                await transport.close()
            except Exception:  # keep closing the others
                log.exception("closing %s failed", transport.kind)
        self.transports.clear()
        for module in self.simulation.modules:  # the last snapshot; the journals go
            module.eeprom.flush()
        if self._can_bus is not None and self._can_bus.timing is not None:
            self._can_bus.timing.close()
        self.observers.close()
        if self.config.ready_file:
            Path(self.config.ready_file).unlink(missing_ok=True)
        self._stopped.set()

    def request_stop(self) -> None:
        self._stopped.set()

    async def wait_stopped(self) -> None:
        await self._stopped.wait()

    async def __aenter__(self) -> Server:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()

    # -- real-time scheduling -----------------------------------------------------------------

    def _reschedule(self) -> None:
        """Arm one loop timer for the next internal event (real clocks only)."""
        if self._loop is None or self.clock.virtual or self._running_due:
            return
        nxt = self.simulation.next_event_ns()
        if nxt is None:
            return
        delay = max(0.0, self.clock.wall_seconds(nxt - self.clock.now_ns()))
        when = max(self._loop.time() + delay, self._hosts_until)
        if self._timer is not None:
            if self._timer_when <= when:
                return
            self._timer.cancel()
        self._timer_when = when
        self._timer = self._loop.call_at(when, self._on_timer)

    def _on_timer(self) -> None:
        """Run what is due; a busy program goes in chunks, and after :data:`SLICE_WALL_S` of
        work the loop gets its turn (requests, replies) before the rest."""
        self._timer = None
        self._running_due = True  # run_due's change notices must not arm a second timer
        simulation = self.simulation
        requests = simulation.requests
        hosts = requests != self._requests_seen
        self._requests_seen = requests
        started = self.wall_s()
        skipped = sum(simulation.skipped_ns)
        if skipped != self._skipped_seen:
            self._skipped_seen, self._skipped_at = skipped, started
        hopeless = started - self._skipped_at < HOPELESS_HOLD_S
        traffic = hosts and (hopeless or simulation.lag_ns < PROGRAM_PRIORITY_LAG_NS)
        chunk_ns = PROGRAM_CHUNK_TRAFFIC_NS if traffic else PROGRAM_CHUNK_NS
        try:
            deadline = started + (SLICE_WALL_TRAFFIC_S if traffic else SLICE_WALL_S)
            while simulation.run_due(chunk_ns):
                now = self.wall_s()
                if now >= deadline and self._loop is not None:
                    if hosts and hopeless:  # the hosts' share first (PROGRAM_SHARE_TRAFFIC)
                        pause = (now - started) * (1 - PROGRAM_SHARE_TRAFFIC) / PROGRAM_SHARE_TRAFFIC
                        self._hosts_until = self._timer_when = self._loop.time() + pause
                        self._timer = self._loop.call_at(self._timer_when, self._on_timer)
                    else:
                        self._timer_when = self._loop.time()
                        self._timer = self._loop.call_soon(self._on_timer)
                    return
        finally:
            self._running_due = False
        self._reschedule()
