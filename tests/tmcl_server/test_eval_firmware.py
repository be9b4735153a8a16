"""The TMC4361A evaluation board against Trinamic's open evaluation firmware (TMC-EvalSystem
3.11.7, ``tmc/TMCL.c``, ``boards/TMC4361A_eval.c``): GIO/SIO, command 144 (the TMCL-IDE's
switch simulation, the closed-loop calibration, the boards' reset), 136 and 157, and the motor
byte of GAP/SAP, ROR/ROL/MST/MVP and 146/148 — through a real TCP socket and through
pytrinamic's own ``Landungsbruecke`` / ``TMC4361_eval`` classes over a pty, on the virtual
clock.  docs/tmc4361a.md ("The evaluation board") records every answer and its source.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.evalboards import TMC4361_eval
from pytrinamic.ic import TMC4361
from pytrinamic.modules import Landungsbruecke
from pytrinamic.tmcl import TMCLReplyStatusError

from axes.chips.tmc4361a.registers import Event, RefConf
from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import MoveType, Opcode, Status

REG = TMC4361.REG
UF_CH1 = 144
GET_INFO = 157
READ_MC = 148
STATUS_STOPL, STATUS_STOPR = 1 << 7, 1 << 8  # STATUS STOPL_ACTIVE_F, STOPR_ACTIVE_F


@pytest.fixture
def sim(tmp_path) -> Iterator[SimulatorThread]:
    with SimulatorThread(clock="virtual", module_type="landungsbruecke-tmc4361a",
                         tcp=["127.0.0.1:0"], pty=[str(tmp_path / "ttyACM0")]) as sim:
        yield sim


@pytest.fixture
def client(sim, raw_client_factory) -> RawClient:
    return raw_client_factory(sim.tcp)


def answer(client: RawClient, opcode: int, type_: int = 0, motor: int = 0,
           value: int = 0) -> tuple[int, int]:
    reply = client.request(1, opcode, type_, motor, value)
    assert reply.opcode == opcode and reply.module == 1
    return reply.status, reply.value


def ok(client: RawClient, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
    status, result = answer(client, opcode, type_, motor, value)
    assert status == Status.OK, (opcode, type_, motor, value, status)
    return result


def register(client: RawClient, address: int) -> int:
    return ok(client, READ_MC, address) & 0xFFFF_FFFF


def clear_events(client: RawClient) -> None:
    register(client, REG.EVENTS)  # clear on read: a latched stop event blocks its direction


# == GIO / SIO ====================================================================================

def test_gio_answers_the_landungsbrueckes_adc_readings_on_any_bank(sim, client) -> None:
    sim.call(lambda: sim.module().set_analog_input(1, 1234))
    for bank in (0, 1, 2, 7, 255):  # the firmware switches on the type only
        assert ok(client, Opcode.GIO, 1, bank) == 1234  # AIN1
        assert ok(client, Opcode.GIO, 5, bank) == 240  # VM: 24.0 V in 0.1 V
        assert ok(client, Opcode.GIO, 0, bank) == 0
    raw = ok(client, Opcode.GIO, 6, 0)  # the VM divider's raw 16-bit ADC count
    assert raw * 713 // 65535 == 240
    assert [ok(client, Opcode.GIO, t, 1) for t in (2, 3, 4, 7)] == [0, 0, 0, 0]
    assert answer(client, Opcode.GIO, 8, 1, 99) == (Status.WRONG_TYPE, 99)
    sim.call(lambda: sim.module().set_supply_voltage(12.3))
    assert ok(client, Opcode.GIO, 5, 0) == 123
    sim.call(lambda: sim.module().set_supply_voltage(80.0))  # beyond the ADC's 71.3 V
    assert (ok(client, Opcode.GIO, 5, 0), ok(client, Opcode.GIO, 6, 0)) == (713, 65535)


def test_sio_is_accepted_and_changes_nothing(client) -> None:
    before = [register(client, a) for a in (REG.REFERENCE_CONF, REG.RAMPMODE, REG.STATUS)]
    for type_, bank, value in ((0, 2, 1), (5, 0, 0), (255, 255, -1)):
        assert answer(client, Opcode.SIO, type_, bank, value) == (Status.OK, value)
    assert [register(client, a) for a in (REG.REFERENCE_CONF, REG.RAMPMODE, REG.STATUS)] == before


# == command 144: the TMCL-IDE's switch simulation, calibration, reset =====================

def test_144_drives_the_stop_switch_inputs_of_the_chip(sim, client) -> None:
    ok(client, Opcode.WRITE_MC, REG.REFERENCE_CONF, 0, RefConf.STOP_LEFT_EN | RefConf.STOP_RIGHT_EN)
    assert register(client, REG.STATUS) & (STATUS_STOPL | STATUS_STOPR) == 0  # driven high
    assert answer(client, UF_CH1, 0, 0, 0b01) == (Status.OK, 0b01)  # STOP_L low, STOP_R released
    assert register(client, REG.STATUS) & (STATUS_STOPL | STATUS_STOPR) == STATUS_STOPL
    ok(client, Opcode.ROL, 0, 0, 20_000)
    sim.advance(0.2)
    assert ok(client, Opcode.GAP, 1) == 0  # the left stop holds the motor
    ok(client, Opcode.ROR, 0, 0, 20_000)
    sim.advance(0.2)
    assert ok(client, Opcode.GAP, 1) > 0  # the other direction is free
    assert answer(client, UF_CH1, 0, 7, 0b10) == (Status.OK, 0b10)  # any motor byte
    assert register(client, REG.STATUS) & (STATUS_STOPL | STATUS_STOPR) == STATUS_STOPR
    sim.advance(0.2)
    assert ok(client, Opcode.GAP, 3) == 0  # stopped by the right switch
    ok(client, UF_CH1, 0, 0, 0b1011)  # other bits set: nothing happens
    assert register(client, REG.STATUS) & (STATUS_STOPL | STATUS_STOPR) == STATUS_STOPR
    ok(client, UF_CH1, 0, 0, 0b11)  # both released
    assert register(client, REG.STATUS) & (STATUS_STOPL | STATUS_STOPR) == 0


def test_144_keeps_the_worlds_switches_working(tmp_path, raw_client_factory) -> None:
    """A released line follows an external switch, as the firmware's comment has it."""
    world = tmp_path / "world.toml"
    world.write_text("[[axis]]\nindex = 0\nright = { position = 1000 }\n")
    with SimulatorThread(clock="virtual", module_type="landungsbruecke-tmc4361a",
                         tcp=["127.0.0.1:0"], world=str(world)) as sim:
        client = raw_client_factory(sim.tcp)
        ok(client, Opcode.WRITE_MC, REG.REFERENCE_CONF, 0, RefConf.STOP_RIGHT_EN)
        ok(client, UF_CH1, 0, 0, 0b11)
        ok(client, Opcode.ROR, 0, 0, 20_000)
        sim.advance(0.5)
        assert ok(client, Opcode.GAP, 1) == 1000  # the world's switch stopped it
        assert register(client, REG.STATUS) & STATUS_STOPR


def test_144_drives_home_ref_and_freeze(sim, client) -> None:
    # HOME_REF: a falling edge latches X_HOME (home event 12: low on the negative side)
    ok(client, Opcode.WRITE_MC, REG.REFERENCE_CONF, 0, 12 << 16 | RefConf.START_HOME_TRACKING)
    ok(client, Opcode.WRITE_MC, REG.XACTUAL, 0, 4321)
    clear_events(client)
    assert answer(client, UF_CH1, 1, 0, 0) == (Status.OK, 0)  # HOME_REF driven low
    assert register(client, REG.EVENTS) & Event.XLATCH_DONE
    assert register(client, REG.X_HOME) == 4321
    ok(client, UF_CH1, 1, 0, 1)
    # FREEZE: a falling edge freezes the chip (DFREEZE 0 after the firmware's reset: at once)
    ok(client, Opcode.ROR, 0, 0, 20_000)
    sim.advance(0.2)
    assert ok(client, Opcode.GAP, 3) != 0
    assert answer(client, UF_CH1, 2, 0, 0) == (Status.OK, 0)
    assert ok(client, Opcode.GAP, 3) == 0
    frozen_at = ok(client, Opcode.GAP, 1)
    assert register(client, REG.EVENTS) & Event.FROZEN
    assert register(client, REG.EVENTS) & Event.FROZEN  # stays until the chip is reset
    ok(client, UF_CH1, 2, 0, 1)  # releasing the line does not unfreeze
    ok(client, Opcode.ROL, 0, 0, 20_000)
    sim.advance(0.2)
    assert ok(client, Opcode.GAP, 1) == frozen_at
    assert answer(client, UF_CH1, 255, 0, 42) == (Status.OK, 42)  # the boards' reset: NRST
    assert register(client, REG.RAMPMODE) == 1  # the firmware's configuration again
    ok(client, Opcode.ROL, 0, 0, 20_000)
    sim.advance(0.2)
    assert ok(client, Opcode.GAP, 1) < frozen_at


def test_144_calibration_answers_delayed_and_runs_to_the_next_full_step(sim, client) -> None:
    ok(client, Opcode.MVP, MoveType.ABS, 0, 200)
    sim.advance(0.5)
    assert (ok(client, Opcode.GAP, 1), register(client, REG.MSCNT)) == (200, 200)
    assert answer(client, UF_CH1, 3, 0, 55) == (Status.DELAYED, 0)  # running
    sim.advance(0.1)  # the periodic job, once per millisecond
    assert (ok(client, Opcode.GAP, 1), register(client, REG.MSCNT) % 256) == (128, 128)
    assert register(client, REG.RAMPMODE) == 0b100 | 1  # positioning | the ramp it found
    assert register(client, REG.ENC_IN_CONF) >> 22 & 0b111 == 0b001  # regulation mode 1, cal off
    assert answer(client, UF_CH1, 3, 0, 0) == (Status.DELAYED, 0)  # a new one starts


def test_144_unknown_types_answer_3_and_145_has_no_board(client) -> None:
    assert answer(client, UF_CH1, 4, 0, 77) == (Status.WRONG_TYPE, 77)
    assert answer(client, 145, 0, 0, 5)[0] == Status.INVALID_COMMAND  # no driver board


# == 136 and GetInfo ==============================================================================

def test_136_and_157_answer_as_the_firmware(client) -> None:
    assert ok(client, Opcode.GET_FIRMWARE_VERSION, 1) == 0x000C_030B
    assert ok(client, Opcode.GET_FIRMWARE_VERSION, 4, 0, 0x1234_5678) == 0x1234_0002  # EEPROM
    assert ok(client, Opcode.GET_FIRMWARE_VERSION, 5) == 3117
    assert ok(client, Opcode.GET_FIRMWARE_VERSION, 6) == 1  # motors: 1 + 0
    for type_ in (2, 3, 7, 200):
        assert answer(client, Opcode.GET_FIRMWARE_VERSION, type_, 0, 99) == (Status.OK, 99)
    info = {t: ok(client, GET_INFO, t, 3) for t in (0, 1, 2, 3, 20, 21, 30, 200, 201, 202)}
    assert info == {0: 12, 1: 0x0003_000B, 2: 0x2, 3: 0, 20: 8, 21: 12, 30: 0x0922_0279,
                    200: 7, 201: 0x000B_0000, 202: 0x0103_FFFF}
    assert ok(client, GET_INFO, 1, 0, 0x1122_3344) == 0x1103_330B  # bytes 3 and 1 kept
    assert answer(client, GET_INFO, 4, 0, 9) == (Status.WRONG_TYPE, 9)


# == the motor byte ===============================================================================

def test_gap_sap_on_another_motor_answer_3(client) -> None:
    for motor in (1, 2, 255):
        assert answer(client, Opcode.GAP, 1, motor, 5) == (Status.WRONG_TYPE, 5)
        assert answer(client, Opcode.SAP, 4, motor, 5) == (Status.WRONG_TYPE, 5)
        assert answer(client, Opcode.GAP, 99, motor)[0] == Status.WRONG_TYPE  # motor first
    assert answer(client, Opcode.GAP, 99, 0)[0] == Status.INVALID_COMMAND  # motor 0: type


def test_motion_commands_on_any_motor_move_motor_0(sim, client) -> None:
    assert answer(client, Opcode.ROR, 0, 1, 20_000) == (Status.OK, 20_000)
    sim.advance(1.5)  # AMAX 20 000 pps² after the firmware's reset
    assert ok(client, Opcode.GAP, 3) == 20_000
    assert answer(client, Opcode.MST, 0, 5, 0)[0] == Status.OK
    sim.advance(1.5)
    assert ok(client, Opcode.GAP, 3) == 0
    assert answer(client, Opcode.ROL, 0, 255, 1000)[0] == Status.OK
    sim.advance(0.1)
    assert ok(client, Opcode.GAP, 3) < 0
    ok(client, Opcode.MST, 0, 0)
    sim.advance(1.0)
    start = ok(client, Opcode.GAP, 1)
    assert answer(client, Opcode.MVP, MoveType.REL, 3, 1000) == (Status.OK, start + 1000)
    sim.advance(2.0)
    assert ok(client, Opcode.GAP, 1) == start + 1000
    assert answer(client, Opcode.MVP, MoveType.ABS, 1, -500)[0] == Status.OK
    sim.advance(5.0)
    assert ok(client, Opcode.GAP, 1) == -500
    assert answer(client, Opcode.MVP, MoveType.COORD, 1, 0)[0] == Status.INVALID_COMMAND
    assert answer(client, Opcode.MVP, 3, 1, 0)[0] == Status.WRONG_TYPE


def test_146_148_drop_the_motor_byte(client) -> None:
    assert answer(client, Opcode.WRITE_MC, REG.XTARGET, 3, 777) == (Status.OK, 777)
    assert register(client, REG.XTARGET) == 777
    assert ok(client, READ_MC, REG.XTARGET, 0x17) == 777  # low nibble motor, high nibble cut
    assert ok(client, READ_MC, REG.XTARGET | 0x80, 0) == 777  # the SPI sees 7 address bits
    ok(client, Opcode.WRITE_MC, REG.XTARGET | 0x80, 2, 888)
    assert register(client, REG.XTARGET) == 888


# == pytrinamic ===================================================================================

def test_pytrinamic_reads_the_boards_inputs_and_info_and_drives_the_switches(sim) -> None:
    with ConnectionManager(f"--interface serial_tmcl --port {sim.pty} --data-rate 115200"
                           ).connect() as iface:
        lb = Landungsbruecke(iface)
        board = TMC4361_eval(iface)
        assert lb.detect_board_ids() == (11, 0)
        assert iface.get_analog_input(5) == 240
        assert iface.get_info("FWModuleID").value == 12
        version = iface.get_info("FWVersion")
        assert (version.major, version.minor) == (3, 11)
        assert iface.get_info("RegAddrBitWidth").value == 12
        board.write_register(REG.REFERENCE_CONF, RefConf.STOP_LEFT_EN)
        iface.send(UF_CH1, 0, 0, 0b01)  # the IDE's "left switch" button
        assert board.read_register(REG.STATUS) & STATUS_STOPL
        board.rotate(0, -20_000)
        sim.advance(0.2)
        assert board.motors[0].actual_position == 0
        with pytest.raises(TMCLReplyStatusError) as refused:
            iface.get_axis_parameter(1, 1)  # a second motor: the firmware's 3
        assert refused.value.reply.status == Status.WRONG_TYPE


# == the tmcl tool ================================================================================

def test_the_tmcl_tool_sends_the_boards_commands(sim, capsys) -> None:
    def run(*argv: str) -> tuple[int, str]:
        code = tmcl(["--tcp", sim.tcp, "--module-type", "landungsbruecke-tmc4361a", *argv])
        return code, capsys.readouterr().out

    assert run("send", "GIO", "5", "0") == (0, "GIO 5 b0 → 100 OK = 240\n")
    assert run("send", "157", "0", "0", "--value") == (0, "12\n")
    assert run("send", "GET_FIRMWARE_VERSION", "5", "--value") == (0, "3117\n")
    assert run("send", "146", str(REG.REFERENCE_CONF), "0", str(int(RefConf.STOP_LEFT_EN)))[0] == 0
    assert run("send", "144", "0", "0", "1")[0] == 0  # the left switch, pressed
    assert int(run("send", "148", str(REG.STATUS), "--value")[1]) & STATUS_STOPL
    code, out = run("send", "144", "3", "0")
    assert "128 DELAYED = 0" in out
    code, out = run("send", "GAP", "1", "1")
    assert code != 0 and "3 WRONG_TYPE" in out
