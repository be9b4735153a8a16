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
