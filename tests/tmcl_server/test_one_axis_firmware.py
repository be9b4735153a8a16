"""What the one-axis module types do beyond their tables: the TMCM-1111's own parameter
numbering on the TMC4361A core, the sensOstep encoder of the TMCM-1140 generation, GP 131,
and that the tool, the dashboard and the world file follow the profiles (docs/modules.md)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from axes.world import World
from tmcl_server.clock import VirtualClock
from tmcl_server.dispatch import Interface
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCLModule
from tmcl_server.protocol import Reply, Request
from tmcl_server.simulation import Simulation
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import Opcode, Status

#: TMC4361A registers (command 147 reads them on the TMCM-1111).
RAMPMODE, VSTART, VSTOP, VBREAK, AMAX, DMAX, ASTART, DFINAL, DSTOP = (
    0x20, 0x25, 0x26, 0x27, 0x28, 0x29, 0x2A, 0x2B, 0x2C)
BOWS = (0x2D, 0x2E, 0x2F, 0x30)
REFERENCE_CONF = 0x01


class Rig:
    """A module and its simulation, commanded directly (``attach``: a simulator's own)."""

    def __init__(self, kind: str, world: World | None = None) -> None:
        self.module = TMCLModule(kind=kind, world=world)
        self.sim = Simulation([self.module], VirtualClock())

    @classmethod
    def attach(cls, sim: SimulatorThread) -> Rig:
        rig = cls.__new__(cls)
        rig.module, rig.sim = sim.module(), sim.simulation
        return rig

    def cmd(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> Reply:
        (_, reply), = self.sim.execute_on([self.module], Request(1, opcode, type_, motor, value),
                                          Interface.SERIAL)
        assert isinstance(reply, Reply)
        return reply

    def ok(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        reply = self.cmd(opcode, type_, motor, value)
        assert reply.status == Status.OK, (opcode, type_, value, reply)
        return reply.value

    def gap(self, number: int) -> int:
        return self.ok(Opcode.GAP, number)

    def sap(self, number: int, value: int) -> None:
        self.ok(Opcode.SAP, number, 0, value)

    def register(self, address: int) -> int:
        return self.ok(Opcode.READ_MC, address) & 0xFFFF_FFFF

    def move(self, target: int, seconds: float = 10.0) -> float:
        """MVP ABS; the simulated seconds until AP 8 reads 1 (None-safe: at most ``seconds``)."""
        self.ok(Opcode.MVP, 0, 0, target)
        step = 0.01
        for tick in range(round(seconds / step)):
            if self.gap(8):
                return tick * step
            self.sim.advance(step)
        return seconds


# == TMCM-1111: the TMC4361 modules' numbering ================================================


def test_the_tmcm_1111_ramp_parameters_are_the_tmc4361_registers_they_name() -> None:
    rig = Rig("tmcm-1111")
    # power-up (TMCL-LITE-1111): 51200 pps, 51200 pps^2, ASTART = DFINAL = 25600, DSTOP 10000
    assert [rig.register(r) for r in (AMAX, DMAX, ASTART, DFINAL, DSTOP)] == [
        51200 * 4, 51200 * 4, 25600 * 4, 25600 * 4, 10000 * 4]  # 22.2 fixed point
    for number, value in ((15, 100), (16, 3000), (17, 40000), (18, 20000), (19, 5000),
                          (20, 50), (21, 7000), (22, 11), (23, 22), (24, 33), (25, 44)):
        rig.sap(number, value)
    assert [rig.register(r) for r in (VSTART, VBREAK, VSTOP)] == [100 << 8, 20000 << 8, 50 << 8]
    assert [rig.register(r) for r in (ASTART, DMAX, DFINAL, DSTOP)] == [
        3000 * 4, 40000 * 4, 5000 * 4, 7000 * 4]
    assert [rig.register(r) for r in BOWS] == [11, 22, 33, 44]
    # numbers another module uses otherwise changed nothing of theirs: the TMCM-6212's AP 24
    # would have inverted the left switch, its AP 14 swapped the switches
    rig.module.set_switch(0, "left", -1000)
    assert (rig.gap(11), rig.gap(10)) == (0, 0)
    rig.sap(14, 1)  # ramp type: S-shaped
    rig.ok(Opcode.MVP, 0, 0, 1000)
    assert rig.register(RAMPMODE) == 0b110  # positioning, S-shaped profile
    assert (rig.gap(11), rig.gap(10)) == (0, 0)


def test_an_s_shaped_ramp_takes_longer_than_the_trapezoid() -> None:
    trapezoid, s_shaped = Rig("tmcm-1111"), Rig("tmcm-1111")
    for bow in (22, 23, 24, 25):
        s_shaped.sap(bow, 200_000)  # pps^3
    s_shaped.sap(16, 0)  # no start acceleration: the first bow starts from 0
    s_shaped.sap(19, 0)  # no final deceleration: the last bow ends at 0
    s_shaped.sap(14, 1)
    took = [rig.move(102_400) for rig in (trapezoid, s_shaped)]
    assert [rig.gap(1) for rig in (trapezoid, s_shaped)] == [102_400, 102_400]
    # trapezoid: 2 s cruise + 1 s ramps; the bows add a / bow = 0.256 s to each ramp
    assert took[0] == pytest.approx(3.0, abs=0.02)
    assert took[1] == pytest.approx(3.0 + 0.256, abs=0.05)


def test_the_tmcm_1111_limit_switches_are_off_until_enabled_and_can_be_inverted() -> None:
    world = World.from_dict({"axis": [{"index": 0, "right": {"position": 10_000}}]})
    rig = Rig("tmcm-1111", world)
    assert rig.move(20_000) < 10 and rig.gap(1) == 20_000  # power-up: AP 12 = 0, not enabled
    rig.move(0)
    rig.sap(12, 1)  # bit 0: the right switch stops the motor
    rig.move(20_000, seconds=2)
    assert 10_000 <= rig.gap(1) < 11_000 and rig.gap(10) == 1 and rig.gap(8) == 0
    rig.ok(Opcode.MVP, 0, 0, 0)
    rig.sim.advance(2)
    assert rig.gap(10) == 0
    rig.sap(12, 3)  # bit 1: inverted: the open switch reads active
    assert rig.gap(10) == 1 and rig.gap(12) == 3


def test_the_tmcm_1111_virtual_stops_hold_the_motor_short_of_its_target() -> None:
    rig = Rig("tmcm-1111")
    rig.sap(27, 20_000)  # virtual stop right
    rig.sap(28, 2)  # right enabled
    rig.move(51_200, seconds=3)
    assert rig.gap(1) == 20_000 and rig.gap(8) == 0  # a hard stop (mode 0) at the limit
    assert rig.register(REFERENCE_CONF) & 0xC0 == 0x80
    rig.sap(28, 0)
    assert rig.move(51_200) < 10 and rig.gap(1) == 51_200


def test_the_tmcm_1111_answers_in_pps_and_reads_the_encoder_speed() -> None:
    rig = Rig("tmcm-1111")
    assert rig.gap(255) == 1
    rig.ok(Opcode.ROR, 0, 0, 10_000)
    rig.sim.advance(1)
    assert rig.gap(3) == rig.gap(131) == rig.gap(132) == 10_000  # AP 131/132: V_ENC(_MEAN)
    # AP 210 = 4096 lines of a 4096-line encoder: AP 209 in microsteps, 12.5 to a count
    assert abs(rig.gap(209) - rig.gap(1)) < 12.5


def test_the_tmcm_1111_unit_mode_0_is_its_tmc4361s_register_units() -> None:
    """Issue 34, item 8: TMCL-LITE-1111 takes AP 255 = 0 (Commands.c lines 1074-1097) and
    then writes speeds to VMAX and accelerations to AMAX as they are (1/256 pps, 1/4 pps^2:
    ``ConvertInternalToInternal``); GAP 3 reads VACTUAL << 8."""
    rig = Rig("tmcm-1111")
    rig.sap(255, 0)
    rig.sap(5, 100_000 * 4)  # 100,000 pps^2
    rig.ok(Opcode.ROR, 0, 0, 10_000 << 8)  # 10,000 pps
    rig.sim.advance(1)
    assert rig.gap(3) == 10_000 << 8 and rig.register(0x24) & 0xFFFF_FFFF == 10_000 << 8
    assert rig.gap(255) == 0 and rig.gap(5) == 400_000


def test_the_tmcm_1111_refuses_resolutions_while_its_closed_loop_runs() -> None:
    """Issue 34, item 8: a new encoder resolution (AP 210) or motor resolution (AP 202) while
    the closed loop runs answers status 6 (TMCL-LITE-1111 Commands.c lines 993-1008,
    1023-1037); the value it has is taken, and everything goes once AP 129 is 0."""
    rig = Rig("tmcm-1111")
    rig.sap(129, 1)
    for number, value in ((210, 1000), (202, 400)):
        assert rig.cmd(Opcode.SAP, number, 0, value).status == Status.COMMAND_NOT_AVAILABLE
        assert rig.gap(number) != value
        rig.sap(number, rig.gap(number))  # the value it has: accepted
    rig.sap(129, 0)
    rig.sap(210, 1000)
    rig.sap(202, 400)
    assert (rig.gap(210), rig.gap(202)) == (1000, 400)


def test_the_tmcm_1111_powers_up_with_the_lite_firmwares_stallguard_settings() -> None:
    """Issue 34, item 8: filter on, threshold 5 (TMCL-LITE-1111 TMC262.c lines 310-311)."""
    rig = Rig("tmcm-1111")
    assert (rig.gap(173), rig.gap(174)) == (1, 5)


def test_the_tmcm_1111_stops_on_an_encoder_deviation_in_microsteps() -> None:
    world = World.from_dict({"axis": [{"index": 0, "encoder_slip": 0.5}]})
    rig = Rig("tmcm-1111", world)
    rig.sap(212, 1000)  # ENC_POS_DEV_TOL: microsteps
    rig.move(51_200, seconds=3)
    assert rig.ok(Opcode.GAP, 207) == 2  # stopped on the deviation
    assert 2000 <= rig.gap(1) <= 2030  # the encoder saw half: 1000 microsteps behind
    assert rig.gap(1) - rig.gap(209) == pytest.approx(1000, abs=20)


def test_stored_tmcm_1111_parameters_come_back_by_their_own_numbers(tmp_path: Path) -> None:
    state = str(tmp_path / "state")
    for restart in (False, True):
        with SimulatorThread(clock="virtual", module_type="tmcm-1111", tcp=["127.0.0.1:0"],
                             state_dir=state) as sim:
            rig = Rig.attach(sim)  # its commands run on the simulator's loop (sim.call)
            if not restart:
                for number, value in ((15, 300), (22, 4444), (12, 1)):
                    sim.call(rig.sap, number, value)
                    sim.call(rig.ok, Opcode.STAP, number)
            else:
                assert [sim.call(rig.gap, n) for n in (15, 22, 12)] == [300, 4444, 1]
                assert sim.call(rig.register, VSTART) == 300 << 8
                assert sim.call(rig.register, BOWS[0]) == 4444
                assert sim.call(rig.register, REFERENCE_CONF) & 0b10  # stop_right_en


# == the sensOstep encoder (TMCM-1140, 1160, 1161) ===========================================


@pytest.mark.parametrize("kind", ["tmcm-1140", "tmcm-1160", "tmcm-1161"])
def test_the_sensostep_counts_1024_per_turn_in_microsteps(kind: str) -> None:
    rig = Rig(kind)
    assert rig.gap(210) == 25600  # prescaler 50: 1024 counts -> 51200 microsteps
    rig.move(12_345)
    assert rig.gap(209) == 12_300  # whole counts of 50 microsteps
    assert rig.gap(215) == 12_345 // 50  # the rotor angle, one turn
    rig.sap(209, 0)  # AP 209 rezeroed; the absolute angle stays
    assert (rig.gap(209), rig.gap(215)) == (0, 246)
    rig.move(12_345 + 51_200)
    assert rig.gap(215) == 246 and rig.gap(209) == 51_200


def test_acq4s_prescaler_for_16_microsteps_reads_microsteps() -> None:
    """acq4's Thorlabs MFC1 driver sets AP 140 = 4 and AP 210 = 1600 on its TMCM-1140."""
    rig = Rig("tmcm-1140")
    rig.sap(140, 4)
    rig.sap(210, 1600)  # 3.125: 1024 counts -> 3200 microsteps
    rig.sap(209, 0)
    rig.move(3200, seconds=20)
    assert rig.gap(209) == 3200


def test_a_world_file_names_another_encoder() -> None:
    world = World.from_dict({"axis": [{"index": 0, "encoder_resolution": 51200}]})
    rig = Rig("tmcm-1140", world)
    rig.sap(210, 512)  # counts as they are
    rig.move(1000)
    assert rig.gap(209) == 1000


def test_gp_131_holds_the_last_error() -> None:
    rig = Rig("tmcm-1160")
    assert rig.ok(Opcode.GGP, 131, 0) == 0
    assert rig.cmd(Opcode.SAP, 6, 0, 300).status == Status.INVALID_VALUE
    assert rig.ok(Opcode.GGP, 131, 0) == Status.INVALID_VALUE
    assert rig.cmd(Opcode.GAP, 189, 0).status == Status.WRONG_TYPE
    assert rig.ok(Opcode.GGP, 131, 0) == Status.WRONG_TYPE
    assert rig.cmd(Opcode.SGP, 131, 0, 0).status == Status.WRONG_TYPE  # read-only


# == the tool and the dashboard follow the profile ==========================================


@pytest.mark.parametrize(("kind", "can_id"), [("tmcm-1140", 1), ("tmcm-1161", None),
                                               ("tmcm-1111", 1)])
def test_tmcl_info_names_the_module(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                    kind: str, can_id: int | None) -> None:
    with SimulatorThread(clock="virtual", module_type=kind, tcp=["127.0.0.1:0"]) as sim:
        assert tmcl(["--tcp", sim.tcp, "info", "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert (info["type"], info["axes"], info["can_id"]) == (kind.upper(), 1, can_id)


def test_tmcl_dump_lists_the_tmcm_1111_parameters_by_their_own_names(
        capsys: pytest.CaptureFixture[str]) -> None:
    with SimulatorThread(clock="virtual", module_type="tmcm-1111", tcp=["127.0.0.1:0"]) as sim:
        assert tmcl(["--tcp", sim.tcp, "dump", "--json"]) == 0
    dump = json.loads(capsys.readouterr().out)
    axis = dump["axes"]["0"]
    assert dump["type"] == "TMCM-1111"
    assert (axis["RampType"], axis["StartAcceleration"], axis["StopDeceleration"],
            axis["Bow1"], axis["EncoderResolution"]) == (0, 25600, 10000, 0, 4096)
    assert dump["globals"]["0"]["LastTMCLError"] == 0


def test_the_dashboard_shows_the_tmcm_1140_with_its_io_and_sensostep() -> None:
    dashboard = pytest.importorskip("tmcl_server.dashboard.core")
    simulation = Simulation([TMCLModule(1, kind="tmcm-1140")], VirtualClock())
    board = dashboard.Dashboard(simulation)
    module = board.hello()["modules"][0]
    assert (module["type"], module["axes"], module["inputs"], module["outputs"]) == (
        "TMCM-1140", 1, 4, 2)
    names = {row["name"] for row in module["axis_parameters"]}
    assert {"EncoderPrescaler", "AbsoluteResolverValue", "ExternalEncoderPosition"} <= names
    assert "GroupIndex" not in names
    frame = board.frame(dashboard.Viewer("http 127.0.0.1:5000", 1), parameters=True)
    assert frame["parameters"]["axis"]["210"] == [25600]
