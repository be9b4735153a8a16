"""Standalone mode: the module side of the TMCL interpreter.

:class:`ProgramSupport` sits between the module model and :mod:`interpreter.machine`: it
implements the interpreter's :class:`~interpreter.machine.ModulePort`, serves the control
commands 128-135 and the program commands sent in direct mode (its :attr:`COMMANDS` table,
merged into the module's), keeps program memory in the EEPROM, and turns module events into
interrupts.  It reaches the module only through :class:`StandaloneHost`, the few things it
needs; the module imports this file, never the other way round.  Choices the manual leaves
open are in docs/interpreter.md.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any, ClassVar, Protocol

from axes.interface import Axis, AxisEvent, AxisEventKind
from interpreter import interrupts
from interpreter.interrupts import Trigger
from interpreter.isa import Instruction
from interpreter.machine import Interpreter
from tmcl_server.dispatch import CommandError, Interface, ReplySink
from tmcl_server.eeprom import WRITE_TIME_NS, Eeprom
from tmcl_server.protocol import RawReply, Request, checksum
from tmcl_spec.commands import (
    CALC_MAX_OPERATION,
    READ_ONLY_OPCODES,
    CalcOp,
    CodeProtection,
    ErrorFlag,
    Opcode,
    RfsType,
    Status,
)
from tmcl_spec.modules import ModuleType
from tmcl_spec.numbers import INT32_MAX, INT32_MIN
from tmcl_spec.parameters import GP

EEPROM_SECTION = "program"
_GGP, _SGP, _OK = int(Opcode.GGP), int(Opcode.SGP), int(Status.OK)
#: Command 135 "mode" while the module is in download mode (GP 128 only knows 0..3).
DOWNLOAD_MODE = 4
_LEGACY_READ = struct.Struct(">BBBBiB")

_EVENT_VECTORS = {
    AxisEventKind.TARGET_REACHED: interrupts.target_reached,
    AxisEventKind.STALL: interrupts.stall,
    AxisEventKind.DEVIATION: interrupts.deviation,
}
_SWITCH_VECTORS = {
    AxisEventKind.LEFT_SWITCH: interrupts.left_switch,
    AxisEventKind.RIGHT_SWITCH: interrupts.right_switch,
}


class StandaloneHost(Protocol):
    """What standalone mode needs from the module it runs on."""

    now_ns: int
    eeprom: Eeprom
    #: The module type (its bank-2 table tells which user variables are plain RAM).
    type: ModuleType
    #: Whether the command last performed changed anything (see ModulePort.probe).
    changed: bool
    #: Counts what may have intervened from outside a program's loop (interpreter/skipping.py
    #: I10).
    epoch: int
    #: bank -> number -> value, as stored in RAM (GP 77, GP 81, bank 3 timers and triggers).
    globals: dict[int, dict[int, int]]

    @property
    def address(self) -> int: ...

    @property
    def host_address(self) -> int: ...

    def catch_up(self, t_ns: int) -> None:
        """Make ``t_ns`` the module's present (an instruction's time; no event lies before it)."""

    def may_reschedule(self, opcode: int, bank: int) -> bool:
        """Whether a command can create, move or cancel an internal event."""

    def steady_until(self, opcode: int, type_: int, motor: int, status: int) -> int:
        """How long the unchanged command just performed would answer the same."""

    def first_time_at(self, opcode: int, type_: int, motor: int, values: tuple[int, ...],
                      read_ns: int) -> int:
        """When a moving value read by GAP at ``read_ns`` first compares otherwise with one
        of ``values`` (0: unknown)."""

    def perform(self, request: Request, sink: ReplySink | None = None,
                interface: Interface = Interface.SERIAL) -> tuple[int, Any]:
        """Run a command's handler as direct mode does: (status, value)."""

    def axis(self, index: int) -> Axis:
        """Axis ``index`` at the module's present time."""

    def emit(self, kind: str, axis: int | None, time_ns: int | None = None, **data: Any) -> None:
        """Tell the module's listeners (telemetry) about a program event."""

    def emit_run(self, kind: str, axis: int | None, time_ns: int, period_ns: int, repeat: int,
                 **data: Any) -> None:
        """Tell them about ``repeat`` like events, ``period_ns`` apart (``ModuleEvent.repeat``)."""


class ProgramSupport:
    """Program memory, download mode, the interpreter and its control commands for one module."""

    def __init__(self, module: StandaloneHost, memory_size: int,
                 number_of_axes: int = interrupts.NUMBER_OF_AXES,
                 number_of_inputs: int = interrupts.NUMBER_OF_INPUTS) -> None:
        self.module = module
        self.memory_size = memory_size
        #: Bank-3 parameters that are trigger transitions, for this module's axes and inputs.
        self._triggered = interrupts.triggered(number_of_axes, number_of_inputs)
        self.interpreter = Interpreter(self, number_of_axes=number_of_axes, memory_size=memory_size)
        self.downloading = False
        self.download_address = 0
        self._dirty = False
        #: User variables any int32 can be written to and read from (GGP/SGP bank 2 fast path).
        self._plain_variables = frozenset(
            number for number, spec in module.type.global_parameters.get(2, {}).items()
            if spec.readable and spec.writable and spec.minimum <= INT32_MIN
            and spec.maximum >= INT32_MAX)

    # == power-up ==============================================================================

    def power_up(self) -> None:
        """Reload the program from the EEPROM, forget the run state, auto-start (GP 77)."""
        now = self.module.now_ns
        self.interpreter.power_up(now)
        self.interpreter.erase()
        self.downloading = False
        self._dirty = False
        for key, fields in self.module.eeprom.items(EEPROM_SECTION):
            self.interpreter.store(int(key), Instruction(*fields))
        for number, value in self.module.globals.get(3, {}).items():
            self.global_written(3, number, value)
        if self.module.globals[0][GP.AUTO_START] == 1 and self.interpreter.program():
            self.interpreter.start(now, 0)

    # == the interpreter's port ================================================================

    def execute(self, time_ns: int, opcode: int, type_: int, motor: int,
                value: int) -> tuple[int, int, bool]:
        module = self.module
        module.catch_up(time_ns)
        if motor == 2 and type_ in self._plain_variables:  # user variables: plain RAM, the usual
            variables = module.globals[2]                # case of a program's GGP and AGP
            if opcode == _GGP:
                module.changed = False
                return _OK, variables[type_], False
            if opcode == _SGP:
                module.changed = variables[type_] != value
                variables[type_] = value
                return _OK, value, False
        request = tuple.__new__(Request, (module.address, opcode, type_, motor, value))  # no __new__
        if opcode in READ_ONLY_OPCODES:  # the usual case: a read stores nothing, moves no event
            status, result = module.perform(request)
            return status, result, False
        eeprom = module.eeprom
        stores = eeprom.stores
        status, result = module.perform(request)
        if eeprom.stores != stores:  # the program waits for the part's write cycles
            self.interpreter.busy_until(time_ns + (eeprom.stores - stores) * WRITE_TIME_NS)
        return status, result, module.changed and module.may_reschedule(opcode, motor)

    def probe(self, time_ns: int, opcode: int, type_: int, motor: int,
              value: int) -> tuple[int, int, bool, int]:
        status, result, _ = self.execute(time_ns, opcode, type_, motor, value)
        module = self.module
        if module.changed:
            return status, result, True, 0
        return status, result, False, module.steady_until(opcode, type_, motor, status)

    def first_time_at(self, time_ns: int, opcode: int, type_: int, motor: int,
                      values: tuple[int, ...]) -> int:
        self.module.catch_up(time_ns)
        return self.module.first_time_at(opcode, type_, motor, values, time_ns)

    def axis_parameter(self, time_ns: int, motor: int, number: int) -> int:
        self.module.catch_up(time_ns)
        return self.module.axis(motor).get_parameter(number)

    def reference_search_active(self, time_ns: int, motor: int) -> bool:
        self.module.catch_up(time_ns)
        return self.module.axis(motor).reference_search(RfsType.STATUS) != 0

    def steady_until(self, time_ns: int, opcode: int, type_: int, motor: int) -> int:
        self.module.catch_up(time_ns)
        return self.module.steady_until(opcode, type_, motor, _OK)

    def program_event(self, time_ns: int, kind: str, **data: int) -> None:
        self.module.emit(kind, None, time_ns=time_ns, **data)

    def program_events(self, time_ns: int, period_ns: int, repeat: int, kind: str,
                       **data: int) -> None:
        self.module.emit_run(kind, None, time_ns, period_ns, repeat, **data)

    def epoch(self) -> int:
        return self.module.epoch

    def user_variable(self, number: int) -> int | None:
        return self.module.globals[2][number] if number in self._plain_variables else None

    # == time ==================================================================================

    def next_event_ns(self, now_ns: int) -> int | None:
        return self.interpreter.next_event_ns(now_ns)

    def run(self, now_ns: int, end_ns: int) -> bool:
        """Run the program's instructions that start before ``end_ns`` (see Interpreter)."""
        return self.interpreter.run_until(now_ns, end_ns)

    @property
    def skip_loops(self) -> bool:
        """Whether loops that change nothing are skipped (False: every instruction stepped)."""
        return self.interpreter.skip_loops

    @skip_loops.setter
    def skip_loops(self, value: bool) -> None:
        self.interpreter.skip_loops = value

    def on_virtual_clock(self, slice_ns: int) -> None:
        """Nothing waits for a real clock: a running program asks to be run every
        ``slice_ns`` only, its timers fire inside its runs (docs/scheduling.md)."""
        self.interpreter.slice_ns = slice_ns
        self.interpreter.wake_for_timers = False

    @property
    def busy(self) -> bool:
        """The program has instructions to run now (it is not stopped or idle in a WAIT)."""
        return self.interpreter.busy

    # == module events =========================================================================

    def on_axis_event(self, event: AxisEvent) -> None:
        vector = _EVENT_VECTORS.get(event.kind)
        if vector is not None:
            self.interpreter.raise_interrupt(vector(event.axis))
            if event.kind is AxisEventKind.DEVIATION:
                self.interpreter.set_error_flag(ErrorFlag.EDV)
            return
        switch = _SWITCH_VECTORS.get(event.kind)
        if switch is not None and event.active is not None:
            self.interpreter.trigger_transition(switch(event.axis), event.active)

    def on_input_changed(self, port: int, level: int) -> None:
        self.interpreter.trigger_transition(interrupts.input_change(port), bool(level))

    def global_written(self, bank: int, number: int, value: int, old: int | None = None) -> None:
        """A global parameter changed: timers and triggers (bank 3), code protection (GP 81)."""
        if bank == 3:
            if number < interrupts.NUMBER_OF_TIMERS:
                self.interpreter.set_timer(number, value, self.module.now_ns)
            elif number in self._triggered:
                self.interpreter.triggers[number] = Trigger(value)
        elif (bank == 0 and number == GP.CODE_PROTECTION and old is not None
              and old & CodeProtection.READ and not value & CodeProtection.READ):
            # Lifting the read protection erases the program first (GP 81, Table 16).
                self.interpreter.stop()
                self.interpreter.erase()
                self.module.eeprom.replace_section(EEPROM_SECTION, {})

    def read_global(self, number: int) -> int | None:
        """GP 128/129/130 mirror the interpreter; None for every other parameter."""
        if number == GP.APPLICATION_STATUS:
            return int(self.interpreter.status)
        if number == GP.DOWNLOAD_MODE:
            return int(self.downloading)
        if number == GP.PROGRAM_COUNTER:
            return self.interpreter.pc
        return None

    # == download mode =========================================================================

    def store(self, request: Request) -> tuple[int, int]:
        """Download mode: keep the command in program memory instead of executing it."""
        if self.download_address >= self.memory_size:
            return Status.MAX_EXCEEDED, request.value
        self.interpreter.store(self.download_address,
                               Instruction(request.opcode, request.type, request.motor, request.value))
        self.download_address += 1
        self._dirty = True
        return Status.LOADED, request.value

    def persist(self) -> None:
        """Write program memory to the EEPROM (at the end of a download)."""
        if not self._dirty:
            return
        stored = {address: list(ins) for address, ins in enumerate(self.interpreter.program())
                  if ins.opcode != 0}
        self.module.eeprom.replace_section(EEPROM_SECTION, stored)
        self._dirty = False

    @property
    def _protection(self) -> int:
        return self.module.globals[0][GP.CODE_PROTECTION]

    # == control commands (Table 13) ===========================================================

    def _cmd_stop_application(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.interpreter.stop()

    def _cmd_run_application(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if self.downloading:
            raise CommandError(Status.COMMAND_NOT_AVAILABLE)
        if req.type == 0:
            self.interpreter.start(self.module.now_ns)
        elif req.type == 1:
            if not 0 <= req.value < self.memory_size:
                raise CommandError(Status.INVALID_VALUE)
            self.interpreter.start(self.module.now_ns, req.value)
        else:
            raise CommandError(Status.WRONG_TYPE)

    def _cmd_step_application(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if self.downloading:
            raise CommandError(Status.COMMAND_NOT_AVAILABLE)
        self.interpreter.step(self.module.now_ns)

    def _cmd_reset_application(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.interpreter.reset()

    def _cmd_enter_download_mode(self, req: Request, sink: ReplySink | None,
                                 interface: Interface) -> None:
        if self._protection & CodeProtection.WRITE:
            raise CommandError(Status.WRITE_PROTECTED)
        if not 0 <= req.value < self.memory_size:
            raise CommandError(Status.INVALID_VALUE)
        self.interpreter.stop()
        self.downloading = True
        self.download_address = req.value

    def _cmd_exit_download_mode(self, req: Request, sink: ReplySink | None,
                                interface: Interface) -> None:
        self.downloading = False
        self.persist()

    def _cmd_read_program_memory(self, req: Request, sink: ReplySink | None,
                                 interface: Interface) -> RawReply:
        """The legacy layout: ``[host][opcode][type][motor][value x4][checksum]``."""
        if not 0 <= req.value < self.memory_size:
            raise CommandError(Status.INVALID_VALUE)
        ins = self.interpreter.code[req.value]
        if self._protection & CodeProtection.READ:
            ins = Instruction(0)  # protected memory reads as empty: nothing to disassemble
        body = _LEGACY_READ.pack(self.module.host_address, ins.opcode, ins.type, ins.motor,
                                 ins.value, 0)[:8]
        return RawReply(body + bytes((checksum(body),)), body[1:8])

    def _cmd_get_application_status(self, req: Request, sink: ReplySink | None,
                                    interface: Interface) -> int:
        interp = self.interpreter
        if req.type in (0, 1):
            mode = DOWNLOAD_MODE if self.downloading else int(interp.status)
            pointer = self.download_address if req.type == 0 else interp.pc
            return mode << 24 | int(interp.wait is not None) << 16 | pointer & 0xFFFF
        if req.type == 2:
            return interp.accumulator
        if req.type == 3:
            return interp.x
        raise CommandError(Status.WRONG_TYPE)

    # == program commands sent in direct mode ==================================================

    def _acknowledge(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        """Flow commands in direct mode: OK, and the program is untouched."""

    # CALC, CALCX and CLE act on the registers the program uses: direct AAP/AGP/ACO read
    # that same accumulator (§3.5.5).  The reply echoes the operand (§3.6.14).

    def _cmd_calc(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if not 0 <= req.type <= CALC_MAX_OPERATION:
            raise CommandError(Status.WRONG_TYPE)
        self.interpreter.calc(req.type, req.value)

    def _cmd_calcx(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if not 0 <= req.type <= max(CalcOp):
            raise CommandError(Status.WRONG_TYPE)
        self.interpreter.calcx(req.type)

    def _cmd_cle(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if not 0 <= req.type <= max(ErrorFlag):
            raise CommandError(Status.WRONG_TYPE)
        self.interpreter.clear_error_flags(req.type)

    def _cmd_ei(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.interpreter.enable_interrupt(req.type)

    def _cmd_di(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self.interpreter.disable_interrupt(req.type)

    def _cmd_vect(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        if not 0 <= req.value < self.memory_size:
            raise CommandError(Status.INVALID_VALUE)
        self.interpreter.vectors[req.type] = req.value

    def _accumulator_to(self, opcode: Opcode, req: Request) -> None:
        status, _ = self.module.perform(Request(req.address, opcode, req.type, req.motor,
                                                self.interpreter.accumulator))
        if status != Status.OK:
            raise CommandError(Status(status))

    def _cmd_aap(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self._accumulator_to(Opcode.SAP, req)

    def _cmd_agp(self, req: Request, sink: ReplySink | None, interface: Interface) -> None:
        self._accumulator_to(Opcode.SGP, req)

    # == the dispatch table ====================================================================

    #: Opcode -> handler of the commands standalone mode serves (merged into the module's).
    COMMANDS: ClassVar[dict[int, Callable[..., Any]]] = {
        Opcode.STOP_APPLICATION: _cmd_stop_application,
        Opcode.RUN_APPLICATION: _cmd_run_application,
        Opcode.STEP_APPLICATION: _cmd_step_application,
        Opcode.RESET_APPLICATION: _cmd_reset_application,
        Opcode.ENTER_DOWNLOAD_MODE: _cmd_enter_download_mode,
        Opcode.EXIT_DOWNLOAD_MODE: _cmd_exit_download_mode,
        Opcode.READ_PROGRAM_MEMORY: _cmd_read_program_memory,
        Opcode.GET_APPLICATION_STATUS: _cmd_get_application_status,
        Opcode.EI: _cmd_ei,
        Opcode.DI: _cmd_di,
        Opcode.VECT: _cmd_vect,
        Opcode.AAP: _cmd_aap,
        Opcode.AGP: _cmd_agp,
        Opcode.CALC: _cmd_calc,
        Opcode.CALCX: _cmd_calcx,
        Opcode.CLE: _cmd_cle,
        **dict.fromkeys((Opcode.COMP, Opcode.JC, Opcode.JA, Opcode.CSUB, Opcode.RSUB,
                         Opcode.WAIT, Opcode.STOP, Opcode.RETI),
                        _acknowledge),
    }
