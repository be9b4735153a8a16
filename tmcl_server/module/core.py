"""The module's state and what every command family shares: power-up, addressing, the
execution of one command, time and events, the world around the axes, global parameters.

The command handlers live in files by concern (``motion.py``, ``parameters.py``, ``io.py``,
``control.py``, ``evaluation.py``), each a mixin over :class:`ModuleCore`;
``tmcl_server/module/__init__.py`` joins them into :class:`TMCLModule` and holds the opcode
table.  Standalone mode (program memory, the interpreter, commands 128-135) is
``tmcl_server/module/program.py``.
"""

from __future__ import annotations

import logging
import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, ClassVar, Protocol

from axes.cores import CHIP_CORES, make_axes, refusal
from axes.interface import FOREVER, Axis, AxisEvent, AxisEventKind
from axes.world import DEFAULT_SIDES, INFINITY, AxisWorld, LoadZone, Switch, World, check_supply_voltage
from tmcl_server.dispatch import NO_REPLY, CommandError, Handler, Interface, ReplySink
from tmcl_server.eeprom import Eeprom, EepromWriteError
from tmcl_server.eeprom_check import first_problem
from tmcl_server.module.program import ProgramSupport
from tmcl_server.protocol import AnyReply, RawReply, Reply, Request
from tmcl_spec.commands import ALWAYS_REPLIED, READ_ONLY_OPCODES, IOBank, Opcode, Status
from tmcl_spec.modules import ModuleType, module_type
from tmcl_spec.numbers import NS_PER_MS, to_int32
from tmcl_spec.parameters import AP, GP, SWITCH_NAMES, Motion, ParamSpec

log = logging.getLogger(__name__)

#: Commands that cannot move an event either: coordinates, and global parameters of bank 2
#: (user variables, plain RAM) for the parameter commands below.
_SCHEDULE_NEUTRAL = READ_ONLY_OPCODES | {int(Opcode.GCO), int(Opcode.SCO)}
_GLOBAL_PARAMETER_COMMANDS = frozenset({int(Opcode.SGP), int(Opcode.STGP), int(Opcode.RSGP)})
#: Bank-0 parameters that decide which frames a module answers.
ADDRESS_PARAMETERS = frozenset({GP.SERIAL_ADDRESS, GP.SERIAL_SECONDARY_ADDRESS, GP.CAN_ID,
                                GP.CAN_SECONDARY_ID})
_OK = int(Status.OK)
#: Statuses of a command refused before it did anything (validation).
_REFUSALS = frozenset({int(Status.INVALID_COMMAND), int(Status.WRONG_TYPE),
                       int(Status.INVALID_VALUE)})
_GAP, _GGP = int(Opcode.GAP), int(Opcode.GGP)
#: GP 132, the tick timer, is 31 bits wide (read_global).
_TICK_MASK = 0x7FFF_FFFF
_INVALID_COMMAND = int(Status.INVALID_COMMAND)

#: The heartbeat period (GP 68 / GP 82, ms) watching each kind of interface.
HEARTBEAT_PARAMETERS = {Interface.SERIAL: GP.SERIAL_HEARTBEAT, Interface.CAN: GP.CAN_HEARTBEAT}


def chip_core_problem(kind: ModuleType, core: str) -> str | None:
    """One line saying why the module type cannot run on chip core ``core`` and which cores
    it runs on; None if it can (issue 34, item 10: refused at start, never a crash later)."""
    reason = refusal(core, kind.axis_parameters)
    if reason is None:
        return None
    if len(reason) > 100:  # a core's own message may list every parameter it lacks
        reason = f"{reason[:97]}..."
    fits = [name for name in sorted(CHIP_CORES) if refusal(name, kind.axis_parameters) is None]
    return (f"the {kind.name} does not run on the {core} core ({reason}); "
            f"it runs on {', '.join(fits)}")


@dataclass(frozen=True, slots=True)
class ModuleEvent:
    """Something observable happened inside the module (for telemetry and interrupts)."""

    time_ns: int
    kind: str
    axis: int | None = None
    data: dict[str, Any] = field(default_factory=dict)
    #: A run of like events, as only :attr:`ModuleCore.run_listeners` get them: ``repeat``
    #: events ``period_ns`` apart from ``time_ns`` on (a timer's dispatches left out by loop
    #: skipping, interpreter/skipping.py I12).  Everyone else gets each one.
    repeat: int = 1
    period_ns: int = 0

    def each(self) -> Iterator[ModuleEvent]:
        """The events of a run one by one, each at its instant."""
        if self.repeat == 1:
            yield self
            return
        for index in range(self.repeat):
            yield ModuleEvent(self.time_ns + index * self.period_ns, self.kind, self.axis,
                              self.data)


@dataclass(slots=True)
class _ReachWatch:
    sink: ReplySink
    interface: Interface


AxisFactory = Callable[[int], Axis]


class AxisSampler(Protocol):
    """Samples a module's axes at instants the module passes without stopping there (a
    recorder, tmcl_server/record.py): told before an axis is brought past one, it samples
    the axis there first, so a program's batches go on through the instants."""

    #: Per axis, the next instant it still has to sample (FOREVER: none now).
    due: list[int]

    def before_move(self, index: int, t_ns: int) -> None:
        """Axis ``index`` is about to be brought to ``t_ns``: sample it at the instants before."""
        ...


#: A handler: (module, request, sink, interface) -> reply value, None, or a special result.
HandlerFunction = Callable[..., Any]


class ModuleCore:
    """One simulated module's state (not thread-safe: the server calls it from one loop)."""

    #: Opcode -> handler of every command the module serves itself (the opcode table is in
    #: tmcl_server/module/__init__.py); a module type answers status 2 for opcodes it lacks.
    COMMANDS: ClassVar[dict[int, HandlerFunction]] = {}
    #: Handlers a module type assigns to opcodes itself (ModuleType.handlers), by name.
    VARIANT_COMMANDS: ClassVar[dict[str, HandlerFunction]] = {}

    def __init__(self, slot: int = 1, eeprom: Eeprom | None = None,
                 axis_factory: AxisFactory | None = None, start_ns: int = 0,
                 world: World | None = None, kind: ModuleType | str | None = None,
                 chip_core: str | None = None) -> None:
        #: The module type (profile): tables, I/O, identity, chip core.
        self.type = (module_type() if kind is None else module_type(kind) if isinstance(kind, str)
                     else kind)
        #: The motion-controller core of the axes: the profile's unless chosen otherwise
        #: (``chip_core``, e.g. ``--axis-core``, before the world file's ``[chip] core``).
        self.chip_core = chip_core or (world.chip_core if world else None) or self.type.chip_core
        #: The address the module was created with; names its state directory.
        self.slot = slot
        self.eeprom = eeprom if eeprom is not None else Eeprom()
        if self.eeprom.problem is None and self.eeprom.path is not None:
            problem = first_problem(self.eeprom.sections(), self.type)
            if problem is not None:
                self.eeprom.reject(problem)
        #: The physical surroundings (switches, load, encoder slip); kept across restarts.
        self.world = world or World()
        #: Builds one axis by index (tests); None: the chip core builds the module's axes.
        self._axis_factory = axis_factory
        self.listeners: list[Callable[[ModuleEvent], None]] = []
        #: Listeners that take a run of like events as one event (``ModuleEvent.repeat``): a
        #: timer's dispatches left out by loop skipping cost them one call, not one a tick
        #: (the others get each dispatch, at its instant, and pay for each).
        self.run_listeners: list[Callable[[ModuleEvent], None]] = []
        #: Called when the serial or CAN addresses may have changed (routers cache them).
        self.on_address_change: Callable[[], None] | None = None
        self.now_ns = start_ns
        #: Whether the command last performed changed anything (a refusal, a read and a write
        #: of what already is do not): a program loop that changes nothing may be skipped.
        self.changed = False
        #: Counts what may change a program's view of the module from outside its loop: host
        #: requests, a command that changed something, module events, world changes, power-up.
        #: A loop's pass analysed under one value is reused while it holds
        #: (interpreter/skipping.py I10); a program's write of a user variable does not count
        #: (the plan checks the variables it reads).
        self.epoch = 0
        #: Told before an axis is brought past an instant it samples (a recorder catching
        #: up, :class:`AxisSampler`); None: nobody samples.
        self.sampler: AxisSampler | None = None
        #: Standalone mode: program memory, the interpreter, control commands 128-135.
        self.program = ProgramSupport(self, self.type.program_memory, self.type.number_of_axes,
                                      self.type.digital_inputs)
        #: Opcode -> bound handler, for the commands this module type knows.
        self.handlers: dict[int, Handler] = {
            opcode: handler.__get__(owner)
            for owner in (self, self.program)
            for opcode, handler in owner.COMMANDS.items()
            if opcode in self.type.commands
        }
        for opcode, name in self.type.handlers.items():  # the module type's own meanings
            self.handlers[opcode] = self.VARIANT_COMMANDS[name].__get__(self)
        self.power_up()

    # == power-up and factory reset ============================================================

    def power_up(self) -> None:
        """Reset RAM state and reload what the EEPROM holds, as after switching on."""
        self.epoch += 1
        ee = self.eeprom
        self.globals: dict[int, dict[int, int]] = {
            bank: {n: spec.default for n, spec in table.items()}
            for bank, table in self.type.global_parameters.items()
        }
        bank0 = self.globals[0]
        # A simulated bus needs distinct addresses: each module's factory address is its slot.
        bank0[GP.SERIAL_ADDRESS] = self.slot
        bank0[GP.CAN_ID] = self.slot
        for key, value in ee.items("globals"):
            if int(key) in bank0:
                bank0[int(key)] = value
        if self.globals[0][GP.DO_NOT_RESTORE_USER_VARIABLES] == 0:
            for key, value in ee.items("user_variables"):
                self.globals[2][int(key)] = value
        # A restart resets the counters, not the mechanics: they stay where they are.
        mechanics = ([self.axis(i).status().mechanical_position for i in range(len(self.axes))]
                     if hasattr(self, "axes") else [])
        self.axes: list[Axis] = self._build_axes()
        #: Each axis's next event, and the axes whose entry must be asked again.
        self._axis_due: list[int | None] = [None] * len(self.axes)
        self._stale_axes: set[int] = set(range(len(self.axes)))
        #: Axes the command in progress touched (they are re-planned if it may reschedule).
        self._touched: set[int] = set()
        for axis in self.axes:  # the firmware's clock starts now (axes/tasks.py)
            axis.start_firmware_clock(self.type.firmware_clock, self.now_ns, len(self.axes))
            axis.advance_to(self.now_ns)
            if mechanics and mechanics[axis.index]:
                axis.place_mechanics(mechanics[axis.index])
            for key, value in (ee.get("axis_parameters", axis.index) or {}).items():
                try:
                    axis.set_parameter(int(key), value)
                except ValueError as exc:  # stored on another core, beyond what this one runs
                    log.warning("axis %d: stored AP %s = %s not restored: %s", axis.index, key,
                                value, exc)
        self.coordinates = [[0] * self.type.coordinates for _ in self.axes]
        if self.globals[0][GP.COORDINATE_STORAGE] == 1:
            self._copy_coordinates_from_eeprom(range(1, self.type.coordinates))
        self.outputs = [0] * self.type.outputs
        self.pullups = [1] * self.type.pullup_ports
        self.analog_inputs = [0] * self.type.analog_inputs
        if bank0.get(GP.END_SWITCH_POLARITY):
            self._apply_switch_polarity()
        boards = self.type.eval_boards
        #: Evaluation system: the boards' ID EEPROMs by channel (kept in RAM).
        self.id_eeproms: dict[int, bytearray] = (
            {} if boards is None else {ch: bytearray(image) for ch, image in boards.id_eeproms.items()})
        self.apply_world(self.world)
        self._tick_origin_ms = self.now_ns // NS_PER_MS
        self._random = random.Random(0)
        #: GP 131 (where the module has it): the status of the last command that failed.
        self.last_error = 0
        self._reach_request: tuple[int, bool, ReplySink, Interface] | None = None
        self._reach_watch: dict[int, _ReachWatch] = {}
        self._last_command_ns = {Interface.SERIAL: self.now_ns, Interface.CAN: self.now_ns}
        self._heartbeat_tripped = {Interface.SERIAL: False, Interface.CAN: False}
        self._due_ns: int | None = None
        self._due_stale = True
        #: GP 75 telegram pause (ms) before a serial reply, in seconds (kept up to date).
        self.reply_delay_s = self.globals[0][GP.TELEGRAM_PAUSE] / 1000.0
        self._addresses_changed()
        self.program.power_up()

    def _build_axes(self) -> list[Axis]:
        """The module's axes: on its chip core (in groups where a chip drives several)."""
        count = self.type.number_of_axes
        if self._axis_factory is not None:
            axes = [self._axis_factory(index) for index in range(count)]
        else:
            try:
                axes = make_axes(self.chip_core, count, self.type.axis_parameters,
                                 self.world.clock_hz)
            except ValueError:
                problem = chip_core_problem(self.type, self.chip_core)
                if problem is None:
                    raise
                raise ValueError(problem) from None
        if self.type.encoder_counts_per_rev is not None:
            for axis in axes:  # the module's own encoder, where the world names none
                axis.builtin_encoder_counts = self.type.encoder_counts_per_rev
        return axes

    @property
    def accumulator(self) -> int:
        """The program's A register (ACO, AAP and AGP read it in direct mode too)."""
        return self.program.interpreter.accumulator

    def factory_reset(self) -> None:
        """Command 137: erase the EEPROM and restart with factory settings."""
        self.eeprom.erase()
        self.power_up()

    def power_cycle(self) -> None:
        """Switch the module off and on (a reset fault, docs/faults.md): RAM as after power-on,
        the EEPROM kept, a program auto-started if GP 77 says so; the world stays."""
        self.power_up()
        self.emit("power_cycle", None)

    # == addressing ============================================================================

    @property
    def address(self) -> int:
        return self.globals[0][GP.SERIAL_ADDRESS]

    @property
    def host_address(self) -> int:
        return self.globals[0][GP.HOST_ADDRESS]

    @property
    def can_id(self) -> int:
        return self.globals[0][GP.CAN_ID]

    @property
    def can_reply_id(self) -> int:
        return self.globals[0][GP.CAN_REPLY_ID]

    def _addresses_changed(self) -> None:
        if self.on_address_change is not None:
            self.on_address_change()

    def accepts_serial(self, address: int) -> bool:
        secondary = self.globals[0][GP.SERIAL_SECONDARY_ADDRESS]
        return address == self.address or (secondary != 0 and address == secondary)

    def accepts_can(self, can_id: int) -> bool:
        if not self.type.has_can:
            return False
        secondary = self.globals[0][GP.CAN_SECONDARY_ID]
        return can_id == self.can_id or (secondary != 0 and can_id == secondary)

    def make_reply(self, status: int, opcode: int, value: int, interface: Interface) -> Reply:
        bank0 = self.globals[0]
        module = bank0[GP.CAN_ID] if interface is Interface.CAN else bank0[GP.SERIAL_ADDRESS]
        if not -0x8000_0000 <= value <= 0x7FFF_FFFF:
            value = to_int32(value)
        # tuple.__new__ skips the NamedTuple's Python-level __new__ (hot path)
        return tuple.__new__(Reply, (bank0[GP.HOST_ADDRESS], module, status, opcode, value))

    def checksum_error_reply(self) -> Reply:
        return self.make_reply(Status.WRONG_CHECKSUM, 0, 0, Interface.SERIAL)

    # == execution =============================================================================

    def execute(self, request: Request, interface: Interface = Interface.SERIAL,
                sink: ReplySink | None = None) -> AnyReply | None:
        """Run one direct-mode command and build its reply (None: no reply is sent)."""
        opcode = request.opcode
        self.epoch += 1  # a host request: whatever it does, a loop's plan is analysed again
        self._last_command_ns[interface] = self.now_ns
        self._heartbeat_tripped[interface] = False
        if self.program.downloading and opcode < Opcode.STOP_APPLICATION:
            status, value = self.program.store(request)
        else:
            status, result = self.perform(request, sink, interface)
            if result is NO_REPLY:
                return None
            value = result
        # GP 255 silences every reply but those of GAP, GGP and GIO (§5.1): special layouts too
        if self.globals[0][GP.SUPPRESS_REPLY] and opcode not in ALWAYS_REPLIED:
            return None
        if isinstance(value, RawReply):
            return value
        return self.make_reply(status, opcode, value, interface)

    def perform(self, request: Request, sink: ReplySink | None = None,
                interface: Interface = Interface.SERIAL) -> tuple[int, Any]:
        """Run a command's handler: (status, reply value or a special result)."""
        opcode = request.opcode
        handler = self.handlers.get(opcode)
        if handler is None:
            self.last_error = _INVALID_COMMAND
            return _INVALID_COMMAND, request.value
        touched = self._touched
        touched.clear()
        self.changed = opcode not in READ_ONLY_OPCODES  # a handler that changes nothing says so
        try:
            result = handler(request, sink, interface)
        except CommandError as exc:
            self.last_error = int(exc.status)
            if exc.status in _REFUSALS:  # refused before anything was done
                self.changed = False
            return exc.status, request.value if exc.value is None else exc.value
        except EepromWriteError:  # logged by the EEPROM; the host learns it from the status
            self.last_error = int(Status.EEPROM_LOCKED)
            return Status.EEPROM_LOCKED, request.value
        finally:
            if self.changed:
                self.epoch += 1
            if self.changed and self.may_reschedule(opcode, request.motor):
                self._stale_axes |= touched  # the command may start, stop or move an event
                self._due_stale = True
        return _OK, request.value if result is None else result

    def steady_until(self, opcode: int, type_: int, motor: int, status: int) -> int:
        """How long the command just performed (and unchanged) would answer the same and
        change nothing if executed again, nothing intervening (see ModulePort.probe)."""
        if status != _OK:
            return FOREVER if status in _REFUSALS else 0
        if opcode == _GAP:
            return self.axes[motor].steady_until(type_)
        if opcode == _GGP:  # the motor field is the bank; the row says how it moves
            row = self.type.global_parameters.get(motor, {}).get(type_)
            if row is None:
                return 0  # not a row of the table: no promise
            if row.motion is Motion.TIME:  # the tick timer counts milliseconds
                return (self.now_ns // NS_PER_MS + 1) * NS_PER_MS
            if row.motion is Motion.ACCESS:  # the next random number; a refused command of
                return 0  # the same loop sets the last error (a refusal "changes nothing")
        # inputs, outputs, variables, coordinates: changed only from outside; RFS STATUS: the
        # search moves on only at its axis's notable instants (events) or by a command
        return FOREVER

    def first_time_at(self, opcode: int, type_: int, motor: int, values: tuple[int, ...],
                      read_ns: int) -> int:
        """For GAP of a moving value, or GGP of the tick timer, read at ``read_ns``: when it
        first compares otherwise with one of ``values`` (0: unknown)."""
        if opcode == _GGP:
            row = self.type.global_parameters.get(motor, {}).get(type_)
            if row is None or row.motion is not Motion.TIME:
                return 0
            return self._tick_first_time_at(values, read_ns)
        if opcode != _GAP or not 0 <= motor < len(self.axes):
            return 0
        return self.axes[motor].first_time_at(type_, values, read_ns)

    def _tick_first_time_at(self, values: tuple[int, ...], read_ns: int) -> int:
        """GP 132 counts whole milliseconds from its origin, 31 bits wide (read_global): it
        meets every value above the one read, one a millisecond, and wraps to 0 past the top
        (a comparison flips there without meeting its boundary, as AP 1's at its wrap).  Only
        a command (SGP 132) or a power-up moves its origin, and both count in the epoch."""
        read_ms = read_ns // NS_PER_MS
        tick = (read_ms - self._tick_origin_ms) & _TICK_MASK
        first = read_ms + _TICK_MASK - tick + 1  # the wrap to 0
        for value in values:
            if tick < value <= _TICK_MASK:
                first = min(first, read_ms + value - tick)
        return first * NS_PER_MS

    @staticmethod
    def may_reschedule(opcode: int, bank: int) -> bool:
        """Whether a command can create, move or cancel an internal event (``bank``: the motor
        field, which is the bank of the global-parameter commands)."""
        if opcode in _SCHEDULE_NEUTRAL:
            return False
        return not (opcode in _GLOBAL_PARAMETER_COMMANDS and bank == 2)

    # == time ==================================================================================
    #
    # Axes are brought up to date lazily: advancing the module only steps every axis when an
    # event is due; otherwise an axis catches up when a command touches it (:meth:`axis`).
    # The time of the next event is cached and recomputed after anything that may change it.

    def next_event_ns(self) -> int | None:
        """Earliest simulated time at which the module changes state by itself."""
        hardware = self._hardware_next_event_ns()
        program = self.program.next_event_ns(self.now_ns)
        if program is None or (hardware is not None and hardware < program):
            return hardware
        return program

    def _hardware_next_event_ns(self) -> int | None:
        """Next event of the axes and heartbeats (cached until something may move it).

        Each axis's next event is cached too: only the axes a command touched are asked again.
        """
        if self._due_stale:
            axis_due = self._axis_due
            for index in self._stale_axes:
                axis_due[index] = self.axes[index].next_event_ns()
            self._stale_axes.clear()
            times = [t for t in axis_due if t is not None]
            times.extend(self._heartbeat_deadlines())
            self._due_ns = min(times) if times else None
            self._due_stale = False
        return self._due_ns

    def advance_to(self, t_ns: int) -> None:
        """Run the module up to ``t_ns``, handling every internal event in time order.

        The program runs in batches between hardware events; a batch ends early after a
        command that may have scheduled a new event, and the plan is made again.
        """
        while True:
            hardware = self._hardware_next_event_ns()
            if hardware is None or hardware > t_ns:
                # Instructions timed exactly at a hardware event run after it is handled.
                if self.program.run(self.now_ns, t_ns + 1):
                    continue
                break
            target = max(hardware, self.now_ns)
            if self.program.run(self.now_ns, target):
                continue
            self.step_to(target)
        if t_ns > self.now_ns:
            self.now_ns = t_ns  # the axes catch up lazily

    def invalidate_schedule(self) -> None:
        """Forget the cached next-event times (the world changed from outside)."""
        self._stale_axes.update(range(len(self.axes)))
        self._due_stale = True
        self.epoch += 1

    def snapshot(self) -> dict[str, Any]:
        """A JSON-ready picture of the module for telemetry (docs/mqtt.md names the fields)."""
        axes = []
        for index in range(len(self.axes)):
            s = self.axis(index).status()
            axes.append({
                "position": s.position, "target": s.target, "velocity": s.velocity,
                "mode": s.mode, "reached": s.position_reached, "home": s.home_switch,
                "left": s.left_switch, "right": s.right_switch, "load": s.load,
                "errors": s.error_flags, "current": s.current, "standby": s.standby,
                "encoder": s.encoder_position, "reference_search": s.reference_search,
            })
        return {
            "t": self.now_ns / 1e9,
            "address": self.address,
            "axes": axes,
            "outputs": list(self.outputs),
            "inputs": [self.digital_input(p) for p in range(self.type.digital_inputs)],
            "analog": list(self.analog_inputs),
            "supply": self.supply_voltage,
            "program": {"state": self.read_global(GP.APPLICATION_STATUS, 0),
                        "pc": self.read_global(GP.PROGRAM_COUNTER, 0)},
        }

    def axis(self, index: int) -> Axis:
        """Axis ``index``, brought up to the module's current time (use this, not ``axes``)."""
        axis = self.axes[index]
        self._touched.add(index)
        sampler = self.sampler
        if sampler is not None and sampler.due[index] < self.now_ns:
            sampler.before_move(index, self.now_ns)  # a recorder's instants it passes
        for event in axis.advance_to(self.now_ns):  # none are due: advance_to handled them
            self._on_axis_event(event)
        return axis

    def axis_at(self, index: int, t_ns: int) -> Axis:
        """Axis ``index`` brought to ``t_ns``, an instant the module has reached but the axis
        not yet (a recorder's sample: nothing but its own motion changed the axis since)."""
        axis = self.axes[index]
        for event in axis.advance_to(t_ns):
            self._on_axis_event(event)
        return axis

    def step_to(self, t_ns: int) -> None:
        """Make ``t_ns`` the present and handle every event due at it (none may lie before)."""
        self.now_ns = t_ns
        self._due_stale = True
        self.epoch += 1  # events are handled here: what a loop reads may change
        sampler = self.sampler
        for index, due in enumerate(self._axis_due):
            if (due is not None and due <= t_ns) or index in self._stale_axes:
                self._stale_axes.add(index)
                if sampler is not None and sampler.due[index] < t_ns:
                    sampler.before_move(index, t_ns)  # its samples before the event
                for event in self.axes[index].advance_to(t_ns):
                    self._on_axis_event(event)
        self._check_heartbeats()

    def skip_program_to(self, t_ns: int) -> None:
        """The program lost the race against a real clock: it resumes at ``t_ns`` without
        running what lies before (docs/scheduling.md); the axes still get every event."""
        self.program.interpreter.skip_to(t_ns)
        self.advance_to(t_ns)

    def catch_up(self, t_ns: int) -> None:
        """Make ``t_ns`` the present, no event lying before it (a program instruction's time):
        the axes follow lazily when a command touches them."""
        if t_ns > self.now_ns:
            self.now_ns = t_ns

    def _heartbeat_deadline(self, interface: Interface) -> int | None:
        """When the heartbeat of ``interface`` trips, if it is on and armed."""
        period = self.globals[0][HEARTBEAT_PARAMETERS[interface]]
        if not period or self._heartbeat_tripped[interface]:
            return None
        return self._last_command_ns[interface] + period * NS_PER_MS

    def _heartbeat_deadlines(self) -> list[int]:
        return [t for t in map(self._heartbeat_deadline, HEARTBEAT_PARAMETERS) if t is not None]

    def _check_heartbeats(self) -> None:
        for interface in HEARTBEAT_PARAMETERS:
            deadline = self._heartbeat_deadline(interface)
            if deadline is not None and self.now_ns >= deadline:
                self._heartbeat_tripped[interface] = True
                for index in range(len(self.axes)):
                    self.axis(index).emergency_stop()
                self._stale_axes.update(range(len(self.axes)))
                self.emit("heartbeat_timeout", None, interface=interface.value)

    def _on_axis_event(self, event: AxisEvent) -> None:
        self.emit(event.kind.value, event.axis, time_ns=event.time_ns, active=event.active)
        self.program.on_axis_event(event)
        if event.kind is AxisEventKind.TARGET_REACHED:
            watch = self._reach_watch.pop(event.axis, None)
            if watch is not None and not self.globals[0][GP.SUPPRESS_REPLY]:
                reply = self.make_reply(Status.TARGET_REACHED_EVENT, Opcode.TARGET_REACHED_EVENT,
                                        1 << event.axis, watch.interface)
                watch.sink.send_unsolicited(reply)

    def emit(self, kind: str, axis: int | None, time_ns: int | None = None, **data: Any) -> None:
        if not self.listeners and not self.run_listeners:
            return
        event = ModuleEvent(self.now_ns if time_ns is None else time_ns, kind, axis, data)
        for listener in list(self.listeners):
            listener(event)
        for listener in list(self.run_listeners):
            listener(event)

    def emit_run(self, kind: str, axis: int | None, time_ns: int, period_ns: int, repeat: int,
                 **data: Any) -> None:
        """``repeat`` events of ``kind``, ``period_ns`` apart from ``time_ns`` on: each one to
        :attr:`listeners`, the run as one event to :attr:`run_listeners`."""
        if repeat <= 0 or (not self.listeners and not self.run_listeners):
            return
        run = ModuleEvent(time_ns, kind, axis, data, repeat, period_ns)
        for listener in list(self.listeners):
            for event in run.each():
                listener(event)
        for listener in list(self.run_listeners):
            listener(run)

    # == I/O from the outside world ============================================================

    def set_analog_input(self, port: int, value: int) -> None:
        if not 0 <= port < self.type.analog_inputs or not 0 <= value <= self.type.analog_full_scale:
            raise ValueError(f"input {port} value {value} out of range")
        before = self.digital_input(port)
        self.epoch += 1
        self.analog_inputs[port] = value
        if self.digital_input(port) != before:
            self.emit("input_changed", None, port=port, level=int(not before))
            self.program.on_input_changed(port, int(not before))

    def set_digital_input(self, port: int, active: bool) -> None:
        self.set_analog_input(port, self.type.analog_full_scale if active else 0)

    def digital_input(self, port: int) -> int:
        return int(self.analog_inputs[port] >= self.type.digital_threshold)

    @property
    def supply_voltage(self) -> float:
        """The supply voltage (V) the module's monitor sees: the world's, or the nominal one."""
        volts = self.world.supply_voltage
        return self.type.nominal_supply_voltage if volts is None else volts

    def set_supply_voltage(self, volts: float) -> None:
        """Change the supply (V) at run time, e.g. to test a host's under-voltage check."""
        self.world.supply_voltage = check_supply_voltage(volts)
        self.epoch += 1
        self.emit("supply_changed", None, volts=self.world.supply_voltage)

    def supply_voltage_reading(self) -> int:
        """What ``GIO <supply channel>, 1`` answers (0.1 V units on the TMCM-6212)."""
        return round(self.supply_voltage * self.type.supply_voltage_per_volt)

    # == the world around the axes (world file, tests, MQTT) ===================================

    def apply_world(self, world: World) -> None:
        """Place switches, load zones and encoder slip, and set the inputs, as ``world`` says."""
        self.world = world
        for index, axis_world in world.axes.items():
            self._world_axis(index).set_world(axis_world)
        for port, value in world.analog_inputs.items():
            self.set_analog_input(port, value)
        for port, active in world.digital_inputs.items():
            self.set_digital_input(port, active)

    def _world_axis(self, index: int) -> Axis:
        """The axis at the current time, about to have its world changed."""
        if not 0 <= index < len(self.axes):
            raise ValueError(f"axis {index} outside 0..{len(self.axes) - 1} of the {self.type.name}")
        axis = self.axis(index)
        self._stale_axes.add(index)  # switches and load zones decide when the next event is
        self._due_stale = True
        self.epoch += 1
        return axis

    def set_switch(self, axis: int, name: str, position: int | None, width: int | None = None,
                   side: str | None = None, normally_closed: bool = False) -> None:
        """Place (or with ``position=None`` remove) the "left", "right" or "home" switch."""
        if name not in SWITCH_NAMES:
            raise ValueError(f"unknown switch {name!r}")
        switch = None if position is None else Switch.place(
            position, width, side or DEFAULT_SIDES[name], normally_closed)
        target = self._world_axis(axis)
        target.set_switch(name, switch)
        self.world.axes.setdefault(axis, target.world)

    def force_switch(self, axis: int, name: str, active: bool) -> None:
        """Hold a switch at a level wherever the axis is (a test rig pressing it by hand)."""
        if name not in SWITCH_NAMES:
            raise ValueError(f"unknown switch {name!r}")
        target = self._world_axis(axis)
        target.set_switch(name, Switch(-INFINITY, INFINITY) if active else None)
        self.world.axes.setdefault(axis, target.world)

    def set_load(self, axis: int,
                 zones: list[tuple[int, int, int]] | list[tuple[int, int, int, bool | None]],
                 free_load: int | None = None) -> None:
        """Load zones as (from, to, load value[, blocked]); load 0 (or blocked True) is a
        blocked motor, which stalls a motor faster than AP 181 (docs/world.md)."""
        target = self._world_axis(axis)
        target.set_load([LoadZone(*zone) for zone in zones], free_load)
        self.world.axes.setdefault(axis, target.world)

    def set_encoder_slip(self, axis: int, slip: float) -> None:
        target = self._world_axis(axis)
        target.set_encoder_slip(slip)
        self.world.axes.setdefault(axis, target.world)

    def set_axis_stuck(self, axis: int, stuck: bool, load: int | None = None) -> None:
        """The motor of ``axis`` stops following its steps (a fault; False: it follows again)."""
        target = self._world_axis(axis)
        target.set_stuck(stuck, load)
        self.world.axes.setdefault(axis, target.world)

    def break_switch(self, axis: int, name: str, level: bool | None) -> None:
        """Hold the "left", "right" or "home" input at an electrical level (None: repaired)."""
        if name not in SWITCH_NAMES:
            raise ValueError(f"unknown switch {name!r}")
        target = self._world_axis(axis)
        target.break_switch(name, level)
        self.world.axes.setdefault(axis, target.world)

    def axis_world(self, axis: int) -> AxisWorld:
        return self._world_axis(axis).world

    # == checks shared by handlers =============================================================

    def _axis_index(self, motor: int) -> int:
        if not 0 <= motor < len(self.axes):
            raise CommandError(Status.INVALID_VALUE)
        return motor

    def _axis(self, motor: int) -> Axis:
        if not 0 <= motor < len(self.axes):
            raise CommandError(Status.INVALID_VALUE)
        return self.axis(motor)

    def _axis_spec(self, number: int) -> ParamSpec:
        spec = self.type.axis_parameters.get(number)
        if spec is None:
            raise CommandError(Status(self.type.unknown_parameter_status))
        return spec

    def _global_spec(self, number: int, bank: int) -> ParamSpec:
        table = self.type.global_parameters.get(bank)
        if table is None:
            raise CommandError(Status.INVALID_VALUE)
        spec = table.get(number)
        if spec is None:
            raise CommandError(Status.WRONG_TYPE)
        return spec

    # == global parameters and inputs (the RAM copy; the handlers validate) ====================

    def read_global(self, number: int, bank: int) -> int:
        """GGP semantics for callers that already validated the request (also the interpreter)."""
        if bank == 0:
            mirrored = self.program.read_global(number)
            if mirrored is not None:
                return mirrored
            if number == GP.TICK_TIMER:
                return (self.now_ns // NS_PER_MS - self._tick_origin_ms) & _TICK_MASK
            if number == GP.RANDOM_NUMBER:
                return self._random.randrange(2**31)
            if number == GP.LAST_TMCL_ERROR:
                return self.last_error
        return self.globals[bank][number]

    def write_global(self, number: int, bank: int, value: int) -> None:
        if bank == 2:  # user variables: plain RAM that nothing else watches (the common case)
            self.globals[2][number] = value
            return
        if bank == 0:
            if number == GP.TICK_TIMER:
                self._tick_origin_ms = self.now_ns // NS_PER_MS - value
                return
            if number == GP.RANDOM_NUMBER:
                self._random.seed(value)
                return
        old = self.globals[bank][number]
        self.globals[bank][number] = value
        self.program.global_written(bank, number, value, old)
        if bank == 0:
            if number in ADDRESS_PARAMETERS:
                self._addresses_changed()
            elif number == GP.TELEGRAM_PAUSE:
                self.reply_delay_s = value / 1000.0
            elif number == GP.COORDINATE_STORAGE and value == 1:
                self._copy_coordinates_to_eeprom(range(1, self.type.coordinates))
            elif number == GP.END_SWITCH_POLARITY:
                self._apply_switch_polarity()
            if self.type.global_parameters[0][number].auto_stored:  # last: it may fail (status 5)
                self.eeprom.put("globals", number, value)

    def _apply_switch_polarity(self) -> None:
        """GP 79 (TMC429 modules): 1 inverts every axis's limit switches, as the TMCM-6212's
        AP 24/25 invert one axis's (the module's input stage, docs/modules.md)."""
        inverted = self.globals[0][GP.END_SWITCH_POLARITY]
        for index in range(len(self.axes)):
            axis = self.axis(index)
            axis.set_parameter(AP.LEFT_POLARITY, inverted)
            axis.set_parameter(AP.RIGHT_POLARITY, inverted)

    def _copy_coordinates_to_eeprom(self, numbers: Any, motors: Any = None) -> None:
        stored = {k: dict(v) for k, v in self.eeprom.items("coordinates")}
        for motor in range(len(self.axes)) if motors is None else motors:
            row = stored.setdefault(str(motor), {})
            for n in numbers:
                row[str(n)] = self.coordinates[motor][n]
        self.eeprom.replace_section("coordinates", stored)

    def _copy_coordinates_from_eeprom(self, numbers: Any) -> None:
        for motor in range(len(self.axes)):
            row = self.eeprom.get("coordinates", motor) or {}
            for n in numbers:
                self.coordinates[motor][n] = row.get(str(n), 0)

    def read_input(self, port: int, bank: int) -> int:
        if bank == IOBank.DIGITAL_INPUTS:
            return self.digital_input(port)
        if bank == IOBank.ANALOG_INPUTS:
            return self.analog_inputs[port]
        return self.outputs[port]


    def _arm_reach_watch(self, *axes: int) -> None:
        """One MVP starts moves on ``axes``: watch those a 138 request covers.

        A type-0 request covers the next MVP that moves a motor of its mask (all the motors
        of its mask that this one MVP moves); type 1 covers every MVP (docs/protocol.md).
        A move that has reached its target but not yet come to rest ends with its own
        "target reached" (and 138 reply) before the new move's watch replaces its own.
        """
        for axis in axes:
            self.axes[axis].conclude_move()
            self.axis(axis)  # hands on what that announced, to the old watch
            self._reach_watch.pop(axis, None)
        if self._reach_request is None:
            return
        mask, every_move, sink, interface = self._reach_request
        covered = [axis for axis in axes if mask >> axis & 1]
        for axis in covered:
            self._reach_watch[axis] = _ReachWatch(sink, interface)
        if covered and not every_move:
            self._reach_request = None

