"""Conformance with the firmware manual, through a real TCP socket (issue 14).

Each test names the manual's section it checks; docs/protocol.md and docs/module.md record the
choices where the manual leaves room.
"""

from __future__ import annotations

import pytest

from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_reply
from tmcl_spec.commands import CalcOp, ErrorFlag, MoveType, Opcode, Status
from tmcl_spec.parameters import AP, GP
from tmcl_spec.tmcm6212 import SUPPLY_VOLTAGE_CHANNEL

OK = Status.OK


@pytest.fixture
def sim():
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
        yield sim


@pytest.fixture
def client(sim, raw_client_factory) -> RawClient:
    return raw_client_factory(sim.tcp)


def ok(client: RawClient, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
    reply = client.request(1, opcode, type_, motor, value)
    assert reply.status == OK, reply
    return reply.value


# -- GP 255 (§5.1) ------------------------------------------------------------------------------

def test_gp255_also_silences_the_136_string_and_134(client: RawClient):
    client.send_raw(Request(1, Opcode.SGP, GP.SUPPRESS_REPLY, 0, 1).encode())
    client.expect_silence(0.1)
    for frame in (Request(1, Opcode.GET_FIRMWARE_VERSION, 0, 0, 0),   # the 9-byte string
                  Request(1, Opcode.GET_FIRMWARE_VERSION, 1, 0, 0),
                  Request(1, Opcode.READ_PROGRAM_MEMORY, 0, 0, 0),    # the legacy layout
                  Request(1, Opcode.MVP, MoveType.ABS, 0, 100)):
        client.send_raw(frame.encode())
        client.expect_silence(0.1)
    assert ok(client, Opcode.GGP, GP.SUPPRESS_REPLY) == 1  # GAP, GGP, GIO always answer
    assert ok(client, Opcode.GAP, AP.MAX_SPEED) == 51200
    reply = client.request(1, Opcode.SGP, GP.SUPPRESS_REPLY, 0, 0)  # answered: it is off now
    assert reply.status == OK
    assert client.request(1, Opcode.GET_FIRMWARE_VERSION, 1).status == OK


def test_gp255_also_silences_the_delayed_138_reply(sim, client: RawClient):
    assert ok(client, Opcode.TARGET_REACHED_EVENT, 1, 0, 0b1) == 0b1
    client.send_raw(Request(1, Opcode.SGP, GP.SUPPRESS_REPLY, 0, 1).encode())
    client.send_raw(Request(1, Opcode.MVP, MoveType.ABS, 0, 1000).encode())
    sim.advance(1.0)
    client.expect_silence(0.1)
    assert ok(client, Opcode.GAP, AP.POSITION_REACHED) == 1


# -- UF0..UF7 (§3.6.34) ------------------------------------------------------------------------

@pytest.mark.parametrize("opcode", range(Opcode.UF0, Opcode.UF7 + 1))
def test_user_functions_answer_ok(client: RawClient, opcode: int):
    reply = client.request(1, opcode, 3, 1, -77)
    assert (reply.status, reply.opcode, reply.value) == (OK, opcode, -77)


# -- CALC / CALCX / CLE in direct mode (§3.5.5) --------------------------------------------------

def test_direct_calc_feeds_the_accumulator_that_direct_aap_reads(client: RawClient):
    assert ok(client, Opcode.CALC, CalcOp.LOAD, 0, 20000) == 20000
    ok(client, Opcode.CALCX, CalcOp.LOAD)            # X = 20000
    ok(client, Opcode.CALC, CalcOp.ADD, 0, 5000)     # A = 25000
    ok(client, Opcode.AAP, AP.MAX_SPEED, 2)
    assert ok(client, Opcode.GAP, AP.MAX_SPEED, 2) == 25000
    ok(client, Opcode.CALCX, CalcOp.SUB)             # A = 25000 - 20000
    ok(client, Opcode.ACO, 4, 3)
    assert ok(client, Opcode.GCO, 4, 3) == 5000
    assert ok(client, Opcode.GET_APPLICATION_STATUS, 2) == 5000  # 135 type 2: the accumulator
    assert ok(client, Opcode.CLE, ErrorFlag.ALL) == 0
    assert client.request(1, Opcode.CALC, 10, 0, 1).status == Status.WRONG_TYPE


# -- MVP COORD motor numbers (§3.6.4) ------------------------------------------------------------

def test_mvp_coord_with_a_motor_mask_moves_each_motor_to_its_coordinate(sim, client: RawClient):
    ok(client, Opcode.SCO, 5, 0, 3000)
    ok(client, Opcode.SCO, 5, 2, -4000)
    ok(client, Opcode.SCO, 5, 1, 9999)  # motor 1 is not in the mask
    assert ok(client, Opcode.TARGET_REACHED_EVENT, 0, 0, 0b111) == 0b111
    assert ok(client, Opcode.MVP, MoveType.COORD, 0x80 | 0b101, 5) == 5
    sim.advance(2.0)
    events = [decode_reply(client.recv_exact(9)) for _ in range(2)]
    assert {(e.status, e.opcode) for e in events} == {(Status.TARGET_REACHED_EVENT, 138)}
    assert sorted(e.value for e in events) == [0b001, 0b100]  # one per motor of that one MVP
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 0) == 3000
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 2) == -4000
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 1) == 0
    ok(client, Opcode.MVP, MoveType.COORD, 1, 5)  # type 0 was used up: no further event
    sim.advance(2.0)
    client.expect_silence(0.1)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 1) == 9999


@pytest.mark.parametrize("motor", [6, 0x7F, 0x80, 0xC0])
def test_mvp_coord_motor_numbers_that_name_no_motor_are_refused(client: RawClient, motor: int):
    assert client.request(1, Opcode.MVP, MoveType.COORD, motor, 1).status == Status.INVALID_VALUE


def test_mvp_coord_mask_bits_beyond_the_axes_are_ignored(sim, client: RawClient):
    ok(client, Opcode.SCO, 2, 5, 777)
    assert ok(client, Opcode.MVP, MoveType.COORD, 0xFF & ~0x1F, 2) == 2  # 0xE0: motor 5 only
    sim.advance(1.0)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 5) == 777
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 0) == 0


# -- the supply voltage on GIO 8, 1 --------------------------------------------------------------

def test_supply_voltage_reads_in_tenths_of_a_volt_and_can_be_changed(sim, client: RawClient):
    assert ok(client, Opcode.GIO, SUPPLY_VOLTAGE_CHANNEL, 1) == 240
    sim.call(lambda: sim.module(1).set_supply_voltage(11.3))
    assert ok(client, Opcode.GIO, SUPPLY_VOLTAGE_CHANNEL, 1) == 113
    assert client.request(1, Opcode.GIO, SUPPLY_VOLTAGE_CHANNEL, 0).status == Status.WRONG_TYPE
    assert client.request(1, Opcode.GIO, 4, 1).status == Status.WRONG_TYPE
    with pytest.raises(ValueError, match="supply voltage"):
        sim.call(lambda: sim.module(1).set_supply_voltage(-1))


def test_supply_voltage_from_the_world_file(tmp_path, raw_client_factory):
    world = tmp_path / "low.toml"
    world.write_text("[supply]\nvoltage = 9.5\n")
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], world=str(world)) as sim:
        client = raw_client_factory(sim.tcp)
        assert ok(client, Opcode.GIO, SUPPLY_VOLTAGE_CHANNEL, 1) == 95


# -- stallGuard2 and coolStep (§6.3-6.4, AP 168-174, 180-182, 206) -----------------------------

def set_load(sim: SimulatorThread, axis: int, zones: list[tuple[int, int, int]], free: int) -> None:
    sim.call(lambda: sim.module(1).set_load(axis, zones, free_load=free))


def test_ap206_follows_the_stallguard_threshold(sim, client: RawClient):
    set_load(sim, 0, [], 300)
    assert ok(client, Opcode.GAP, AP.LOAD) == 300
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 0, 5)   # less sensitive: reads higher
    assert ok(client, Opcode.GAP, AP.LOAD) == 300 + 5 * 16
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 0, -20)  # more sensitive: reads 0 here
    assert ok(client, Opcode.GAP, AP.LOAD) == 0
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 0, 63)
    assert ok(client, Opcode.GAP, AP.LOAD) == 1023


def test_a_sensitive_threshold_stalls_where_the_default_does_not(sim, client: RawClient):
    set_load(sim, 1, [(5000, 9000, 40)], 500)
    ok(client, Opcode.SAP, AP.STOP_ON_STALL, 1, 1000)
    ok(client, Opcode.MVP, MoveType.ABS, 1, 20000)
    sim.advance(2.0)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 1) == 20000  # 40 is no stall at AP 174 = 0
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 1, -3)   # 40 - 48 reads 0: a stall
    ok(client, Opcode.MVP, MoveType.ABS, 1, 0)
    sim.advance(2.0)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 1) == 9000  # stopped on entering the zone
    assert ok(client, Opcode.GAP, AP.ERROR_FLAGS, 1) == 1


@pytest.mark.parametrize("threshold", [0, 1, 6, 12, 24, 32])
def test_a_blocked_motor_stalls_at_the_thresholds_users_tune(sim, client: RawClient, threshold):
    """A world load of 0 is a blocked motor: it stalls at AP 174 = 1..24 (and up to 32) as
    at 0, while the same threshold still lets a partial load run (docs/motion.md)."""
    set_load(sim, 4, [(3000, 6000, 150), (8000, 90_000, 0)], 500)
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 4, threshold)
    ok(client, Opcode.SAP, AP.STOP_ON_STALL, 4, 1000)
    ok(client, Opcode.ROR, 0, 4, 51200)
    sim.advance(1.0)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 4) == 8000  # through 150, not into 0
    assert ok(client, Opcode.GAP, AP.ACTUAL_SPEED, 4) == 0
    assert ok(client, Opcode.GAP, AP.ERROR_FLAGS, 4) == 1  # stallGuard stop
    assert ok(client, Opcode.GAP, AP.LOAD, 4) == 0


def test_a_threshold_beyond_reason_misses_even_a_blocked_motor(sim, client: RawClient):
    """The datasheets' tuning rule ("if the motor stalls before SG reaches zero, decrease
    SGT"): a threshold high enough keeps a blocked motor's reading above 0."""
    set_load(sim, 4, [(8000, 90_000, 0)], 500)
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 4, 40)
    ok(client, Opcode.SAP, AP.STOP_ON_STALL, 4, 1000)
    ok(client, Opcode.MVP, MoveType.ABS, 4, 20_000)
    sim.advance(2.0)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 4) == 20_000
    assert ok(client, Opcode.GAP, AP.LOAD, 4) == (40 - 32) * 16
    assert ok(client, Opcode.GAP, AP.ERROR_FLAGS, 4) == 0


def test_the_threshold_still_sets_the_sensitivity_to_partial_loads(sim, client: RawClient):
    set_load(sim, 5, [(3000, 90_000, 150)], 500)
    ok(client, Opcode.SAP, AP.STOP_ON_STALL, 5, 1000)
    for threshold, reading in ((10, 150 + 160), (0, 150), (-9, 6)):
        ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 5, threshold)
        ok(client, Opcode.MVP, MoveType.ABS, 5, 5000)
        sim.advance(1.0)
        assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 5) == 5000, threshold
        assert ok(client, Opcode.GAP, AP.LOAD, 5) == reading
        ok(client, Opcode.MVP, MoveType.ABS, 5, 0)
        sim.advance(1.0)
    ok(client, Opcode.SAP, AP.STALLGUARD_THRESHOLD, 5, -10)  # 150 - 160: a stall at 3000
    ok(client, Opcode.MVP, MoveType.ABS, 5, 5000)
    sim.advance(1.0)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 5) == 3000
    assert ok(client, Opcode.GAP, AP.ERROR_FLAGS, 5) == 1  # stallGuard stop


def test_the_filter_averages_four_full_steps(sim, client: RawClient):
    set_load(sim, 2, [(10_000, 50_000, 100)], 500)
    ok(client, Opcode.SAP, AP.STALLGUARD_FILTER, 2, 1)
    ok(client, Opcode.MVP, MoveType.ABS, 2, 10_000 + 2 * 256)  # two full steps into the zone
    sim.advance(2.0)
    assert ok(client, Opcode.GAP, AP.LOAD, 2) == (100 + 100 + 100 + 500) // 4  # p, p-1, p-2 fs in
    ok(client, Opcode.SAP, AP.STALLGUARD_FILTER, 2, 0)
    assert ok(client, Opcode.GAP, AP.LOAD, 2) == 100


def test_a_filtered_stall_comes_four_full_steps_into_the_obstacle(sim, client: RawClient):
    set_load(sim, 3, [(5000, 90_000, 0)], 500)
    ok(client, Opcode.SAP, AP.STOP_ON_STALL, 3, 1000)
    ok(client, Opcode.SAP, AP.STALLGUARD_FILTER, 3, 1)
    ok(client, Opcode.ROR, 0, 3, 51200)
    sim.advance(1.0)
    stopped_at = ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 3)
    assert ok(client, Opcode.GAP, AP.ACTUAL_SPEED, 3) == 0
    assert ok(client, Opcode.GAP, AP.ERROR_FLAGS, 3) == 1
    first_zero = 5000 + 3 * 256  # the mean of four readings is 0 once the fourth is in the zone
    assert first_zero <= stopped_at <= first_zero + 52  # sampled every 1 ms at 51200 pps


def coolstep(client: RawClient, motor: int, overrides: dict[int, int] | None = None) -> None:
    settings = {AP.MAX_ACCELERATION: 5_120_000,  # at speed within 10 ms
                AP.MAX_CURRENT: 255, AP.SMARTENERGY_HYSTERESIS_START: 1,   # lower threshold 32
                AP.SMARTENERGY_HYSTERESIS: 2,                                # upper (1+2+1)*32
                AP.SMARTENERGY_CURRENT_DOWN_STEP: 3, AP.SMARTENERGY_CURRENT_UP_STEP: 0,
                AP.SMARTENERGY_CURRENT_MINIMUM: 0, **(overrides or {})}
    for number, value in settings.items():
        ok(client, Opcode.SAP, number, motor, value)


def test_coolstep_lowers_the_current_at_light_load_and_raises_it_under_load(sim, client: RawClient):
    set_load(sim, 0, [], 600)  # far above the upper threshold: light load
    coolstep(client, 0)
    # AP 180 is what the firmware's pass read (axes/tasks.py): axis 0's is at 11 ms, 77 ms, ...
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 0  # none yet
    ok(client, Opcode.ROR, 0, 0, 51200)  # 200 full steps (readings) a second
    sim.advance(0.012)  # after the first pass: running, AP 6's scale, one reading taken off
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 30
    sim.advance(0.066)
    assert 15 < ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) < 31  # coming down
    sim.advance(1.0)
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 15  # half of CS (AP 168 = 0)
    status = sim.call(lambda: sim.module(1).axis(0).status())
    assert status.current == 255 * 16 // 32  # the coil current follows
    set_load(sim, 0, [], 10)  # heavy load: below the lower threshold, +1 per reading
    sim.advance(0.066)
    assert 15 < ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) < 31
    sim.advance(0.1)
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 31
    ok(client, Opcode.MST)
    sim.advance(0.5)
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 31  # at rest: nothing measured


def test_coolstep_minimum_threshold_speed_and_off_switch(sim, client: RawClient):
    set_load(sim, 4, [], 600)
    coolstep(client, 4, {AP.SMARTENERGY_CURRENT_MINIMUM: 1})  # down to a quarter
    ok(client, Opcode.ROR, 0, 4, 51200)
    sim.advance(1.5)
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT, 4) == 7
    ok(client, Opcode.SAP, AP.SMARTENERGY_THRESHOLD_SPEED, 4, 60000)  # only above 60000 pps
    sim.advance(0.066)  # axis 4's next pass (one axis every 11 ms, in turn)
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT, 4) == 31
    ok(client, Opcode.SAP, AP.SMARTENERGY_THRESHOLD_SPEED, 4, 0)
    ok(client, Opcode.SAP, AP.SMARTENERGY_HYSTERESIS_START, 4, 0)  # 0 switches coolStep off
    sim.advance(1.0)
    assert ok(client, Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT, 4) == 31


# -- AP 29 measured speed ------------------------------------------------------------------------

def test_measured_speed_reads_the_speed_as_a_magnitude(sim, client: RawClient):
    assert ok(client, Opcode.GAP, AP.MEASURED_SPEED) == 0
    ok(client, Opcode.ROL, 0, 0, 51200)
    sim.advance(1.0)
    actual = ok(client, Opcode.GAP, AP.ACTUAL_SPEED)
    assert actual < 0 and ok(client, Opcode.GAP, AP.MEASURED_SPEED) == -actual > 51000


# -- command 137 restarts the whole module (§3.6.36, docs/protocol.md) ----------------------------

def test_restoring_factory_settings_restarts_the_module(sim, client: RawClient):
    ok(client, Opcode.SAP, AP.MAX_SPEED, 0, 20000)
    ok(client, Opcode.SGP, 9, 2, 99)
    ok(client, Opcode.STGP, 9, 2)
    ok(client, Opcode.SCO, 3, 1, 4444)
    ok(client, Opcode.TARGET_REACHED_EVENT, 1, 0, 0b11)
    ok(client, Opcode.MVP, MoveType.ABS, 0, 1_000_000)
    ok(client, Opcode.ROR, 0, 1, 30000)
    for line in (Request(1, Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0), Request(1, Opcode.CALC, 9, 0, 5),
                 Request(1, Opcode.STOP, 0, 0, 0), Request(1, Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0),
                 Request(1, Opcode.RUN_APPLICATION, 0, 0, 0)):
        client.request(*line)
    sim.advance(0.5)
    assert ok(client, Opcode.GAP, AP.ACTUAL_POSITION, 0) > 0
    client.send_raw(Request(1, Opcode.RESTORE_FACTORY_SETTINGS, 0, 0, 1234).encode())
    client.expect_silence(0.1)  # no reply: the module restarts
    # RAM as after power-on: motion stopped, positions 0, parameters and variables at defaults
    assert [ok(client, Opcode.GAP, AP.ACTUAL_POSITION, m) for m in (0, 1)] == [0, 0]
    assert [ok(client, Opcode.GAP, AP.ACTUAL_SPEED, m) for m in (0, 1)] == [0, 0]
    assert ok(client, Opcode.GAP, AP.MAX_SPEED, 0) == 51200
    assert ok(client, Opcode.GGP, 9, 2) == 0
    assert ok(client, Opcode.GCO, 3, 1) == 0
    # the EEPROM is empty (program included) and the program no longer runs
    assert ok(client, Opcode.GET_APPLICATION_STATUS, 1) >> 24 == 0
    client.send_raw(Request(1, Opcode.READ_PROGRAM_MEMORY, 0, 0, 0).encode())
    assert client.recv_exact(9)[1:8] == bytes(7)  # cell 0: empty (was CALC LOAD, 5)
    ok(client, Opcode.RSGP, 9, 2)
    assert ok(client, Opcode.GGP, 9, 2) == 0
    # the pending 138 request died with the RAM: the next move sends no event
    ok(client, Opcode.MVP, MoveType.ABS, 0, 100)
    sim.advance(1.0)
    client.expect_silence(0.1)


# -- 138 type 0: the next MVP of a motor in the mask (§3.6.35, docs/protocol.md) -----------------

def test_138_type_0_is_not_used_up_by_a_motor_outside_its_mask(sim, client: RawClient):
    ok(client, Opcode.TARGET_REACHED_EVENT, 0, 0, 0b100)
    ok(client, Opcode.MVP, MoveType.ABS, 0, 500)   # motor 0: not asked about
    ok(client, Opcode.MVP, MoveType.ABS, 2, 700)   # the next MVP of motor 2: reported
    sim.advance(1.0)
    event = decode_reply(client.recv_exact(9))
    assert (event.status, event.opcode, event.value) == (Status.TARGET_REACHED_EVENT, 138, 0b100)
    client.expect_silence(0.1)
    ok(client, Opcode.MVP, MoveType.ABS, 2, 0)    # used up: no second event
    sim.advance(1.0)
    client.expect_silence(0.1)


# -- user variables 56..255 are not storable (§5.3 against Table 18, docs/module.md) --------------

def test_only_the_first_56_user_variables_can_be_stored(client: RawClient):
    assert client.request(1, Opcode.STGP, 55, 2).status == OK
    for number in (56, 255):
        assert client.request(1, Opcode.STGP, number, 2).status == Status.WRONG_TYPE
        assert client.request(1, Opcode.RSGP, number, 2).status == Status.WRONG_TYPE


# -- status codes beyond Table 4 (docs/protocol.md) --------------------------------------------------

def test_a_download_past_the_end_of_memory_answers_9_and_stores_nothing(client: RawClient):
    ok(client, Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 6143)
    assert client.request(1, Opcode.MST).status == Status.LOADED
    reply = client.request(1, Opcode.ROR, 0, 0, 5)
    assert (reply.status, reply.opcode) == (Status.MAX_EXCEEDED, Opcode.ROR) == (9, 1)
    ok(client, Opcode.EXIT_DOWNLOAD_MODE)
    ok(client, Opcode.SGP, 81, 0, 2)  # GP 81 bit 1: the program is protected against writing
    assert client.request(1, Opcode.ENTER_DOWNLOAD_MODE).status == Status.WRITE_PROTECTED == 8
