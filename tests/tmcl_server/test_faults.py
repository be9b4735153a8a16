"""Faults on purpose (tmcl_server/faults.py): the spec language, the decisions, reproducibility,
the trace, the physical faults and the power cycle, in-process on a virtual clock."""

from __future__ import annotations

import io
import json

import pytest

from interpreter.assembler import assemble
from tests.conftest import Collector
from tmcl_server.clock import VirtualClock
from tmcl_server.eeprom import Eeprom
from tmcl_server.fault_language import (
    FaultSpecError,
    describe_kinds,
    fault_from_mapping,
    fault_spec,
    load_fault_file,
    parse_fault,
)
from tmcl_server.faults import Delivery, FaultInjector
from tmcl_server.module import TMCM6212, TMCLModule
from tmcl_server.protocol import Reply, Request
from tmcl_server.simulation import Simulation
from tmcl_server.trace import Tracer
from tmcl_server.transports.mqtt.fault_topics import apply_fault_message
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.modules import MODULE_TYPES
from tmcl_spec.parameters import AP, GP


class Sink(Collector):
    """A reply sink with a name, like a transport's session."""

    def __init__(self, endpoint: str = "tcp 127.0.0.1:5000") -> None:
        super().__init__()
        self.endpoint = endpoint


class Rig:
    """Modules on a virtual clock, requests through the router as a byte stream sends them."""

    def __init__(self, modules: int = 1, eeprom_dir=None) -> None:
        self.modules = [TMCM6212(slot, Eeprom(eeprom_dir / f"m{slot}" if eeprom_dir else None))
                        for slot in range(1, modules + 1)]
        self.simulation = Simulation(self.modules, VirtualClock())
        self.faults = FaultInjector.of(self.simulation)
        self.sink = Sink()

    def send(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0, address: int = 1,
             sink: Sink | None = None) -> Reply | Delivery | None:
        routed = self.simulation.handle_serial_frame(Request(address, opcode, type_, motor, value).encode(),
                                                     sink or self.sink)
        return routed[0][1] if routed else None  # type: ignore[return-value]

    def gap(self, number: int, motor: int = 0) -> int:
        reply = self.send(Opcode.GAP, number, motor)
        assert isinstance(reply, Reply)
        return reply.value


# -- the spec language ----------------------------------------------------------------------------


def test_a_spec_as_text_as_a_table_and_with_keywords_is_the_same_fault() -> None:
    text = parse_fault("noreply:opcode=GAP|SAP,type=ActualPosition|4,rate=0.25,seed=7,module=2")
    table = fault_from_mapping({"kind": "noreply", "opcode": ["GAP", "SAP"], "type": [1, 4],
                                "rate": 0.25, "seed": 7, "module": 2})
    keywords = fault_spec("noreply:opcode=GAP|SAP", type="1|4", rate=0.25, seed=7, module=2)
    for spec in (text, table, keywords):
        assert spec.kind.name == "noreply"
        assert spec.keys == {"opcode": {Opcode.GAP, Opcode.SAP}, "type": {1, 4}, "rate": 0.25,
                             "seed": 7, "module": {2}}
    assert text.text == "noreply:opcode=GAP|SAP,type=ActualPosition|4,rate=0.25,seed=7,module=2"
    delay = parse_fault("delay:ms=20..80")
    assert delay.params["ms"] == (20.0, 80.0)
    assert parse_fault("switch:axis=2").params == {"axis": 2, "switch": "left", "state": "active"}
    assert parse_fault("Wrong-Address").kind.name == "wrong_address"
    assert parse_fault("status:status=busy".replace("busy", "COMMAND_NOT_AVAILABLE")).params["status"] == 6


@pytest.mark.parametrize(("text", "message"), [
    ("norepy", "did you mean 'noreply'"),
    ("noreply:opcod=GAP", "did you mean 'opcode'"),
    ("noreply:opcode=GAPP", "did you mean GAP"),
    ("noreply:rate=1.5", "rate must be 0..1"),
    ("noreply:rate", "expected KEY=VALUE"),
    ("stuck", "stuck needs axis="),
    ("delay:ms=80..20", "runs backwards"),
    ("switch:axis=0,switch=middle", "switch must be one of"),
    ("status:status=LATE", "status must be a number or one of"),
    ("noreply:type=NoSuchParameter", "type must be a number or a parameter name"),
])
def test_bad_specs_say_what_is_wrong(text: str, message: str) -> None:
    with pytest.raises(FaultSpecError, match=message):
        parse_fault(text)


def test_fault_files_in_toml_json_and_text(tmp_path) -> None:
    toml = tmp_path / "faults.toml"
    toml.write_text('[[fault]]\nkind = "noreply"\nopcode = "GAP"\nrate = 0.1\nseed = 7\n\n'
                    '[[fault]]\nkind = "stuck"\naxis = 1\n')
    as_json = tmp_path / "faults.json"
    as_json.write_text(json.dumps([{"kind": "noreply", "opcode": "GAP", "rate": 0.1, "seed": 7},
                                   {"kind": "stuck", "axis": 1}]))
    text = tmp_path / "faults.txt"
    text.write_text("# one a line\nnoreply:opcode=GAP,rate=0.1,seed=7\n\nstuck:axis=1  # axis 1\n")
    expected = [("noreply", {"opcode": {6}, "rate": 0.1, "seed": 7}), ("stuck", {})]
    for path in (toml, as_json, text):
        assert [(s.kind.name, s.keys) for s in load_fault_file(path)] == expected
    bad = tmp_path / "bad.toml"
    bad.write_text('[[fault]]\nkind = "noreply"\nopcode = "GAP"\nrat = 0.1\n')
    with pytest.raises(FaultSpecError, match=r"bad\.toml.*did you mean 'rate'"):
        load_fault_file(bad)


def test_every_kind_is_described_for_a_front_end() -> None:
    kinds = {k["kind"]: k for k in describe_kinds()}
    assert set(kinds) == {"noreply", "drop", "delay", "checksum", "status", "tear", "garbage",
                          "duplicate", "wrong_address", "reset", "stuck", "switch", "sag"}
    assert {"key": "ms", "help": "milliseconds, or a range LOW..HIGH", "required": False,
            "default": [100.0, 100.0]} in kinds["delay"]["keys"]
    assert [k["key"] for k in kinds["noreply"]["common_keys"]][:3] == ["endpoint", "module", "opcode"]
    json.dumps(kinds)  # JSON-ready as it is


def test_a_fault_for_an_axis_the_module_lacks_is_refused_before_anything_happens() -> None:
    rig = Rig()
    with pytest.raises(FaultSpecError, match=r"axes 0\.\.5"):
        rig.faults.add("stuck:axis=6")
    with pytest.raises(FaultSpecError, match="no module has slot"):
        rig.faults.add("noreply:module=9")
    assert rig.faults.describe() == []


# -- which requests, how often -------------------------------------------------------------------


def struck(rig: Rig, requests: int) -> list[int]:
    """Indices of the GAPs that got no reply."""
    return [i for i in range(requests) if rig.send(Opcode.GAP, 1) is None]


def test_a_rate_and_a_seed_give_the_same_faults_on_every_run() -> None:
    runs = []
    for _ in range(2):
        rig = Rig()
        rig.faults.add("noreply:opcode=GAP,rate=0.3,seed=7")
        runs.append(struck(rig, 300))
    assert runs[0] == runs[1]
    assert 60 <= len(runs[0]) <= 120  # about 30 % of 300
    other = Rig()
    other.faults.add("noreply:opcode=GAP,rate=0.3,seed=8")
    assert struck(other, 300) != runs[0]


def test_count_and_after_pick_which_matching_requests_are_struck() -> None:
    rig = Rig()
    fault = rig.faults.add("noreply:opcode=GAP,after=1,count=2")
    rig.send(Opcode.SAP, 4, 0, 1000)  # does not match: not counted
    assert struck(rig, 5) == [1, 2]
    assert (fault.seen, fault.fired, fault.exhausted) == (3, 2, True)
    assert rig.simulation.faults is None  # nothing watches requests any more: no cost


def test_filters_by_module_motor_type_and_endpoint() -> None:
    rig = Rig(modules=2)
    rig.faults.add("noreply:module=2,motor=3,type=4,endpoint=pty")
    pty, tcp = Sink("pty /tmp/ttyTMCL0"), Sink("tcp 127.0.0.1:4000")
    assert rig.send(Opcode.GAP, 4, 3, address=2, sink=pty) is None
    for type_, motor, address, sink in ((4, 3, 2, tcp), (4, 2, 2, pty), (5, 3, 2, pty), (4, 3, 1, pty)):
        assert rig.send(Opcode.GAP, type_, motor, address=address, sink=sink) is not None
    rig.faults.clear()
    rig.faults.add("noreply:endpoint=pty /tmp/ttyTMCL0")
    assert rig.send(Opcode.GAP, 1, sink=pty) is None
    assert rig.send(Opcode.GAP, 1, sink=Sink("pty /tmp/ttyTMCL1")) is not None


def test_a_dropped_request_never_reaches_the_module_a_lost_reply_does() -> None:
    rig = Rig()
    with_drop = rig.faults.add("drop:opcode=SAP,count=1")
    assert rig.send(Opcode.SAP, 4, 0, 1000) is None
    assert rig.gap(4) != 1000  # never executed
    rig.faults.remove(with_drop)
    rig.faults.add("noreply:opcode=SAP,count=1")
    assert rig.send(Opcode.SAP, 4, 0, 1000) is None
    assert rig.gap(4) == 1000  # executed, only the reply was lost


def test_altered_replies_and_how_a_byte_stream_carries_them() -> None:
    rig = Rig()
    plain = rig.send(Opcode.GAP, 4)
    assert isinstance(plain, Reply)
    frame = plain.encode()
    for spec, check in (
        ("status:status=INVALID_VALUE", lambda d: d.reply.status == Status.INVALID_VALUE),
        ("wrong_address:address=7", lambda d: d.reply.module == 7 and d.frame()[1] == 7),
        ("checksum", lambda d: d.frame()[:8] == frame[:8] and d.frame()[8] == frame[8] ^ 0xFF),
        ("tear:pieces=3,pause_ms=4", lambda d: d.stream_pieces() == [
            (0.0, frame[:3]), (0.004, frame[3:6]), (0.004, frame[6:])]),
        ("garbage:data=aabbcc", lambda d: d.stream_pieces() == [(0.0, b"\xaa\xbb\xcc" + frame)]),
        ("duplicate:copies=2", lambda d: d.stream_pieces() == [(0.0, frame * 3)]),
        ("delay:ms=25", lambda d: d.stream_pieces() == [(0.025, frame)]),
    ):
        fault = rig.faults.add(spec)
        delivery = rig.send(Opcode.GAP, 4)
        assert isinstance(delivery, Delivery) and check(delivery), spec
        rig.faults.remove(fault)
    rig.faults.add("delay:ms=10..20,seed=1")
    rig.faults.add("tear:pieces=2,pause_ms=5")
    rig.faults.add("duplicate")
    both = rig.send(Opcode.GAP, 4)
    assert isinstance(both, Delivery)
    (first, head), (pause, middle), (last_pause, tail) = both.stream_pieces()
    assert 0.010 <= first <= 0.020 and head == frame[:5]
    assert (pause, middle, last_pause, tail) == (0.005, frame[5:] + frame[:5], 0.005, frame[5:])
    assert both.total_delay_s == pytest.approx(first + 0.005)


def test_every_injection_is_in_the_trace_marked_as_injected() -> None:
    rig = Rig()
    text, lines = io.StringIO(), io.StringIO()
    Tracer(text).attach(rig.simulation)
    rig.faults.add("noreply:opcode=GAP,count=1")
    rig.faults.add("drop:opcode=SAP,count=1")
    rig.send(Opcode.GAP, 1)
    rig.send(Opcode.SAP, 4, 0, 5)
    trace = text.getvalue().splitlines()
    assert "cmd     GAP 1 ActualPosition m0 → 100 OK = 0" in trace[0]
    assert "fault   GAP 1 ActualPosition m0: the reply is lost" in trace[1]
    assert "[fault #1 noreply:opcode=GAP,count=1, injected]" in trace[1]
    assert len(trace) == 3 and "fault   SAP 4 MaxPositioningSpeed m0 = 5: the request is lost" in trace[2]
    rig.simulation.tracer = None
    Tracer(lines, "jsonl").attach(rig.simulation)
    rig.faults.add("sag:volts=8.2")
    records = [json.loads(line) for line in lines.getvalue().splitlines()]
    fault = next(r for r in records if r["kind"] == "fault")
    assert fault["injected"] is True and fault["fault"] == "sag" and fault["spec"] == "sag:volts=8.2"
    assert "the supply sags to 8.2 V (was 24 V)" in fault["text"]


# -- the physical faults ---------------------------------------------------------------------------


def test_a_stuck_axis_leaves_its_encoder_behind_until_the_deviation_stops_it() -> None:
    rig = Rig()
    rig.send(Opcode.SAP, AP.MAX_DEVIATION, 0, 1000)  # encoder counts
    rig.send(Opcode.MVP, 0, 0, 20_000)
    rig.simulation.advance(0.3)
    before = rig.gap(AP.ACTUAL_POSITION)
    stuck = rig.faults.add("stuck:axis=0")
    rig.simulation.advance(0.3)
    assert rig.gap(AP.ENCODER_POSITION) == pytest.approx(before, abs=1)
    assert rig.gap(AP.ACTUAL_POSITION) - before > 900  # the motor kept stepping ...
    rig.simulation.advance(2.0)  # ... until the encoder fell more than 1000 counts behind
    deviation = rig.gap(AP.ACTUAL_POSITION) - rig.gap(AP.ENCODER_POSITION)
    assert rig.gap(AP.ACTUAL_SPEED) == 0 and 1000 < deviation <= 1010
    assert rig.gap(AP.ERROR_FLAGS) & 2  # the deviation flag
    rig.faults.remove(stuck)
    encoder, position = rig.gap(AP.ENCODER_POSITION), rig.gap(AP.ACTUAL_POSITION)
    rig.send(Opcode.MVP, 0, 0, position + 500)  # the mechanics follow again
    rig.simulation.advance(1.0)
    assert rig.gap(AP.ENCODER_POSITION) - encoder == 500


def test_a_stuck_axis_moves_no_switch_and_a_blocked_rotor_stalls() -> None:
    rig = Rig()
    rig.modules[0].set_switch(0, "right", 3000)  # active from 3000 up
    rig.faults.add("stuck:axis=0,load=0")
    rig.send(Opcode.MVP, 0, 0, 6000)
    rig.simulation.advance(3.0)
    assert rig.gap(AP.ACTUAL_POSITION) == 6000 and rig.gap(AP.RIGHT_SWITCH) == 0
    assert rig.gap(AP.LOAD) == 0
    rig.faults.clear()
    rig.send(Opcode.SAP, AP.STOP_ON_STALL, 1, 1)
    rig.faults.add("stuck:axis=1,load=0")
    rig.send(Opcode.MVP, 0, 1, 6000)
    rig.simulation.advance(3.0)
    assert rig.gap(AP.ACTUAL_POSITION, 1) < 6000 and rig.gap(AP.ERROR_FLAGS, 1) & 1  # stalled


def test_a_broken_switch_reads_stuck_and_stops_the_motor_like_a_real_one() -> None:
    rig = Rig()
    fault = rig.faults.add("switch:axis=2,switch=left,state=active")
    assert rig.gap(AP.LEFT_SWITCH, 2) == 1
    rig.send(Opcode.ROL, 0, 2, 2000)
    rig.simulation.advance(0.5)
    assert rig.gap(AP.ACTUAL_SPEED, 2) == 0  # the left stop switch holds it
    rig.send(Opcode.MST, 0, 2)
    rig.faults.remove(fault)
    assert rig.gap(AP.LEFT_SWITCH, 2) == 0
    rig.modules[0].set_switch(2, "home", 100, 20)
    rig.faults.add("switch:axis=2,switch=home,state=inactive")
    rig.send(Opcode.MVP, 0, 2, 100)
    rig.simulation.advance(1.0)
    assert rig.gap(AP.ACTUAL_POSITION, 2) == 100 and rig.gap(AP.HOME_SWITCH, 2) == 0


@pytest.mark.parametrize(("kind", "core"), [*((kind, None) for kind in MODULE_TYPES),
                                           ("tmcm-6212", "tmc4361a")])
def test_every_physical_fault_and_the_power_cycle_apply_on_every_core(kind: str, core: str | None) -> None:
    """stuck, switch, sag and reset on each module type's own core (and the TMC4361A one): the
    evaluation board's axis had no set_stuck, break_switch or place_mechanics (AttributeError)."""
    module = TMCLModule(kind=kind, chip_core=core)
    simulation = Simulation([module], VirtualClock())
    faults = FaultInjector.of(simulation)
    module.execute(Request(1, Opcode.ROR, 0, 0, 1000))
    simulation.advance(0.5)
    stuck = faults.add("stuck:axis=0")
    before = module.axis(0).status()
    simulation.advance(0.5)
    after = module.axis(0).status()
    assert after.position != before.position  # the motor keeps stepping ...
    assert after.mechanical_position == before.mechanical_position  # ... the mechanics do not
    faults.remove(stuck)
    simulation.advance(0.1)
    assert module.axis(0).status().mechanical_position != after.mechanical_position
    module.execute(Request(1, Opcode.MST, 0, 0, 0))
    simulation.advance(2.0)
    switch = faults.add("switch:axis=0,switch=left,state=active")
    assert module.axis(0).status().left_switch
    faults.remove(switch)
    assert not module.axis(0).status().left_switch
    faults.remove(faults.add("sag:volts=9"))
    mechanical = module.axis(0).status().mechanical_position
    assert mechanical
    faults.add("reset")  # a power cycle: the counters start again, the mechanics stay
    status = module.axis(0).status()
    assert status.position == 0 and status.mechanical_position == mechanical


def test_a_supply_sag_and_its_end_through_gio() -> None:
    rig = Rig()
    fault = rig.faults.add("sag:volts=9.5")
    assert rig.send(Opcode.GIO, 8, 1).value == 95  # type: ignore[union-attr]
    rig.faults.remove(fault)
    assert rig.send(Opcode.GIO, 8, 1).value == 240  # type: ignore[union-attr]
    assert rig.modules[0].world.supply_voltage is None  # as it was: the nominal supply


def test_a_state_fault_can_wait_for_a_request() -> None:
    rig = Rig()
    rig.faults.add("sag:opcode=MVP,volts=8")
    assert rig.send(Opcode.GIO, 8, 1).value == 240  # type: ignore[union-attr]
    rig.send(Opcode.MVP, 0, 0, 10)
    assert rig.send(Opcode.GIO, 8, 1).value == 80  # type: ignore[union-attr]


# -- the power cycle -------------------------------------------------------------------------------


def test_a_power_cycle_resets_ram_keeps_eeprom_and_restarts_an_autostart_program(tmp_path) -> None:
    rig = Rig(eeprom_dir=tmp_path)
    module = rig.modules[0]
    program = assemble("Loop:\n    CALC ADD, 1\n    WAIT TICKS, 0, 1\n    JA Loop\n")
    rig.send(Opcode.ENTER_DOWNLOAD_MODE)
    for instruction in program.instructions:
        rig.send(*instruction)
    rig.send(Opcode.EXIT_DOWNLOAD_MODE)
    rig.send(Opcode.SGP, GP.AUTO_START, 0, 1)  # stored at once (RWA)
    rig.send(Opcode.MVP, 0, 0, 10_000)
    rig.simulation.advance(3.0)
    rig.send(Opcode.SAP, AP.MAX_SPEED, 0, 1234)
    rig.send(Opcode.STAP, AP.MAX_SPEED, 0)  # in the EEPROM
    rig.send(Opcode.SAP, AP.MAX_ACCELERATION, 0, 4321)  # RAM only
    rig.send(Opcode.SGP, 0, 2, 77)  # a user variable, RAM only
    rig.modules[0].set_switch(0, "left", 9_000)  # active at mechanical 9000 and below
    rig.faults.add("reset:opcode=GAP,count=1")
    assert rig.send(Opcode.GAP, AP.MAX_SPEED) is None  # lost in the restart
    assert rig.gap(AP.MAX_SPEED) == 1234
    assert rig.gap(AP.MAX_ACCELERATION) == module.type.axis_parameters[AP.MAX_ACCELERATION].default
    assert rig.send(Opcode.GGP, 0, 2).value == 0  # type: ignore[union-attr]
    assert rig.gap(AP.ACTUAL_POSITION) == 0  # the counter starts again ...
    assert rig.gap(AP.ENCODER_POSITION) == 0
    assert rig.send(Opcode.GGP, GP.APPLICATION_STATUS, 0).value == 1  # type: ignore[union-attr]
    rig.send(Opcode.MVP, 0, 0, -900)  # ... but the mechanics stayed at 10000
    rig.simulation.advance(2.0)
    assert rig.gap(AP.LEFT_SWITCH) == 0  # mechanical 9100: not yet at the switch
    rig.send(Opcode.MVP, 0, 0, -1100)
    rig.simulation.advance(2.0)
    assert rig.gap(AP.LEFT_SWITCH) == 1


def test_a_reset_without_a_request_key_happens_at_once_and_is_not_kept() -> None:
    rig = Rig()
    rig.send(Opcode.SAP, AP.MAX_SPEED, 0, 1234)
    events = []
    rig.modules[0].listeners.append(lambda e: events.append(e.kind))
    fault = rig.faults.add("reset")
    assert events == ["power_cycle"] and rig.faults.describe() == [] and fault.fired == 1
    assert rig.gap(AP.MAX_SPEED) != 1234


def test_sim_fault_messages_install_list_and_remove_faults() -> None:
    rig = Rig(modules=2)
    module = rig.modules[1]
    apply_fault_message(rig.faults, module, ["fault"], b"noreply:opcode=GAP")
    apply_fault_message(rig.faults, module, ["fault"], b'{"kind": "delay", "ms": 50}')
    specs = [f["spec"] for f in rig.faults.describe()]
    assert specs == ["noreply:opcode=GAP,module=2", "delay:module=2,ms=50"]
    assert rig.send(Opcode.GAP, 1, address=2) is None and rig.send(Opcode.GAP, 1, address=1) is not None
    apply_fault_message(rig.faults, module, ["fault", "remove"], b"1")
    assert [f["id"] for f in rig.faults.describe()] == [2]
    apply_fault_message(rig.faults, module, ["fault"], b"clear")
    assert rig.faults.describe() == []
    rig.send(Opcode.SAP, AP.MAX_SPEED, 0, 1234, address=2)
    apply_fault_message(rig.faults, module, ["power_cycle"], b"")
    assert rig.send(Opcode.GAP, AP.MAX_SPEED, 0, address=2).value != 1234  # type: ignore[union-attr]
    with pytest.raises(FaultSpecError, match="takes a fault id"):
        apply_fault_message(rig.faults, module, ["fault", "remove"], b"x")
    with pytest.raises(FaultSpecError, match="unknown fault"):
        apply_fault_message(rig.faults, module, ["fault"], b"nothing")


def test_the_command_line_reads_faults_and_wire_timing(tmp_path) -> None:
    from tmcl_server.cli import build_parser, config_from_args

    (tmp_path / "f.toml").write_text('[[fault]]\nkind = "sag"\nvolts = 9.5\n')
    args = build_parser().parse_args(["--fault", "noreply:opcode=GAP", "--faults", str(tmp_path / "f.toml"),
                                      "--wire-timing", "--processing-time", "0.001"])
    config = config_from_args(args)
    assert [f.text for f in config.faults] == ["sag:volts=9.5", "noreply:opcode=GAP"]
    assert config.wire_timing and config.processing_time == 0.001
    with pytest.raises(SystemExit, match="argument --fault noreplyy: unknown fault 'noreplyy'"):
        config_from_args(build_parser().parse_args(["--fault", "noreplyy"]))
