"""The simulated CAN bus and the modules on it, in-process: framing, routing, bad frames, time.

No sockets here: the bus delivers synchronously, so every test is exact and fast.  The
gateways' own tests (test_can_socketcand.py, test_can_slcan.py) drive the same code over
the wire with python-can and pytrinamic.
"""

from __future__ import annotations

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tmcl_server.protocol import Request, decode_can_reply
from tmcl_server.server import ServerConfig, build_simulation
from tmcl_server.simulation import Simulation
from tmcl_server.transports.can.bus import ModuleNode, SimulatedCanBus, open_can_bus
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.parameters import AP, GP
from tmcl_spec.tmcm6212 import TMCM_6212


class Host:
    """A party on the bus that records what it hears (a CAN host, or a sniffer)."""

    def __init__(self, bus: SimulatedCanBus) -> None:
        self.bus = bus
        self.heard: list[can.Message] = []
        bus.attach(self)

    def on_frame(self, frame: can.Message) -> None:
        self.heard.append(frame)

    def send(self, can_id: int, data: bytes, **flags: bool) -> list[can.Message]:
        """Send one frame; return what the bus answered right away."""
        before = len(self.heard)
        self.bus.send(can.Message(arbitration_id=can_id, data=data,
                                  is_extended_id=flags.pop("is_extended_id", False), **flags), self)
        return self.heard[before:]

    def command(self, can_id: int, opcode: int, type_: int = 0, motor: int = 0, value: int = 0,
                length: int = 7) -> list[can.Message]:
        data = Request(can_id, opcode, type_, motor, value).encode_can()
        return self.send(can_id, data + bytes(length - len(data)))


def make_simulation(*addresses: int) -> Simulation:
    return build_simulation(ServerConfig(addresses=list(addresses), clock="virtual"))


def modules_on(bus: SimulatedCanBus) -> ModuleNode:
    assert bus.modules is not None
    return bus.modules


@pytest.fixture
def sim() -> Simulation:
    return make_simulation(1, 3, 5)


@pytest.fixture
def bus(sim: Simulation) -> SimulatedCanBus:
    return open_can_bus(sim)


@pytest.fixture
def host(bus: SimulatedCanBus) -> Host:
    return Host(bus)


def test_request_of_seven_bytes_gets_a_seven_byte_reply_from_gp70(host: Host) -> None:
    (reply,) = host.command(3, Opcode.GAP, AP.MAX_SPEED, 0)
    assert reply.arbitration_id == 2 and not reply.is_extended_id
    assert reply.dlc == 7
    decoded = decode_can_reply(reply.data)
    assert (decoded.module, decoded.status, decoded.opcode) == (3, Status.OK, Opcode.GAP)


def test_request_of_eight_bytes_gets_eight_bytes_padded_with_zero(host: Host) -> None:
    (reply,) = host.command(1, Opcode.SAP, AP.MAX_SPEED, 2, 1234, length=8)
    assert reply.dlc == 8 and reply.data[7] == 0
    assert bytes(reply.data[:7]) == bytes([1, Status.OK, Opcode.SAP]) + (1234).to_bytes(4, "big")
    (read,) = host.command(1, Opcode.GAP, AP.MAX_SPEED, 2, length=8)
    assert decode_can_reply(read.data).value == 1234


@pytest.mark.parametrize("length", [7, 8])
def test_version_string_goes_out_as_its_eight_characters(host: Host, length: int) -> None:
    (reply,) = host.command(5, Opcode.GET_FIRMWARE_VERSION, 0, length=length)
    assert bytes(reply.data) == TMCM_6212.version_string and len(TMCM_6212.version_string) == 8


def test_reply_id_follows_gp70_and_module_byte_the_can_id(host: Host) -> None:
    host.command(5, Opcode.SGP, GP.CAN_REPLY_ID, 0, 0x123)
    (reply,) = host.command(5, Opcode.GGP, GP.CAN_REPLY_ID, 0)
    assert reply.arbitration_id == 0x123 and decode_can_reply(reply.data).value == 0x123
    host.command(5, Opcode.SGP, GP.CAN_ID, 0, 0x305)
    (reply,) = host.command(0x305, Opcode.GGP, GP.CAN_ID, 0)
    assert reply.data[0] == 0x05  # the module's CAN id & 0xFF
    assert host.command(5, Opcode.GGP, GP.CAN_ID, 0) == []  # the old id is gone


def test_duplicate_id_gives_two_replies_as_on_a_real_bus(host: Host) -> None:
    host.command(5, Opcode.SGP, GP.CAN_SECONDARY_ID, 0, 1)
    replies = host.command(1, Opcode.GAP, AP.ACTUAL_POSITION, 0)
    assert sorted(r.data[0] for r in replies) == [1, 5]
    host.command(5, Opcode.SGP, GP.CAN_SECONDARY_ID, 0, 0)
    assert [r.data[0] for r in host.command(1, Opcode.GAP, AP.ACTUAL_POSITION, 0)] == [1]


def test_foreign_ids_get_silence(bus: SimulatedCanBus, host: Host) -> None:
    for can_id in (0, 2, 4, 7, 0x7FF):
        assert host.command(can_id, Opcode.GAP, AP.ACTUAL_POSITION, 0) == []
    assert modules_on(bus).stats["foreign"] == 5


@pytest.mark.parametrize(("frame", "counter"), [
    (dict(can_id=1, data=b"\x06\x01\x00\x00\x00"), "bad_length"),
    (dict(can_id=1, data=b""), "bad_length"),
    (dict(can_id=1, data=bytes(9), is_fd=True), "bad_length"),
    (dict(can_id=1, data=b"", is_remote_frame=True), "remote"),
    (dict(can_id=1, data=b"\x06\x01\x00\x00\x00\x00\x00", is_extended_id=True), "extended"),
    (dict(can_id=1, data=b"\x00", is_error_frame=True), "error_frames"),
])
def test_bad_frames_are_ignored_and_counted(bus: SimulatedCanBus, host: Host, frame: dict,
                                            counter: str) -> None:
    assert host.send(frame.pop("can_id"), frame.pop("data"), **frame) == []
    assert modules_on(bus).stats[counter] == 1
    assert len(host.command(1, Opcode.GAP, AP.ACTUAL_POSITION, 0)) == 1  # still serving


@given(data=st.binary(max_size=8), can_id=st.integers(0, 0x7FF), remote=st.booleans(),
       extended=st.booleans())
def test_no_frame_whatsoever_breaks_the_bus(data: bytes, can_id: int, remote: bool,
                                            extended: bool) -> None:
    bus = open_can_bus(make_simulation(1))
    host = Host(bus)
    host.send(can_id, b"" if remote else data, is_remote_frame=remote, is_extended_id=extended)
    assert modules_on(bus).stats["errors"] == 0
    assert bus.stats["party_errors"] == 0
    (reply,) = host.command(1, Opcode.GGP, GP.CAN_ID, 0)
    assert decode_can_reply(reply.data).value == 1


def test_invalid_command_is_answered_with_its_status(host: Host) -> None:
    (reply,) = host.command(1, 99)
    assert decode_can_reply(reply.data).status == Status.INVALID_COMMAND
    (reply,) = host.command(1, Opcode.GAP, AP.ACTUAL_POSITION, 9)
    assert decode_can_reply(reply.data).status == Status.INVALID_VALUE


def test_every_other_party_hears_every_frame_but_its_own(bus: SimulatedCanBus) -> None:
    alice, bob = Host(bus), Host(bus)
    alice.command(3, Opcode.GAP, AP.ACTUAL_POSITION, 0)
    assert [f.arbitration_id for f in alice.heard] == [2]  # the reply only
    assert [f.arbitration_id for f in bob.heard] == [3, 2]  # alice's request and the reply


def test_modules_do_not_take_each_others_replies_for_requests() -> None:
    sim = make_simulation(1, 2)  # module 2's CAN id equals the default reply id
    host = Host(open_can_bus(sim))
    replies = host.command(1, Opcode.ROR, 0, 0, 1000)  # the reply starts with 01 64 01 ...
    assert [r.data[0] for r in replies] == [1]
    assert sim.module(2).axis(0).get_parameter(AP.ACTUAL_SPEED) == 0
    sim.advance(0.5)
    assert sim.module(2).axis(0).get_parameter(AP.ACTUAL_SPEED) == 0


@pytest.mark.parametrize("length", [7, 8])
def test_target_reached_event_goes_out_on_the_bus(sim: Simulation, host: Host, length: int) -> None:
    host.command(3, Opcode.SGP, GP.CAN_REPLY_ID, 0, 0x40)
    (ack,) = host.command(3, Opcode.TARGET_REACHED_EVENT, 0, 0, 0b10, length=length)
    assert decode_can_reply(ack.data).status == Status.OK
    host.command(3, Opcode.MVP, 0, 1, 2000)
    before = len(host.heard)
    assert sim.advance_until(lambda: len(host.heard) > before, timeout=30)
    (event,) = host.heard[before:]
    assert event.arbitration_id == 0x40 and event.dlc == length
    decoded = decode_can_reply(event.data)
    assert (decoded.module, decoded.status, decoded.opcode, decoded.value) == (
        3, Status.TARGET_REACHED_EVENT, Opcode.TARGET_REACHED_EVENT, 0b10)
    assert sim.module(3).axis(1).get_parameter(AP.ACTUAL_POSITION) == 2000


def test_can_heartbeat_stops_a_moving_axis(sim: Simulation, host: Host) -> None:
    host.command(1, Opcode.SGP, GP.CAN_HEARTBEAT, 0, 100)
    host.command(1, Opcode.ROR, 0, 0, 2000)
    host.command(3, Opcode.ROR, 0, 0, 2000)  # no heartbeat set on module 3
    sim.advance(0.08)
    (speed,) = host.command(1, Opcode.GAP, AP.ACTUAL_SPEED, 0)  # a command: the timer restarts
    assert decode_can_reply(speed.data).value > 0
    sim.advance(0.09)
    assert sim.module(1).axis(0).get_parameter(AP.ACTUAL_SPEED) > 0
    sim.advance(0.5)
    assert sim.module(1).axis(0).get_parameter(AP.ACTUAL_SPEED) == 0
    assert sim.module(3).axis(0).get_parameter(AP.ACTUAL_SPEED) > 0


def test_serial_traffic_does_not_feed_the_can_heartbeat(sim: Simulation, host: Host) -> None:
    host.command(1, Opcode.SGP, GP.CAN_HEARTBEAT, 0, 100)
    host.command(1, Opcode.ROR, 0, 0, 2000)
    for _ in range(10):
        sim.advance(0.03)
        sim.handle_serial_frame(Request(1, Opcode.GAP, AP.ACTUAL_SPEED, 0, 0).encode())
    assert sim.module(1).axis(0).get_parameter(AP.ACTUAL_SPEED) == 0


def test_bus_names_socketcand_can_carry_are_checked() -> None:
    sim = make_simulation(1)
    assert open_can_bus(sim, "line2").name == "line2"
    for bad in ("", "two words", "a<b>", "x" * 17):
        with pytest.raises(ValueError, match="bad CAN bus name"):
            open_can_bus(sim, bad)
