"""``--can INTERFACE:CHANNEL``: the simulated bus joined to a python-can bus (its in-process
``virtual`` interface here; socketcan/pcan/slcan adapters work the same way)."""

from __future__ import annotations

import uuid
from collections.abc import Callable

import can
import pytest

from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_can_reply
from tmcl_server.transports.can.python_can import parse_can_spec
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import GP

WAIT_S = 5.0  # a fail-safe for a frame that is due, never a pause to hope in


def request(can_id: int, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> can.Message:
    return can.Message(arbitration_id=can_id, is_extended_id=False,
                       data=Request(can_id, opcode, type_, motor, value).encode_can() + b"\x00")


def receive(bus: can.BusABC) -> can.Message:
    frame = bus.recv(WAIT_S)
    assert frame is not None, "nothing arrived"
    return frame


@pytest.mark.parametrize(("spec", "parsed"), [
    ("socketcan:can0", ("socketcan", "can0", None)),
    ("socketcan:can0:500000", ("socketcan", "can0", 500_000)),
    ("virtual:bus:1", ("virtual", "bus", 1)),
    ("virtual:123", ("virtual", "123", None)),
    ("slcan:/dev/ttyACM0@115200:1000000", ("slcan", "/dev/ttyACM0@115200", 1_000_000)),
    ("pcan:PCAN_USBBUS1", ("pcan", "PCAN_USBBUS1", None)),
])
def test_can_spec(spec: str, parsed: tuple[str, str, int | None]) -> None:
    assert parse_can_spec(spec) == parsed


@pytest.mark.parametrize("spec", ["socketcan", "socketcan:", ":can0"])
def test_bad_can_spec(spec: str) -> None:
    with pytest.raises(ValueError):
        parse_can_spec(spec)


def test_python_can_host_reaches_the_modules_and_the_gateways(
        tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    channel = f"tmcl-sim-{uuid.uuid4()}"
    sim = tmcl_sim_factory(addresses=[1, 3], can=[f"virtual:{channel}"], socketcand=["127.0.0.1:0"])
    host, port = sim.endpoints["socketcand"][0].rsplit(":", 1)
    with (can.Bus(interface="virtual", channel=channel) as local,
          can.Bus(interface="socketcand", host=host, port=int(port), channel="can0") as remote):
        local.send(request(3, Opcode.GGP, GP.CAN_ID))
        reply = receive(local)
        assert reply.arbitration_id == 2 and reply.dlc == 8
        assert decode_can_reply(reply.data).value == 3
        assert [receive(remote).arbitration_id for _ in range(2)] == [3, 2]
        remote.send(request(1, Opcode.GGP, GP.CAN_ID))  # and the other way round
        assert [receive(local).arbitration_id for _ in range(2)] == [1, 2]


def test_two_simulators_share_one_python_can_bus(
        tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    channel = f"tmcl-sim-{uuid.uuid4()}"
    tmcl_sim_factory(addresses=[1], can=[f"virtual:{channel}"])
    tmcl_sim_factory(addresses=[3], can=[f"virtual:{channel}"])
    with can.Bus(interface="virtual", channel=channel) as host:
        for module in (1, 3):
            host.send(request(module, Opcode.GGP, GP.CAN_ID))
            assert decode_can_reply(receive(host).data).value == module
