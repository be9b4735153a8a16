"""The module model through the request router: parameters, statuses, I/O, coordinates, events."""

from __future__ import annotations

import pytest

from tests.conftest import Bench
from tmcl_server.eeprom import Eeprom
from tmcl_server.module import TMCM6212, TMCLModule
from tmcl_server.protocol import RawReply, Reply, Request
from tmcl_spec.commands import MoveType, Opcode, Status
from tmcl_spec.numbers import UINT32_MAX
from tmcl_spec.parameters import GP
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS, BANK_PARAMETERS, TMCM_6212

OK, WRONG_TYPE, INVALID_VALUE, INVALID_COMMAND = 100, 3, 4, 2


def test_version_string_and_binary(bench: Bench):
    routed = bench.simulation.handle_serial_frame(Request(1, 136, 0, 0, 0).encode())
    (_, reply), = routed
    assert isinstance(reply, RawReply)
    assert reply.encode() == bytes([2]) + b"6212V105"
    assert bench.ok(136, 1) == TMCM_6212.version_number == (6212 << 16) | (1 << 8) | 5
    assert bench.status(136, 2) == WRONG_TYPE


def test_unknown_opcode_echoes_value(bench: Bench):
    reply = bench.send(99, 0, 0, 123456)
    assert reply is not None
    assert (reply.status, reply.opcode, reply.value) == (INVALID_COMMAND, 99, 123456)


def test_reply_value_echoes_request_value_for_setters(bench: Bench):
    reply = bench.send(Opcode.SAP, 4, 0, 1000)
    assert reply is not None and (reply.status, reply.value) == (OK, 1000)
    assert (reply.host, reply.module) == (2, 1)


# -- axis parameters over the whole table ---------------------------------------------------

WRITABLE = [s for s in AXIS_PARAMETERS.values()
            if s.writable and s.number not in (0, 1, 2, 209)]


@pytest.mark.parametrize("spec", WRITABLE, ids=lambda s: f"AP{s.number}")
def test_sap_gap_round_trip_at_range_ends(bench: Bench, spec):
    values = sorted(spec.allowed) if spec.allowed else [spec.minimum, spec.maximum]
    for value in (values[0], values[-1]):
        for motor in (0, 5):
            assert bench.ok(Opcode.SAP, spec.number, motor, value) == value
            assert bench.ok(Opcode.GAP, spec.number, motor) == value


@pytest.mark.parametrize("spec", [s for s in WRITABLE if s.allowed is None],
                         ids=lambda s: f"AP{s.number}")
def test_sap_out_of_range_is_refused_and_changes_nothing(bench: Bench, spec):
    before = bench.ok(Opcode.GAP, spec.number, 1)
    for bad in (spec.minimum - 1, spec.maximum + 1):
        if -(2**31) <= bad < 2**31:
            assert bench.status(Opcode.SAP, spec.number, 1, bad) == INVALID_VALUE
    assert bench.ok(Opcode.GAP, spec.number, 1) == before


@pytest.mark.parametrize("spec", [s for s in AXIS_PARAMETERS.values() if not s.writable],
                         ids=lambda s: f"AP{s.number}")
def test_read_only_axis_parameter_refuses_writes(bench: Bench, spec):
    before = bench.ok(Opcode.GAP, spec.number, 2)
    assert bench.status(Opcode.SAP, spec.number, 2, 1) == WRONG_TYPE
    assert bench.ok(Opcode.GAP, spec.number, 2) == before


def test_unknown_axis_parameter_and_bad_motor(bench: Bench):
    assert bench.status(Opcode.GAP, 30, 0) == WRONG_TYPE  # 30 is not in Table 14
    assert bench.status(Opcode.SAP, 250, 0, 1) == WRONG_TYPE
    assert bench.status(Opcode.GAP, 4, 6) == INVALID_VALUE
    assert bench.status(Opcode.ROR, 0, 6, 100) == INVALID_VALUE
    assert bench.status(Opcode.MVP, 3, 0, 100) == WRONG_TYPE


def test_reference_search_mode_allows_documented_variants_only(bench: Bench):
    for mode in (1, 8, 65, 68, 133, 136, 129):
        assert bench.status(Opcode.SAP, 193, 0, mode) == OK
    for mode in (0, 9, 69, 64, 137):
        assert bench.status(Opcode.SAP, 193, 0, mode) == INVALID_VALUE


# -- global parameters ----------------------------------------------------------------------

@pytest.mark.parametrize("spec", [s for s in BANK_PARAMETERS[0].values()
                                  if s.writable and s.number not in (GP.TICK_TIMER,
                                                                     GP.RANDOM_NUMBER,
                                                                     GP.SERIAL_ADDRESS,
                                                                     GP.SUPPRESS_REPLY)],
                         ids=lambda s: f"GP{s.number}")
def test_bank0_round_trip_and_range(bench: Bench, spec):
    for value in (spec.minimum, spec.maximum):
        assert bench.ok(Opcode.SGP, spec.number, 0, value) == value
        assert bench.ok(Opcode.GGP, spec.number, 0) == value
    assert bench.status(Opcode.SGP, spec.number, 0, spec.maximum + 1) == INVALID_VALUE
    assert bench.ok(Opcode.GGP, spec.number, 0) == spec.maximum


def test_read_only_globals_and_bad_banks(bench: Bench):
    for number in (GP.APPLICATION_STATUS, GP.DOWNLOAD_MODE, GP.PROGRAM_COUNTER):
        assert bench.status(Opcode.SGP, number, 0, 1) == WRONG_TYPE
    assert bench.status(Opcode.GGP, 0, 1) == INVALID_VALUE  # bank 1 is not available
    assert bench.status(Opcode.GGP, 7, 4) == INVALID_VALUE
    assert bench.status(Opcode.GGP, 67, 0) == WRONG_TYPE  # 67 is not a bank-0 parameter


def test_bank3_timer_period_takes_full_unsigned_range(bench: Bench):
    assert bench.ok(Opcode.SGP, 0, 3, -1) == -1  # 4294967295 on the wire
    assert bench.module.globals[3][0] == UINT32_MAX
    assert bench.ok(Opcode.GGP, 0, 3) == -1
    assert bench.status(Opcode.SGP, 27, 3, 4) == INVALID_VALUE
    assert bench.ok(Opcode.SGP, 42, 3, 3) == 3
    assert bench.status(Opcode.SGP, 3, 3, 1) == WRONG_TYPE  # no bank-3 parameter 3


def test_user_variables_all_256(bench: Bench):
    for n in (0, 55, 56, 255):
        assert bench.ok(Opcode.SGP, n, 2, -n - 7) == -n - 7
        assert bench.ok(Opcode.GGP, n, 2) == -n - 7


def test_stgp_rsgp_only_for_first_56_user_variables(bench: Bench):
    bench.ok(Opcode.SGP, 42, 2, 1234)
    bench.ok(Opcode.STGP, 42, 2)
    bench.ok(Opcode.SGP, 42, 2, 99)
    bench.ok(Opcode.RSGP, 42, 2)
    assert bench.ok(Opcode.GGP, 42, 2) == 1234
    assert bench.status(Opcode.STGP, 56, 2) == WRONG_TYPE
    assert bench.status(Opcode.RSGP, 200, 2) == WRONG_TYPE
    assert bench.status(Opcode.STGP, 0, 3) == WRONG_TYPE
    assert bench.status(Opcode.STGP, 0, 1) == INVALID_VALUE


def test_tick_timer_counts_simulated_milliseconds_and_can_be_set(bench: Bench):
    start = bench.ok(Opcode.GGP, GP.TICK_TIMER, 0)
    bench.advance(1.5)
    assert bench.ok(Opcode.GGP, GP.TICK_TIMER, 0) == start + 1500
    bench.ok(Opcode.SGP, GP.TICK_TIMER, 0, 1_000_000)
    bench.advance(0.25)
    assert bench.ok(Opcode.GGP, GP.TICK_TIMER, 0) == 1_000_250


def test_random_number_is_seedable(bench: Bench):
    bench.ok(Opcode.SGP, GP.RANDOM_NUMBER, 0, 42)
    first = [bench.ok(Opcode.GGP, GP.RANDOM_NUMBER, 0) for _ in range(5)]
    bench.ok(Opcode.SGP, GP.RANDOM_NUMBER, 0, 42)
    assert [bench.ok(Opcode.GGP, GP.RANDOM_NUMBER, 0) for _ in range(5)] == first
    assert len(set(first)) == 5 and all(0 <= v < 2**31 for v in first)


# -- I/O ------------------------------------------------------------------------------------

def test_outputs_set_and_read_back(bench: Bench):
    for port in range(4):
        assert bench.ok(Opcode.GIO, port, 2) == 0
        bench.ok(Opcode.SIO, port, 2, 1)
        assert bench.ok(Opcode.GIO, port, 2) == 1
    bench.ok(Opcode.SIO, 3, 2, 0)
    assert [bench.ok(Opcode.GIO, p, 2) for p in range(4)] == [1, 1, 1, 0]
    assert bench.status(Opcode.SIO, 0, 2, 2) == INVALID_VALUE
    assert bench.status(Opcode.SIO, 4, 2, 1) == WRONG_TYPE
    assert bench.status(Opcode.SIO, 0, 0, 1) == INVALID_VALUE
    assert bench.status(Opcode.GIO, 0, 3) == INVALID_VALUE


def test_inputs_from_the_simulator_api(bench: Bench):
    bench.module.set_analog_input(0, 302)
    bench.module.set_digital_input(2, True)
    bench.module.set_analog_input(3, 40000)
    assert [bench.ok(Opcode.GIO, p, 1) for p in range(4)] == [302, 0, 65535, 40000]
    assert [bench.ok(Opcode.GIO, p, 0) for p in range(4)] == [0, 0, 1, 1]
    with pytest.raises(ValueError):
        bench.module.set_analog_input(4, 0)
    with pytest.raises(ValueError):
        bench.module.set_analog_input(0, 70000)


def test_input_change_events(bench: Bench):
    events = []
    bench.module.listeners.append(events.append)
    bench.module.set_digital_input(1, True)
    bench.module.set_analog_input(1, 50000)  # still high: no new event
    bench.module.set_digital_input(1, False)
    assert [(e.kind, e.data["port"], e.data["level"]) for e in events] == [
        ("input_changed", 1, 1), ("input_changed", 1, 0)]


# -- coordinates ----------------------------------------------------------------------------

def test_coordinates_set_get_capture_and_move(bench: Bench):
    bench.ok(Opcode.SCO, 1, 0, 1000)
    assert bench.ok(Opcode.GCO, 1, 0) == 1000
    bench.ok(Opcode.MVP, 2, 0, 1)
    bench.advance(5)
    assert bench.ok(Opcode.GAP, 1, 0) == 1000
    assert bench.ok(Opcode.CCO, 7, 0) == 1000
    assert bench.ok(Opcode.GCO, 7, 0) == 1000
    assert bench.status(Opcode.SCO, 21, 0, 5) == WRONG_TYPE
    assert bench.status(Opcode.GCO, 0, 6) == INVALID_VALUE
    assert bench.status(Opcode.MVP, 2, 0, 21) == INVALID_VALUE


def test_coordinate_eeprom_forms(tmp_path):
    module = TMCM6212(1, Eeprom(tmp_path))
    b = Bench(module)
    b.ok(Opcode.SCO, 3, 2, 333)
    b.ok(Opcode.SCO, 4, 2, 444)
    b.ok(Opcode.SCO, 0, 2, 5)  # coordinate 0 is RAM only
    b.ok(Opcode.SCO, 3, 255, 0)  # copy coordinate 3 of every axis to EEPROM
    b.ok(Opcode.SCO, 3, 2, 0)
    b.ok(Opcode.SCO, 4, 2, 0)
    b.ok(Opcode.GCO, 0, 255, 0)  # copy all of 1..20 back from EEPROM
    assert b.ok(Opcode.GCO, 3, 2) == 333
    assert b.ok(Opcode.GCO, 4, 2) == 0  # coordinate 4 was never copied
    assert b.ok(Opcode.GCO, 0, 2) == 5


def test_coordinate_storage_mode_survives_power_cycle(tmp_path):
    b = Bench(TMCM6212(1, Eeprom(tmp_path)))
    b.ok(Opcode.SCO, 5, 1, 555)
    b.ok(Opcode.SCO, 0, 1, 9)
    b.ok(Opcode.SGP, GP.COORDINATE_STORAGE, 0, 1)  # from now on, always stored
    b.ok(Opcode.SCO, 6, 1, 666)
    again = Bench(TMCM6212(1, Eeprom(tmp_path)))
    assert again.ok(Opcode.GCO, 5, 1) == 555
    assert again.ok(Opcode.GCO, 6, 1) == 666
    assert again.ok(Opcode.GCO, 0, 1) == 0  # coordinate 0 is RAM only


def test_coordinates_not_restored_when_ram_only(tmp_path):
    b = Bench(TMCM6212(1, Eeprom(tmp_path)))
    b.ok(Opcode.SCO, 5, 1, 555)
    b.ok(Opcode.SCO, 0, 255, 0)
    again = Bench(TMCM6212(1, Eeprom(tmp_path)))
    assert again.ok(Opcode.GCO, 5, 1) == 0
    again.ok(Opcode.GCO, 5, 255, 0)
    assert again.ok(Opcode.GCO, 5, 1) == 555


# -- motion through the axis interface -------------------------------------------------------

def test_mvp_moves_over_time_not_teleport(bench: Bench):
    bench.ok(Opcode.SAP, 4, 0, 51200)
    bench.ok(Opcode.SAP, 5, 0, 51200)
    bench.ok(Opcode.MVP, 0, 0, 51200)
    assert bench.ok(Opcode.GAP, 8, 0) == 0
    bench.advance(0.5)
    middle = bench.ok(Opcode.GAP, 1, 0)
    assert 0 < middle < 51200
    bench.advance(2.0)
    assert bench.ok(Opcode.GAP, 1, 0) == 51200
    assert bench.ok(Opcode.GAP, 8, 0) == 1


def test_mvp_rel_origin_follows_ap127(bench: Bench):
    bench.ok(Opcode.MVP, 0, 1, 1000)
    bench.advance(1)
    bench.ok(Opcode.MVP, 1, 1, -400)
    bench.advance(1)
    assert bench.ok(Opcode.GAP, 1, 1) == 600


def test_ror_rol_mst(bench: Bench):
    bench.ok(Opcode.ROL, 0, 3, 10000)
    bench.advance(2)
    # AP 3 is the chip's actual velocity converted back: quantised to its register's step
    assert bench.ok(Opcode.GAP, 3, 3) == pytest.approx(-10000, rel=1e-3)
    assert bench.ok(Opcode.GAP, 1, 3) < 0
    bench.ok(Opcode.MST, 0, 3)
    bench.advance(1)
    assert bench.ok(Opcode.GAP, 3, 3) == 0


def test_target_reached_event_once_and_always(bench: Bench):
    assert bench.ok(138, 0, 0, 0b101) == 0b101
    bench.ok(Opcode.MVP, 0, 0, 1000)
    bench.ok(Opcode.MVP, 0, 2, 2000)  # type 0: only the next MVP is reported
    bench.advance(2)
    assert [(r.status, r.opcode, r.value) for r in bench.sink.replies] == [(128, 138, 1)]
    bench.sink.replies.clear()
    bench.ok(138, 1, 0, 0b100)
    for target in (0, 500):
        bench.ok(Opcode.MVP, 0, 2, target)
        bench.advance(2)
    bench.ok(Opcode.MVP, 0, 0, 0)  # motor 0 not in the mask
    bench.advance(2)
    assert [(r.status, r.value) for r in bench.sink.replies] == [(128, 4), (128, 4)]
    assert bench.status(138, 2, 0, 1) == WRONG_TYPE


@pytest.mark.parametrize("core", ["tmc4210", "tmc4361a"])
def test_a_host_that_moves_on_when_ap8_reads_1_gets_every_138_reply(core: str):
    """A TMC4361A enters the target step still braking (XACTUAL = XTARGET, AP 8 = 1, AP 3
    not yet 0): a host (or program) that starts the next move then must still get the
    reply of 138 for the move it saw arrive, as the firmware's target flag shows it."""
    bench = Bench(TMCLModule(kind="tmcm-6212", chip_core=core))
    bench.ok(Opcode.SAP, 4, 0, 50000)
    bench.ok(Opcode.SAP, 5, 0, 40000)
    assert bench.ok(138, 1, 0, 0b1) == 0b1  # every move of motor 0 from now on
    moves = 0
    for target in (100000, 0, 100000, 0):
        bench.ok(Opcode.MVP, 0, 0, target)
        moves += 1
        while bench.ok(Opcode.GAP, 8, 0) != 1:  # poll as a host loop does, 50 µs apart
            bench.advance(0.00005)
        assert bench.ok(Opcode.GAP, 1, 0) == target
    bench.ok(Opcode.MVP, 0, 0, 50000)  # the last one is superseded at once, too
    assert [(r.status, r.opcode, r.value) for r in bench.sink.replies] == [(128, 138, 1)] * moves


@pytest.mark.parametrize("kind,core", [("tmcm-6212", "tmc4210"), ("tmcm-6212", "tmc4361a"),
                                       ("tmcm-6110", None)])
def test_polling_ap8_through_a_move_reads_what_the_chip_brought_up_to_time_reads(
        kind: str, core: str | None, monkeypatch: pytest.MonkeyPatch):
    """AP 8 is answered from the look-ahead while the position is short of the target (no
    run of the chip to every poll): every poll, position and event is what bringing the
    chip up to each poll gives, and the chip runs far less often."""
    from axes.forecast import AxisForecast

    def run(shortcut: bool) -> tuple[list[tuple[int, ...]], list[tuple[int, str]], int]:
        if not shortcut:
            monkeypatch.setattr(AxisForecast, "short_of_target", lambda self: False)
        module = TMCLModule(kind=kind, chip_core=core) if core else TMCLModule(kind=kind)
        bench = Bench(module)
        events: list[tuple[int, str]] = []
        module.listeners.append(lambda e: events.append((e.time_ns, e.kind)))
        runs = 0
        chip = module.axes[0].chip
        original = type(chip).run

        def counting(self, *args, **kwargs):  # type: ignore[no-untyped-def]
            nonlocal runs
            runs += 1
            return original(self, *args, **kwargs)

        monkeypatch.setattr(type(chip), "run", counting)
        polls = []
        for target in (30000, -5000, 12345):
            bench.ok(Opcode.MVP, 0, 0, target)
            for i in range(4000):  # a host polling until the move is done
                bench.advance(0.0013 + (i % 7) * 0.0004)
                polls.append((bench.ok(Opcode.GAP, 8, 0), bench.ok(Opcode.GAP, 8, 0)))
                if polls[-1][0]:
                    break
            polls.append((bench.ok(Opcode.GAP, 1, 0), bench.ok(Opcode.GAP, 3, 0)))
        monkeypatch.undo()
        return polls, events, runs

    fast, slow = run(True), run(False)
    assert fast[:2] == slow[:2]
    assert fast[0].count((1, 1)) == 3 and fast[0].count((0, 0)) > 300
    assert fast[2] * 3 < slow[2], (fast[2], slow[2])

    # the instant AP 8 rises, to 5 µs, found by reading the chip brought up to time ...
    module = TMCLModule(kind=kind, chip_core=core) if core else TMCLModule(kind=kind)
    bench = Bench(module)
    bench.ok(Opcode.MVP, 0, 0, 30000)
    while abs(30000 - bench.ok(Opcode.GAP, 1, 0)) > 100:
        bench.advance(0.001)
    monkeypatch.setattr(AxisForecast, "short_of_target", lambda self: False)
    while bench.ok(Opcode.GAP, 8, 0) == 0:
        bench.advance(0.000005)
    monkeypatch.undo()
    rise = bench.simulation.now_ns
    # ... is where the answer from the look-ahead rises too
    module = TMCLModule(kind=kind, chip_core=core) if core else TMCLModule(kind=kind)
    bench = Bench(module)
    bench.ok(Opcode.MVP, 0, 0, 30000)
    bench.simulation.advance_to_ns(rise - 5000)
    assert bench.ok(Opcode.GAP, 8, 0) == 0
    bench.simulation.advance_to_ns(rise)
    assert bench.ok(Opcode.GAP, 8, 0) == 1


def test_serial_heartbeat_stops_motors(bench: Bench):
    bench.ok(Opcode.SGP, GP.SERIAL_HEARTBEAT, 0, 200)
    bench.ok(Opcode.ROR, 0, 0, 5000)
    bench.advance(0.15)
    bench.ok(Opcode.GAP, 1, 5)  # any command restarts the heartbeat
    bench.advance(0.15)
    assert bench.ok(Opcode.GAP, 3, 0) == pytest.approx(5000, rel=1e-3)
    bench.advance(0.1)
    # the GAP at 0.3 s restarted it
    assert bench.ok(Opcode.GAP, 3, 0) == pytest.approx(5000, rel=1e-3)
    bench.advance(0.21)
    assert bench.module.axis(0).get_parameter(3) == 0


def test_factory_reset(bench: Bench):
    bench.ok(Opcode.SAP, 4, 0, 1234)
    bench.ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 9)
    bench.ok(Opcode.SGP, 7, 2, 77)
    bench.ok(Opcode.STGP, 7, 2)
    assert bench.send(137, 0, 0, 1234) is None  # no reply at all
    assert bench.ok(Opcode.GAP, 4, 0) == AXIS_PARAMETERS[4].default
    assert bench.ok(Opcode.GGP, GP.HOST_ADDRESS, 0) == 2
    assert bench.ok(Opcode.GGP, 7, 2) == 0
    assert bench.status(137, 0, 0, 1) == INVALID_VALUE


def test_suppress_reply_except_reads(bench: Bench):
    # The switch takes effect at once: its own reply is already suppressed.
    assert bench.send(Opcode.SGP, GP.SUPPRESS_REPLY, 0, 1) is None
    assert bench.send(Opcode.SAP, 4, 0, 1000) is None
    assert bench.send(Opcode.GAP, 4, 0).value == 1000
    assert bench.send(Opcode.GGP, GP.SUPPRESS_REPLY, 0).value == 1
    assert bench.send(Opcode.GIO, 0, 2).status == Status.OK
    # ... and so does switching it off: that reply is sent again.
    assert bench.send(Opcode.SGP, GP.SUPPRESS_REPLY, 0, 0).status == Status.OK
    assert bench.send(Opcode.SAP, 4, 0, 1000).status == Status.OK


def test_secondary_address_and_address_change(bench: Bench):
    assert bench.send(Opcode.GAP, 1, 0, address=7) is None
    bench.ok(Opcode.SGP, GP.SERIAL_SECONDARY_ADDRESS, 0, 7)
    reply = bench.send(Opcode.GAP, 1, 0, address=7)
    assert reply is not None and reply.module == 1
    reply = bench.send(Opcode.SGP, GP.SERIAL_ADDRESS, 0, 5, address=1)
    assert reply is not None and reply.module == 5  # the reply already uses the new address
    assert bench.send(Opcode.GAP, 1, 0, address=1) is None
    assert bench.send(Opcode.GAP, 1, 0, address=5).status == Status.OK


def test_checksum_error_for_us_gets_status_1_others_silence(bench: Bench):
    frame = bytearray(Request(1, Opcode.SAP, 4, 0, 999).encode())
    frame[-1] = (frame[-1] + 1) & 0xFF
    (_, reply), = bench.simulation.handle_serial_frame(bytes(frame))
    assert (reply.status, reply.opcode, reply.value) == (1, 0, 0)
    assert bench.ok(Opcode.GAP, 4, 0) != 999  # nothing was executed
    frame[0] = 9
    assert bench.simulation.handle_serial_frame(bytes(frame)) == []


# -- the evaluation system (module type landungsbruecke-tmc4361a) ------------------------------


def test_the_landungsbruecke_answers_with_its_own_command_set() -> None:
    module = TMCLModule(kind="landungsbruecke-tmc4361a")

    def send(opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> Reply:
        reply = module.execute(Request(1, opcode, type_, motor, value))
        assert isinstance(reply, Reply)
        return reply

    assert send(Opcode.MVP, MoveType.REL, 0, 1000).value == 1000  # the absolute target
    assert send(Opcode.MVP, MoveType.COORD, 0, 1).status == Status.INVALID_COMMAND
    assert send(Opcode.GGP, GP.SERIAL_ADDRESS).status == Status.WRONG_TYPE  # kept to itself
    assert send(Opcode.GGP, 2).value == 1  # drivers enabled
    send(64, 0, 0, 0)  # UF0: drivers off
    assert send(Opcode.GGP, 2).value == 0
    assert send(147, 0x10, 0, 55).value == 55  # WRITE_DRV: no driver board, accepted
    assert send(65, 2, 0, 0).value == 0  # no ID EEPROM on channel 2
    assert send(66, 2, 0x12, 0).status == Status.EEPROM_LOCKED
    assert send(66, 1, 0x42, 3).status == Status.OK  # channel 1's EEPROM takes the byte
    assert send(65, 1, 0, 0).value & 0xFF00_0000 == 0x4200_0000
    assert send(Opcode.RFS, 0).status == Status.INVALID_COMMAND
    assert not module.accepts_can(module.can_id)  # the Landungsbruecke has no CAN
    assert TMCLModule(kind="tmcm-6212").accepts_can(1)
