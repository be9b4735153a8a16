"""The official client, unchanged, against the simulator over TCP and over a real pty."""

from __future__ import annotations

import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.modules import TMCM6212
from pytrinamic.tmcl import TMCLReplyStatusError

from tests.helpers.pytrinamic_link import connect
from tmcl_server.embed import SimulatorThread
from tmcl_spec.parameters import GP
from tmcl_spec.tmcm6212 import AXIS_PARAMETERS, BANK0_PARAMETERS

WRITABLE_AXIS = [s for s in AXIS_PARAMETERS.values() if s.writable and s.number not in (0, 1, 2, 209)]


@pytest.fixture
def sim(tmp_path):
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], pty=[str(tmp_path / "ttyTMCL0")],
                         state_dir=str(tmp_path / "state")) as sim:
        yield sim


@pytest.fixture(params=["tcp", "pty"])
def iface(request, sim):
    connection = connect(sim, request.param)
    yield connection
    connection.close()


def test_version(iface):
    assert iface.get_version_string() == "6212V105"
    assert iface.send(136, 1, 0, 0).value == (6212 << 16) | (1 << 8) | 5


def test_axis_parameter_table_round_trips(iface):
    module = TMCM6212(iface)
    for spec in WRITABLE_AXIS:
        values = sorted(spec.allowed) if spec.allowed else [spec.minimum, spec.maximum]
        for value in (values[0], values[-1]):
            motor = spec.number % 6
            module.motors[motor].set_axis_parameter(spec.number, value)
            got = iface.get_axis_parameter(spec.number, motor, signed=True)
            assert got == value, f"AP {spec.number}"


def test_read_only_and_unknown_parameters_raise_with_manual_status(iface):
    with pytest.raises(TMCLReplyStatusError) as info:
        iface.set_axis_parameter(8, 0, 1)
    assert info.value.reply.status == 3
    with pytest.raises(TMCLReplyStatusError) as info:
        iface.get_axis_parameter(189, 0)  # pytrinamic knows it, the TMCM-6212 manual does not
    assert info.value.reply.status == 3
    with pytest.raises(TMCLReplyStatusError) as info:
        iface.set_axis_parameter(4, 0, 8_000_000)
    assert info.value.reply.status == 4
    with pytest.raises(TMCLReplyStatusError) as info:
        iface.get_axis_parameter(4, 6)
    assert info.value.reply.status == 4
    with pytest.raises(TMCLReplyStatusError) as info:
        iface.send(200, 0, 0, 0)
    assert info.value.reply.status == 2


def test_global_parameters(iface):
    for spec in BANK0_PARAMETERS.values():
        if spec.writable and spec.number not in (GP.SERIAL_ADDRESS, GP.SUPPRESS_REPLY,
                                                 GP.TICK_TIMER, GP.RANDOM_NUMBER,
                                                 GP.SERIAL_HEARTBEAT, GP.TELEGRAM_PAUSE):
            iface.set_global_parameter(spec.number, 0, spec.maximum)
            assert iface.get_global_parameter(spec.number, 0) == spec.maximum
    iface.set_global_parameter(200, 2, -123)
    assert iface.get_global_parameter(200, 2, signed=True) == -123


def test_io(iface, sim):
    sim.call(lambda: sim.module(1).set_analog_input(1, 302))
    sim.call(lambda: sim.module(1).set_digital_input(3, True))
    assert iface.get_analog_input(1) == 302
    assert iface.get_digital_input(3) == 1
    assert iface.get_digital_input(0) == 0
    iface.set_digital_output(2)
    assert iface.get_digital_output(2) == 1
    iface.clear_digital_output(2)
    assert iface.get_digital_output(2) == 0


def test_coordinates(iface):
    iface.send(30, 4, 1, -5000)  # SCO 4, 1, -5000
    assert iface.send(31, 4, 1, 0).value == 2**32 - 5000  # GCO (pytrinamic returns unsigned)
    iface.move(2, 1, 4)  # MVP COORD, 1, 4


def test_move_to_and_poll(iface, sim):
    module = TMCM6212(iface)
    motor = module.motors[0]
    module.move_to(0, 20000, velocity=40000)
    assert motor.get_position_reached() == 0
    sim.advance(0.2)
    assert 0 < motor.actual_position < 20000
    assert sim.advance_until(lambda: sim.module(1).axis(0).get_parameter(8) == 1, timeout=5)
    assert motor.get_position_reached() == 1
    assert motor.actual_position == 20000


def test_user_variables_survive_restart(tmp_path):
    state = str(tmp_path / "state")
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], state_dir=state) as sim, \
            connect(sim, "tcp") as iface:
        iface.set_global_parameter(10, 2, 4242)
        iface.store_global_parameter(10, 2)
        iface.set_global_parameter(11, 2, 1111)  # not stored
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], state_dir=state) as sim, \
            connect(sim, "tcp") as iface:
        assert iface.get_global_parameter(10, 2) == 4242
        assert iface.get_global_parameter(11, 2) == 0


def test_second_module_on_the_same_endpoint(tmp_path):
    with SimulatorThread(clock="virtual", modules=3, tcp=["127.0.0.1:0"]) as sim, \
            connect(sim, "tcp") as iface:
        for address in (1, 2, 3):
            iface.set_axis_parameter(4, 0, 1000 * address, module_id=address)
        assert [iface.get_axis_parameter(4, 0, module_id=a) for a in (1, 2, 3)] == [
            1000, 2000, 3000]


def test_pytest_plugin_fixture(tmcl_sim):
    with ConnectionManager(f"--interface socket_serial_tmcl --port {tmcl_sim.tcp}").connect() as i:
        assert i.get_version_string() == "6212V105"
