"""Standalone mode on the module model: the manual's example programs on the virtual clock,
control commands 128-135, download mode, EEPROM, GP 77/81 and interrupts from module events.

The examples that move motors run on both chip cores (``core``: TMC4210 and TMC4361A).
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import pairwise
from pathlib import Path

import pytest

from axes.interface import FOREVER, AxisEvent, AxisEventKind
from interpreter.assembler import assemble
from interpreter.isa import Instruction, decode_program
from interpreter.machine import Interpreter
from tmcl_server.clock import VirtualClock
from tmcl_server.eeprom import Eeprom
from tmcl_server.module import TMCM6212, ModuleEvent, TMCLModule
from tmcl_server.protocol import RawReply, Reply, Request, checksum
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import ApplicationStatus, CalcOp, ErrorFlag, Opcode, Status
from tmcl_spec.parameters import GP
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS

S = 1_000_000_000
MS = 1_000_000
#: The chip cores the manual's motion examples run on.
CORES = ("tmc4210", "tmc4361a")


class Bench:
    """One module on a virtual clock, driven through its command interface."""

    def __init__(self, module: TMCLModule | None = None, core: str | None = None) -> None:
        self.module = module or (TMCM6212() if core is None
                                 else TMCLModule(kind="tmcm-6212", chip_core=core))
        self.sim = Simulation([self.module], VirtualClock())
        self.events: list[ModuleEvent] = []
        self.module.listeners.append(self.events.append)

    def cmd(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> Reply:
        reply = self.module.execute(Request(1, opcode, type_, motor, value))
        assert isinstance(reply, Reply)
        return reply

    def download(self, source: str, start: int = 0) -> list[Instruction]:
        program = assemble(source).instructions
        assert self.cmd(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, start).status == Status.OK
        for ins in program:
            reply = self.cmd(*ins)
            assert (reply.status, reply.opcode, reply.value) == (Status.LOADED, ins.opcode, ins.value)
        assert self.cmd(Opcode.EXIT_DOWNLOAD_MODE).status == Status.OK
        return program

    def run(self, address: int | None = None) -> None:
        reply = self.cmd(Opcode.RUN_APPLICATION, 0, 0, 0) if address is None else \
            self.cmd(Opcode.RUN_APPLICATION, 1, 0, address)
        assert reply.status == Status.OK

    def advance(self, seconds: float) -> None:
        self.sim.advance(seconds)

    def position(self, motor: int = 0) -> int:
        return self.module.axis(motor).get_parameter(1)

    def gp(self, number: int, bank: int = 0) -> int:
        return self.cmd(Opcode.GGP, number, bank).value

    def kinds(self, kind: str) -> list[ModuleEvent]:
        return [e for e in self.events if e.kind == kind]

    @property
    def interpreter(self) -> Interpreter:
        return self.module.program.interpreter


# -- the manual's example programs ------------------------------------------------------------

@pytest.mark.parametrize("core", CORES)
def test_first_steps_position_loop_runs_ten_minutes_of_program(core: str) -> None:
    """§2.4: rotate both ways, then shuttle between +-512000 forever."""
    bench = Bench(core=core)
    bench.download("""
        ROL 0, 51200
        WAIT TICKS, 0, 500
        MST 0
        ROR 0, 51200
        WAIT TICKS, 0, 500
        MST 0
        SAP 4, 0, 51200
        SAP 5, 0, 51200
    Loop:
        MVP ABS, 0, 512000
        WAIT POS, 0, 0
        MVP ABS, 0, -512000
        WAIT POS, 0, 0
        JA Loop
    """)
    bench.run()
    bench.advance(2.5)
    # ROL: turning left at full speed (AP 3 reads the chip's quantised velocity back)
    assert bench.module.axis(0).get_parameter(3) == pytest.approx(-51200, rel=1e-3)
    bench.advance(600)
    arrivals = [(e.time_ns, bench.position()) for e in bench.kinds("target_reached")]
    # First move ends ~11 s after the rotations; every later one spans 1024000 steps.
    assert len(arrivals) >= 25
    gaps = {round((b - a) / S, 3) for (a, _), (b, _) in pairwise(arrivals[1:])}
    # 20 s at 51200 pps + 2 x 0.5 s ramps; the chip's quantised velocity makes it 20.998 s,
    # and every leg takes exactly as long as the others (no drift)
    assert len(gaps) == 1 and gaps.pop() == pytest.approx(21.0, abs=0.005)
    assert bench.interpreter.status is ApplicationStatus.RUN
    assert bench.gp(GP.APPLICATION_STATUS) == 1


def test_timer_interrupt_output_toggler() -> None:
    """§3.5.6.4, with the include-file spelling of the vector numbers."""
    bench = Bench()
    bench.download("""
        #include Interrupts.inc
        VECT TI_TIMER0, Timer0Irq
        SGP TI_TIMER0, 3, 1000
        EI TI_TIMER0
        EI TI_GLOBAL
    Loop:
        SIO 3, 2, 1
        WAIT TICKS, 0, 50
        SIO 3, 2, 0
        WAIT TICKS, 0, 50
        JA Loop
    Timer0Irq:
        GIO 0, 2
        JC NZ, Out0Off
        SIO 0, 2, 1
        RETI
    Out0Off:
        SIO 0, 2, 0
        RETI
    """)
    bench.run()
    bench.advance(4.2)
    changes = [(e.data["port"], e.data["level"], e.time_ns // MS) for e in bench.kinds("output_changed")]
    out0 = [(level, ms) for port, level, ms in changes if port == 0]
    out3 = [(level, ms) for port, level, ms in changes if port == 3]
    assert [level for level, _ in out0] == [1, 0, 1, 0]
    assert [ms for _, ms in out0] == [1000, 2000, 3000, 4000]
    assert [level for level, _ in out3[:4]] == [1, 0, 1, 0]
    assert [ms // 500 for _, ms in out3] == list(range(len(out3)))  # every 500 ms, unaffected
    assert len(out3) == 9


@pytest.mark.parametrize("core", CORES)
def test_subroutine_example(core: str) -> None:
    """§3.6.18: move, call SubW (wait for arrival, then 500 ms), move back, forever."""
    bench = Bench(core=core)
    bench.download("""
    Loop:
        MVP ABS, 0, 10000
        CSUB SubW
        MVP ABS, 0, 0
        CSUB SubW
        JA Loop
    SubW:
        WAIT POS, 0, 0
        WAIT TICKS, 0, 50
        RSUB
    """)
    bench.run()
    bench.advance(10)
    positions = [event.time_ns for event in bench.kinds("target_reached")]
    assert len(positions) >= 6
    # Each leg: 10000 steps at 51200 pps^2 never reaches 51200 pps: a triangle of
    # 2 * sqrt(10000 / 51200) = 0.884 s; then SubW waits 0.5 s more before the next MVP.
    # The emulated TMC4210 quantises velocity and acceleration: within 5 ms of the ideal.
    legs = [round((b - a) / MS) for a, b in pairwise(positions)]
    assert all(abs(leg - (884 + 500)) <= 5 for leg in legs), legs
    assert len(bench.interpreter.stack) <= 1


def test_potentiometer_follower_aap_loop() -> None:
    """§3.6.27: the target position follows analogue input 0, times four."""
    bench = Bench()
    bench.download("""
    Start:
        GIO 0, 1
        CALC MUL, 4
        AAP 0, 0
        JA Start
    """)
    bench.run()
    bench.module.set_analog_input(0, 1000)
    bench.advance(0.8)
    assert bench.module.axis(0).get_parameter(0) == 4000
    assert bench.position() == 4000
    bench.module.set_analog_input(0, 2500)
    bench.advance(0.8)
    assert bench.position() == 10000
    assert bench.cmd(Opcode.GAP, 1, 0).value == 10000


@pytest.mark.parametrize("core", CORES)
def test_host_callable_function_table(core: str) -> None:
    """§7.6: JA entries at 0/1/2 started with command 129 from those addresses."""
    bench = Bench(core=core)
    bench.download("""
    Func1: JA Func1Start
    Func2: JA Func2Start
    Func3: JA Func3Start
    Func1Start:
        MVP ABS, 0, 1000
        WAIT POS, 0, 0
        MVP ABS, 0, 0
        WAIT POS, 0, 0
        STOP
    Func2Start:
        ROL 0, 500
        WAIT TICKS, 0, 100
        MST 0
        STOP
    Func3Start:
        ROR 0, 1000
        WAIT TICKS, 0, 700
        MST 0
        STOP
    """)
    bench.run(0)
    bench.advance(0.15)
    assert bench.position() > 0
    bench.advance(2)
    assert bench.position() == 0 and len(bench.kinds("target_reached")) == 2
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.STOP

    bench.run(1)
    bench.advance(0.5)
    assert bench.module.axis(0).get_parameter(3) == -500
    bench.advance(1)
    assert bench.module.axis(0).get_parameter(3) == 0
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.STOP

    bench.run(2)
    bench.advance(6.5)
    assert bench.module.axis(0).get_parameter(3) == 1000
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.RUN
    bench.advance(1)
    assert bench.module.axis(0).get_parameter(3) == 0
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.STOP


@pytest.mark.parametrize("core", CORES)
def test_pytrinamic_vector_interrupts_revector_each_other(core: str) -> None:
    """The IDE binary: target-reached handlers re-vector interrupt 3 to each other."""
    vector = Path(__file__).resolve().parents[1] / "vectors" / "pytrinamic_test.bin"
    bench = Bench(core=core)
    for address, ins in enumerate(decode_program(vector.read_bytes())):
        bench.interpreter.store(address, ins)
    bench.run()
    bench.advance(9)
    arrivals_ms = [e.time_ns // (S // 1000) for e in bench.kinds("target_reached")]
    # every 2 s, give or take the chip's ramp quantisation (a few ms over the run)
    assert arrivals_ms == pytest.approx([2000, 4000, 6000, 8000], abs=10)
    bench.advance(1)
    assert bench.interpreter.pc == 4 and not bench.interpreter.in_interrupt


@pytest.mark.parametrize("core", CORES)
def test_main_loop_example(core: str) -> None:
    """§7.2: initialise, then run between two positions forever."""
    bench = Bench(core=core)
    bench.download("""
        SAP 4, 0, 50000
        SAP 5, 0, 10000
    MainLoop:
        MVP ABS, 0, 5000
        WAIT POS, 0, 0
        MVP ABS, 0, 0
        WAIT POS, 0, 0
        JA MainLoop
    """)
    arrivals: list[int] = []
    bench.module.listeners.append(
        lambda e: arrivals.append(bench.position()) if e.kind == "target_reached" else None)
    bench.run()
    bench.advance(10)
    assert len(arrivals) >= 6
    assert arrivals == [5000, 0] * (len(arrivals) // 2) + [5000] * (len(arrivals) % 2)


@pytest.mark.parametrize("core", CORES)
def test_comp_jc_example(core: str) -> None:
    """§3.6.15/16: jump when the position of motor 0 is at least 1000."""
    source = """
        GAP 1, 0
        COMP 1000
        JC GE, Label
        STOP
    Label: ROL 0, 1000
        STOP
    """
    for position, rotating in ((1500, True), (1000, True), (999, False)):
        bench = Bench(core=core)
        bench.cmd(Opcode.SAP, 1, 0, position)
        bench.download(source)
        bench.run()
        bench.advance(0.1)
        assert (bench.module.axis(0).get_parameter(2) == -1000) is rotating


@pytest.mark.parametrize(("store", "expected"), [("AGP", 2468), ("AAP", 1234)])
def test_user_variable_example(store: str, expected: int) -> None:
    """§7.4.  The manual stores the result with AAP, which addresses axis parameter 42 of
    motor 2 (no such parameter: the program ignores the error); AGP is what it means."""
    bench = Bench()
    bench.download(f"""
        MyVariable = 42
        SGP MyVariable, 2, 1234
        GGP MyVariable, 2
        CALC MUL, 2
        {store} MyVariable, 2
        STOP
    """)
    bench.run()
    bench.advance(0.01)
    assert bench.gp(42, 2) == expected
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 2).value == 2468


# -- control commands ---------------------------------------------------------------------------

def test_download_mode_stores_from_the_given_address_and_134_reads_back() -> None:
    bench = Bench()
    program = bench.download("CALC LOAD, -2\nJA 100", start=100)
    assert bench.gp(GP.DOWNLOAD_MODE) == 0
    reply = bench.module.execute(Request(1, Opcode.READ_PROGRAM_MEMORY, 0, 0, 100))
    assert isinstance(reply, RawReply)
    body = bytes([2, Opcode.CALC, 9, 0, 0xFF, 0xFF, 0xFF, 0xFE])
    assert reply.encode() == body + bytes([checksum(body)])
    assert reply.encode_can() == body[1:]
    for address, ins in enumerate(program, 100):
        raw = bench.module.execute(Request(1, Opcode.READ_PROGRAM_MEMORY, 0, 0, address)).encode()
        assert tuple(raw[1:4]) == ins[:3]
    assert bench.module.execute(Request(1, 134, 0, 0, 0)).encode()[1] == 0  # empty cell
    assert bench.cmd(Opcode.READ_PROGRAM_MEMORY, 0, 0, 6144).status == Status.INVALID_VALUE


def test_download_mode_answers_101_and_executes_nothing() -> None:
    bench = Bench()
    assert bench.cmd(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0).status == Status.OK
    assert bench.module.read_global(GP.DOWNLOAD_MODE, 0) == 1
    assert bench.cmd(Opcode.GGP, GP.DOWNLOAD_MODE, 0).status == Status.LOADED  # stored, not run
    reply = bench.cmd(Opcode.MVP, 0, 0, 5000)
    assert reply.status == Status.LOADED
    bench.advance(1)
    assert bench.position() == 0
    status = bench.cmd(Opcode.GET_APPLICATION_STATUS, 0)
    assert status.value >> 24 == 4 and status.value & 0xFFFF == 2  # mode 4, pointer after 2
    assert bench.cmd(Opcode.RUN_APPLICATION).status == Status.COMMAND_NOT_AVAILABLE
    assert bench.cmd(Opcode.GET_FIRMWARE_VERSION, 1).status == Status.OK  # control: executed
    assert bench.cmd(Opcode.EXIT_DOWNLOAD_MODE).status == Status.OK
    assert bench.interpreter.code[0] == Instruction(Opcode.GGP, GP.DOWNLOAD_MODE, 0, 0)
    assert bench.interpreter.code[1] == Instruction(Opcode.MVP, 0, 0, 5000)


def test_download_past_the_end_and_bad_addresses() -> None:
    bench = Bench()
    assert bench.cmd(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 6144).status == Status.INVALID_VALUE
    assert bench.cmd(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 6143).status == Status.OK
    assert bench.cmd(Opcode.STOP).status == Status.LOADED
    assert bench.cmd(Opcode.STOP).status == Status.MAX_EXCEEDED
    bench.cmd(Opcode.EXIT_DOWNLOAD_MODE)
    assert bench.cmd(Opcode.RUN_APPLICATION, 1, 0, 6144).status == Status.INVALID_VALUE
    assert bench.cmd(Opcode.RUN_APPLICATION, 2, 0, 0).status == Status.WRONG_TYPE


def test_stop_step_reset_and_application_status() -> None:
    bench = Bench()
    bench.download("CALC LOAD, 5\nCALCX LOAD\nCALC ADD, 1\nLoop: WAIT TICKS, 0, 10\nJA Loop")
    for _ in range(3):
        assert bench.cmd(Opcode.STEP_APPLICATION).status == Status.OK
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.STEP
    assert bench.gp(GP.PROGRAM_COUNTER) == 3
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 2).value == 6
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 3).value == 5
    bench.cmd(Opcode.STEP_APPLICATION)  # the WAIT starts: PC stays on it
    status = bench.cmd(Opcode.GET_APPLICATION_STATUS, 1).value
    assert (status >> 24, status >> 16 & 0xFF, status & 0xFFFF) == (2, 1, 3)
    bench.run()
    bench.advance(0.05)
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 1).value >> 24 == ApplicationStatus.RUN
    assert bench.cmd(Opcode.STOP_APPLICATION).status == Status.OK
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.STOP
    executed = bench.interpreter.executed
    bench.advance(1)
    assert bench.interpreter.executed == executed
    assert bench.cmd(Opcode.RESET_APPLICATION).status == Status.OK
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.RESET
    assert (bench.gp(GP.PROGRAM_COUNTER), bench.cmd(135, 2).value, bench.cmd(135, 3).value) == (0, 0, 0)
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 4).status == Status.WRONG_TYPE


def test_program_is_kept_in_eeprom_and_auto_started(tmp_path: Path) -> None:
    bench = Bench(TMCM6212(eeprom=Eeprom(tmp_path)))
    program = bench.download("Loop: GGP 0, 2\nCALC ADD, 1\nAGP 0, 2\nJA Loop")
    assert bench.cmd(Opcode.SGP, GP.AUTO_START, 0, 1).status == Status.OK

    again = Bench(TMCM6212(eeprom=Eeprom(tmp_path)))  # power cycle
    assert again.interpreter.program() == program
    assert again.gp(GP.APPLICATION_STATUS) == ApplicationStatus.RUN
    again.advance(0.1)
    assert again.gp(0, 2) > 100

    bench.cmd(Opcode.SGP, GP.AUTO_START, 0, 0)
    third = Bench(TMCM6212(eeprom=Eeprom(tmp_path)))
    assert third.gp(GP.APPLICATION_STATUS) == ApplicationStatus.STOP
    assert third.interpreter.program() == program


def test_code_protection() -> None:
    bench = Bench()
    bench.download("CALC LOAD, 1\nSTOP")
    bench.cmd(Opcode.SGP, GP.CODE_PROTECTION, 0, 1)  # no read-back
    raw = bench.module.execute(Request(1, Opcode.READ_PROGRAM_MEMORY, 0, 0, 0)).encode()
    assert raw[1:8] == bytes(7)
    assert bench.interpreter.program() != []  # ... but the program is still there and runs
    bench.cmd(Opcode.SGP, GP.CODE_PROTECTION, 0, 3)  # and no overwriting
    assert bench.cmd(Opcode.ENTER_DOWNLOAD_MODE).status == Status.WRITE_PROTECTED
    assert bench.cmd(Opcode.MVP, 0, 0, 100).status == Status.OK  # still direct mode
    bench.cmd(Opcode.SGP, GP.CODE_PROTECTION, 0, 2)  # lifting the read protection erases
    assert bench.interpreter.program() == []
    bench.cmd(Opcode.SGP, GP.CODE_PROTECTION, 0, 0)
    assert bench.cmd(Opcode.ENTER_DOWNLOAD_MODE).status == Status.OK


# -- direct mode and standalone mode together -------------------------------------------------

def test_direct_reads_never_touch_the_program_accumulator() -> None:
    bench = Bench()
    bench.download("""
        CALC LOAD, 42
    Loop:
        COMP 42
        JC NE, Broken
        JA Loop
    Broken:
        SGP 0, 2, 1
        STOP
    """)
    bench.run()
    bench.module.set_analog_input(1, 1234)
    for _ in range(50):
        bench.advance(0.001)
        assert bench.cmd(Opcode.GIO, 1, 1).value == 1234
        assert bench.cmd(Opcode.GAP, 4, 0).value == 51200
        assert bench.cmd(Opcode.GGP, 0, 2).value == 0
        assert bench.cmd(Opcode.JA, 0, 0, 5).status == Status.OK  # acknowledged, no effect
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 2).value == 42
    assert bench.gp(GP.APPLICATION_STATUS) == ApplicationStatus.RUN


def test_direct_accumulator_commands_use_the_program_accumulator() -> None:
    bench = Bench()
    bench.download("CALC LOAD, 777\nSTOP")
    bench.run()
    bench.advance(0.01)
    assert bench.cmd(Opcode.AAP, 5, 2).status == Status.OK
    assert bench.cmd(Opcode.GAP, 5, 2).value == 777
    assert bench.cmd(Opcode.AGP, 9, 2).status == Status.OK
    assert bench.gp(9, 2) == 777
    assert bench.cmd(Opcode.ACO, 3, 1).status == Status.OK
    assert bench.cmd(Opcode.GCO, 3, 1).value == 777
    assert bench.cmd(Opcode.AAP, 3, 0).status == Status.WRONG_TYPE  # actual speed is read-only


def test_direct_calc_calcx_cle_work_on_the_accumulator_direct_aap_reads() -> None:
    """§3.5.5: one accumulator; direct CALC/CALCX/CLE change it as a program's would."""
    bench = Bench()
    reply = bench.cmd(Opcode.CALC, CalcOp.LOAD, 0, 1000)
    assert (reply.status, reply.value) == (Status.OK, 1000)  # the operand echoed (§3.6.14)
    assert bench.cmd(Opcode.CALC, CalcOp.MUL, 0, 3).status == Status.OK
    assert bench.cmd(Opcode.CALCX, CalcOp.LOAD).status == Status.OK  # X = 3000
    assert bench.cmd(Opcode.CALC, CalcOp.SUB, 0, 500).status == Status.OK  # A = 2500
    assert bench.cmd(Opcode.AAP, 4, 1).status == Status.OK
    assert bench.cmd(Opcode.GAP, 4, 1).value == 2500
    assert bench.cmd(Opcode.CALCX, CalcOp.SWAP).status == Status.OK  # A = 3000, X = 2500
    assert bench.cmd(Opcode.AGP, 7, 2).status == Status.OK
    assert bench.gp(7, 2) == 3000
    assert bench.cmd(Opcode.GET_APPLICATION_STATUS, 3).value == 2500  # X
    assert bench.cmd(Opcode.CALC, CalcOp.SWAP, 0, 1).status == Status.WRONG_TYPE  # CALCX only
    assert bench.cmd(Opcode.CALCX, 11).status == Status.WRONG_TYPE
    bench.interpreter.set_error_flag(ErrorFlag.EDV)
    bench.interpreter.set_error_flag(ErrorFlag.ETO)
    assert bench.cmd(Opcode.CLE, ErrorFlag.EDV).status == Status.OK
    assert not bench.interpreter.error_flag(ErrorFlag.EDV)
    assert bench.interpreter.error_flag(ErrorFlag.ETO)
    assert bench.cmd(Opcode.CLE, ErrorFlag.ALL).status == Status.OK
    assert not bench.interpreter.error_flag(ErrorFlag.ETO)
    assert bench.cmd(Opcode.CLE, 6).status == Status.WRONG_TYPE


def test_a_program_that_loops_forever_leaves_time_to_the_host() -> None:
    bench = Bench()
    bench.download("Loop: JA Loop")
    bench.run()
    bench.advance(30)  # returns: the loop runs in batches up to the clock, never past it
    assert bench.interpreter.executed == pytest.approx(30 * S / bench.interpreter.instruction_ns, abs=2)
    assert bench.cmd(Opcode.GAP, 1, 0).status == Status.OK


# -- interrupts from module events ------------------------------------------------------------

class ScriptedAxis:
    """A test double behind the Axis protocol: events happen when the test says so."""

    def __init__(self, index: int) -> None:
        self.index = index
        self.params = {n: spec.default for n, spec in AXIS_PARAMETERS.items()}
        self.script: list[AxisEvent] = []
        self.searching = False

    def schedule(self, time_ns: int, kind: AxisEventKind, active: bool | None = None) -> None:
        self.script.append(AxisEvent(time_ns, self.index, kind, active))
        self.script.sort(key=lambda e: e.time_ns)

    def advance_to(self, t_ns: int) -> list[AxisEvent]:
        due = [e for e in self.script if e.time_ns <= t_ns]
        self.script = self.script[len(due):]
        for event in due:
            if event.kind is AxisEventKind.LEFT_SWITCH:
                self.params[11] = int(bool(event.active))
            elif event.kind is AxisEventKind.RIGHT_SWITCH:
                self.params[10] = int(bool(event.active))
            elif event.kind is AxisEventKind.REFERENCE_SEARCH_DONE:
                self.searching = False
        return due

    def next_event_ns(self) -> int | None:
        return self.script[0].time_ns if self.script else None

    def start_firmware_clock(self, *args: object) -> None:
        """No firmware pass: the test scripts every event."""

    def rotate(self, velocity: int) -> None:
        self.params[2] = velocity

    def stop(self) -> None:
        self.params[2] = 0

    def move_to(self, target: int) -> None:
        self.params[0] = target

    def emergency_stop(self) -> None:
        self.params[2] = 0

    def get_parameter(self, number: int) -> int:
        return self.params[number]

    def set_parameter(self, number: int, value: int) -> None:
        self.params[number] = value

    def reference_search(self, action: int) -> int:
        if action in (0, 1):
            self.searching = action == 0
        return int(self.searching)

    def steady_until(self, number: int) -> int:
        return FOREVER  # a parameter changes only at a scripted event (or a command)


def scripted_bench() -> tuple[Bench, Callable[[int], ScriptedAxis]]:
    module = TMCM6212(axis_factory=ScriptedAxis)

    def axis(n: int) -> ScriptedAxis:
        a = module.axis(n)
        assert isinstance(a, ScriptedAxis)
        module.invalidate_schedule()  # the test is about to script it from outside
        return a

    return Bench(module), axis


COUNTING_HANDLERS = """
    VECT 16, Stall1        // stallGuard axis 1
    VECT 24, Deviation3    // deviation axis 3
    VECT 27, Left0         // left stop switch 0
    VECT 32, Right2        // right stop switch 2
    VECT 41, Input2        // input change 2
    EI 16
    EI 24
    EI 27
    EI 32
    EI 41
    EI 255
Idle:
    JA Idle
Stall1:     GGP 16, 2
            CALC ADD, 1
            AGP 16, 2
            RETI
Deviation3: GGP 24, 2
            CALC ADD, 1
            AGP 24, 2
            RETI
Left0:      GGP 27, 2
            CALC ADD, 1
            AGP 27, 2
            RETI
Right2:     GGP 32, 2
            CALC ADD, 1
            AGP 32, 2
            RETI
Input2:     GGP 41, 2
            CALC ADD, 1
            AGP 41, 2
            RETI
"""


def test_stall_and_deviation_events_raise_their_interrupts() -> None:
    bench, axis = scripted_bench()
    bench.download(COUNTING_HANDLERS)
    bench.run()
    axis(1).schedule(100 * MS, AxisEventKind.STALL)
    axis(1).schedule(300 * MS, AxisEventKind.STALL)
    axis(3).schedule(200 * MS, AxisEventKind.DEVIATION)
    axis(0).schedule(250 * MS, AxisEventKind.STALL)  # no vector for stall 0: ignored
    bench.advance(1)
    assert (bench.gp(16, 2), bench.gp(24, 2)) == (2, 1)
    assert bench.interpreter.error_flag(ErrorFlag.EDV)


def test_stop_switch_interrupts_follow_the_bank_3_trigger_transition() -> None:
    bench, axis = scripted_bench()
    bench.download(COUNTING_HANDLERS)
    bench.run()
    axis(0).schedule(100 * MS, AxisEventKind.LEFT_SWITCH, True)
    bench.advance(0.2)
    assert bench.gp(27, 2) == 0  # trigger transition "off" (the default)
    bench.cmd(Opcode.SGP, 27, 3, 1)  # left 0: low-high
    bench.cmd(Opcode.SGP, 32, 3, 3)  # right 2: both
    for t, active in ((300, False), (400, True), (500, False)):
        axis(0).schedule(t * MS, AxisEventKind.LEFT_SWITCH, active)
        axis(2).schedule(t * MS, AxisEventKind.RIGHT_SWITCH, active)
    bench.advance(1)
    assert bench.gp(27, 2) == 1  # only the rising edge at 400 ms
    assert bench.gp(32, 2) == 3  # every edge


def test_input_change_interrupt() -> None:
    bench, _ = scripted_bench()
    bench.download(COUNTING_HANDLERS)
    bench.cmd(Opcode.SGP, 41, 3, 2)  # input 2: high-low
    bench.run()
    bench.advance(0.01)
    for level in (True, False, True, False):
        bench.module.set_digital_input(2, level)
        bench.advance(0.01)
    assert bench.gp(41, 2) == 2


def test_wait_rfs_and_limit_switch_through_the_module() -> None:
    bench, axis = scripted_bench()
    bench.download("""
        RFS START, 4
        WAIT RFS, 4, 0
        SGP 0, 2, 1
        WAIT LIMSW, 4, 50
        JC ETO, NoSwitch
        SGP 1, 2, 1
        STOP
    NoSwitch:
        SGP 1, 2, 2
        STOP
    """)
    axis(4).schedule(700 * MS, AxisEventKind.REFERENCE_SEARCH_DONE)
    axis(4).schedule(900 * MS, AxisEventKind.RIGHT_SWITCH, True)
    bench.run()
    bench.advance(0.6)
    assert bench.gp(0, 2) == 0
    bench.advance(0.2)
    assert bench.gp(0, 2) == 1
    bench.advance(1)
    assert bench.gp(1, 2) == 1
    assert not bench.interpreter.error_flag(ErrorFlag.ETO)


@pytest.mark.parametrize("core", CORES)
def test_target_reached_interrupt_from_the_motion_axis(core: str) -> None:
    bench = Bench(core=core)
    bench.download("""
        VECT 5, Arrived    // target position reached, axis 2
        EI 5
        EI 255
        MVP ABS, 2, 25600
    Idle: JA Idle
    Arrived:
        GAP 1, 2
        AGP 5, 2
        RETI
    """)
    bench.run()
    bench.advance(3)
    assert bench.gp(5, 2) == 25600
