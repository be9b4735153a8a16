"""pytrinamic, unchanged, drives the emulated axes over TCP on a virtual clock."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.modules import TMCM6212

from tmcl_server.embed import SimulatorThread

WORLD = Path(__file__).resolve().parents[2] / "docs" / "world-example.toml"


@pytest.fixture
def sim() -> Iterator[SimulatorThread]:
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], world=str(WORLD)) as simulator:
        yield simulator


@pytest.fixture
def module(sim: SimulatorThread) -> Iterator[TMCM6212]:
    manager = ConnectionManager(f"--interface socket_serial_tmcl --port {sim.tcp}")
    with manager.connect() as interface:
        yield TMCM6212(interface)


def test_move_to_poll_position_reached_read_position(sim: SimulatorThread, module: TMCM6212) -> None:
    motor = module.motors[0]
    motor.linear_ramp.max_velocity = 102_400  # (pytrinamic's own demo sets motor.max_velocity,
    motor.linear_ramp.max_acceleration = 204_800  # which is a plain attribute: nothing is sent)
    assert motor.linear_ramp.max_velocity == 102_400
    module.move_to(0, 100_000)
    polls = 0
    while not motor.get_position_reached():
        sim.advance(0.1)
        polls += 1
        assert polls < 100
    assert motor.actual_position == 100_000
    assert 14 <= polls <= 16  # 100 000 steps at 102 400 pps with 0.5 s ramps: about 1.5 s
    assert motor.actual_velocity == 0


def test_rotate_stop_sequence_like_rotate_demo(sim: SimulatorThread, module: TMCM6212) -> None:
    motors = [module.motors[i] for i in (2, 3, 5)]  # rotate_demo uses 0; 0 has switches here
    for motor, (acceleration, velocity) in zip(
            motors, ((51200, 51200), (25600, 25600), (102400, 51200)), strict=True):
        motor.drive_settings.max_current = 128
        motor.drive_settings.standby_current = 0
        motor.linear_ramp.max_acceleration = acceleration
        motor.linear_ramp.max_velocity = velocity
        motor.actual_position = 0
    motors[0].rotate(51200)
    motors[1].rotate(-25600)
    motors[2].rotate(102400)
    sim.advance(5)
    speeds = [m.actual_velocity for m in motors]
    assert speeds[0] == pytest.approx(51200, rel=0.001)
    assert speeds[1] == pytest.approx(-25600, rel=0.001)
    assert speeds[2] == pytest.approx(102400, rel=0.001)
    for motor in motors:
        motor.stop()
    sim.advance(3)
    positions = [m.actual_position for m in motors]
    assert positions[0] == pytest.approx(51200 * 5, rel=0.01)  # 1 s up, 4 s full, ~0.5 s down
    assert positions[1] < 0
    for motor, position in zip(motors, positions, strict=True):
        motor.move_by(position)
    sim.advance(12)
    for motor, position in zip(motors, positions, strict=True):
        assert motor.get_position_reached() == 1
        assert motor.actual_position == 2 * position
    for motor in motors:
        motor.move_to(0)
    sim.advance(25)  # motor 5 rotated at 102 400 pps but positions at 51 200 pps
    assert [m.actual_position for m in motors] == [0, 0, 0]


def test_register_access_and_world_switches(sim: SimulatorThread, module: TMCM6212) -> None:
    interface = module.connection
    version = interface.read_mc(0x39)  # TYPE_VERSION of axis 0's TMC4210 (command 148)
    assert version & 0xFFFFFF == 0x429101
    assert version >> 24 & 0xFF == 0x15 | 0x08  # idle status; GP_IN = the home cam is active
    assert module.motors[0].get_axis_parameter(9) == 1  # on the home cam at power-on
    reply = interface.send(146, 0x03, 1, 1234)  # write V_MAX of axis 1 directly
    assert reply.status == 100
    assert interface.send(147, 0x03, 1, 0).value & 0xFFFFFF == 1234
    module.motors[0].rotate(-200_000)  # towards the left cam of the example world
    sim.advance(3)
    assert module.motors[0].get_axis_parameter(11) == 1
    assert module.motors[0].actual_position == -200_000  # hard stop on the switching point
