"""World files, the run-time world API of the module, and --world plumbing."""

from __future__ import annotations

from pathlib import Path

import pytest

from axes.world import BLOCKED_LOAD, INFINITY, AxisWorld, LoadZone, Switch, World, load_world
from tmcl_server.cli import build_parser, config_from_args
from tmcl_server.module import TMCM6212
from tmcl_server.protocol import Request
from tmcl_server.server import ServerConfig, build_simulation
from tmcl_spec.numbers import NS_PER_S
from tmcl_spec.parameters import AP
from tmcl_spec.tmcm6212 import TMCM_6212

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "world-example.toml"


def test_example_world_file_loads() -> None:
    world = load_world(EXAMPLE)
    stage = world.axes[0]
    assert stage.switches["left"] == Switch(-204_000, -200_000)
    assert stage.switches["right"] == Switch(200_000, INFINITY)
    assert stage.switches["home"] == Switch(-1000, 1000)
    assert stage.load_zones == [LoadZone(150_000, 152_000, 0)]
    assert stage.load_at(151_000) == BLOCKED_LOAD and stage.load_at(0) == 600  # load 0: blocked
    assert world.axes[1].encoder_slip == 0.02
    assert world.axes[1].switches["home"].normally_closed
    assert world.analog_inputs == {0: 0, 1: 12000, 2: 0, 3: 65535}
    assert world.digital_inputs == {0: False, 1: True}
    assert world.clock_hz == 16_000_000


def test_switch_placement_sides() -> None:
    assert Switch.place(100, 10, "above") == Switch(100, 110)
    assert Switch.place(100, 10, "below") == Switch(90, 100)
    assert Switch.place(100, None, "below") == Switch(-INFINITY, 100)
    assert Switch.place(100, 10, "centre") == Switch(95, 105)
    with pytest.raises(ValueError):
        Switch.place(0, 5, "sideways")


@pytest.mark.parametrize("text", [
    "[[axis]]\nindex = 9\n",
    "[[axis]]\nindex = 0\nencoder_slip = 2\n",
    "[[axis]]\nindex = 0\n[[axis.load_zone]]\nfrom = 0\nto = 5\nload = 5000\n",
    "not toml at all [",
])
def test_bad_world_files_are_reported_with_their_name(tmp_path: Path, text: str) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"bad\.toml"):
        load_world(path, TMCM_6212.number_of_axes)  # the module type bounds the axis index


def test_a_world_for_more_axes_than_the_module_has_stops_the_server(tmp_path: Path) -> None:
    path = tmp_path / "seven.toml"
    path.write_text("[[axis]]\nindex = 6\n")
    with pytest.raises(ValueError, match=r"seven\.toml.*axis index 6 outside 0\.\.5"):
        build_simulation(ServerConfig(clock="virtual", world=str(path)))


def test_world_reaches_the_module_through_config_and_cli(tmp_path: Path) -> None:
    args = build_parser().parse_args(["--world", str(EXAMPLE), "--no-tcp", "--pty", "/tmp/x"])
    config = config_from_args(args)
    assert config.world == str(EXAMPLE)
    simulation = build_simulation(ServerConfig(world=str(EXAMPLE), clock="virtual", endpoints={}))
    module = simulation.modules[0]
    assert module.analog_inputs[3] == 65535 and module.analog_inputs[2] == 0
    assert module.analog_inputs[1] == 65535 and module.digital_input(1) == 1  # digital wins
    assert module.axis_world(0).switches["home"] == Switch(-1000, 1000)
    home = module.execute(Request(1, 6, 9, 0, 0))  # GAP 9: the axis starts on its home cam
    assert home is not None and home.value == 1


def test_module_world_api_changes_things_at_run_time() -> None:
    module = TMCM6212()
    events = []
    module.listeners.append(events.append)
    module.set_switch(2, "left", 0)  # placed on top of the motor: active at once
    module.advance_to(module.now_ns)
    assert [(e.kind, e.axis, e.data["active"]) for e in events] == [("left_switch", 2, True)]
    assert module.execute(Request(1, 6, 11, 2, 0)).value == 1
    module.set_switch(2, "left", None)
    assert module.execute(Request(1, 6, 11, 2, 0)).value == 0
    module.set_load(3, [(0, 10, 123)], free_load=700)
    assert module.execute(Request(1, 6, 206, 3, 0)).value == 123
    module.set_encoder_slip(4, 0.5)
    module.execute(Request(1, 4, 0, 4, 10000))
    module.advance_to(module.now_ns + 2_000_000_000)
    assert module.execute(Request(1, 6, 209, 4, 0)).value == 5000
    assert module.world.axes[4].encoder_slip == 0.5


def test_world_survives_a_factory_reset() -> None:
    module = TMCM6212(world=World(axes={0: AxisWorld(switches={"home": Switch(-5, 5)})}))
    module.execute(Request(1, 137, 0, 0, 1234))
    assert module.execute(Request(1, 6, 9, 0, 0)).value == 1


def test_an_event_raised_by_a_command_at_time_zero_is_delivered() -> None:
    """MVP to where the motor stands at t = 0: target reached at once, through the router."""
    simulation = build_simulation(ServerConfig(clock="virtual", endpoints={}))
    module = simulation.modules[0]
    events = []
    module.listeners.append(events.append)
    simulation.handle_serial_frame(Request(1, 4, 0, 0, 0).encode())
    simulation.advance(0.001)
    assert [(e.kind, e.time_ns) for e in events] == [("target_reached", 0)]


# -- strict validation: file, line and key in every message -----------------------------------

@pytest.mark.parametrize(("text", "message"), [
    ("[[axes]]\nindex = 0\n", r"line 1: unknown key 'axes'; did you mean 'axis'"),
    ("[[axis]]\nindex = 0\n\n[[axis]]\nindex = 1\nhome = { posiiton = 5, width = 2 }\n",
     r"line 6: unknown key 'axis\[1\]\.home\.posiiton'; did you mean 'position'"),
    ("[[axis]]\nindex = 0\nleft = { width = 5 }\n", r"line 3: axis\[0\]\.left: missing key 'position'"),
    ("[[axis]]\nload = 4\n", r"line 1: axis\[0\]: missing key 'index'"),
    ("[[axis]]\nindex = 0\n[[axis.load_zone]]\nfrom = 0\nto = 9\nlaod = 0\n",
     r"line 6: unknown key 'axis\[0\]\.load_zone\[0\]\.laod'"),
    ("[chip]\nclock_hz = 16000000\nclock = 5\n", r"line 3: unknown key 'chip\.clock'"),
    ("[inputs]\nanalog = [0, 70000]\n", r"line 2: inputs\.analog\[1\] 70000 outside 0\.\.65535"),
    ("[inputs]\ndigital = [1]\n", r"line 2: inputs\.digital\[0\] must be true or false"),
    ("[inputs]\nanalog = [0, 0, 0, 0, 0]\n", r"line 2: inputs\.analog lists 5 inputs; the module has 4"),
    ("[[axis]]\nindex = 0\nencoder_slip = 'lots'\n", r"line 3: axis\[0\]\.encoder_slip must be a number"),
    ("[[axis]]\nindex = 0\n[[axis]]\nindex = 0\n", r"line 4: .*appears twice"),
    ("[supply]\nvolts = 24\n", r"line 2: unknown key 'supply\.volts'; did you mean 'voltage'"),
    ("[[axis]]\nindex = 0\nhome = { position = 0, side = 'left' }\n", r"line 3: .*unknown switch side"),
    ("[[axis]]\nindex = 0\n[[axis.load_zone]]\nfrom = 0\nto = 9\nblocked = true\nload = 300\n",
     r"line 7: axis\[0\]\.load_zone\[0\]: a blocked motor has no load value"),
    ("[[axis]]\nindex = 0\nblocked = 'yes'\n", r"line 3: axis\[0\]\.blocked must be true or false"),
])
def test_world_files_are_validated_strictly(tmp_path: Path, text: str, message: str) -> None:
    path = tmp_path / "w.toml"
    path.write_text(text)
    with pytest.raises(ValueError, match=rf"world file .*w\.toml, {message}"):
        load_world(path, TMCM_6212.number_of_axes, TMCM_6212.analog_inputs)


def test_toml_syntax_errors_keep_tomllibs_line(tmp_path: Path) -> None:
    path = tmp_path / "w.toml"
    path.write_text("[chip]\nclock_hz = = 5\n")
    with pytest.raises(ValueError, match=r"w\.toml: .*line 2"):
        load_world(path)


def test_the_server_refuses_a_misspelt_world_with_the_message(tmp_path: Path) -> None:
    path = tmp_path / "typo.toml"
    path.write_text("[[axis]]\nindex = 0\nright = { posiiton = 100 }\n")
    with pytest.raises(ValueError, match=r"typo\.toml, line 3: unknown key"):
        build_simulation(ServerConfig(clock="virtual", world=str(path)))


def test_supply_voltage_in_the_world_and_at_run_time(tmp_path: Path) -> None:
    path = tmp_path / "supply.toml"
    path.write_text("[supply]\nvoltage = 30\n")
    module = TMCM6212(world=load_world(path))
    assert module.supply_voltage == 30.0
    assert module.execute(Request(1, 15, 8, 1, 0)).value == 300
    module.set_supply_voltage(23.96)
    assert module.execute(Request(1, 15, 8, 1, 0)).value == 240
    module.execute(Request(1, 137, 0, 0, 1234))  # the supply is the world's, not the EEPROM's
    assert module.supply_voltage == 23.96
    assert TMCM6212().execute(Request(1, 15, 8, 1, 0)).value == 240  # nominal 24.0 V


def test_the_chip_core_from_the_world_file_and_the_command_line_wins(tmp_path: Path) -> None:
    path = tmp_path / "core.toml"
    path.write_text("[chip]\ncore = \"tmc4361a\"\n")
    simulation = build_simulation(ServerConfig(clock="virtual", world=str(path)))
    assert simulation.modules[0].chip_core == "tmc4361a"
    assert type(simulation.modules[0].axes[0]).__name__ == "TMC4361AAxis"
    chosen = build_simulation(ServerConfig(clock="virtual", world=str(path), axis_core="tmc4210"))
    assert chosen.modules[0].chip_core == "tmc4210"
    path.write_text("[chip]\nclock_hz = 16000000\ncore = \"tmc4631a\"\n")
    with pytest.raises(ValueError, match=r"core\.toml, line 3: chip\.core 'tmc4631a' is not a "
                                         r"chip core \(known: .*tmc4361a"):
        build_simulation(ServerConfig(clock="virtual", world=str(path)))


# -- a blocked motor apart from a partial load ------------------------------------------------

def test_the_world_says_where_the_motor_is_blocked(tmp_path: Path) -> None:
    path = tmp_path / "w.toml"
    path.write_text("[[axis]]\nindex = 0\n"
                    "[[axis.load_zone]]\nfrom = 100\nto = 200\nblocked = true\n"  # a hard stop
                    "[[axis.load_zone]]\nfrom = 300\nto = 400\nload = 0\nblocked = false\n"
                    "[[axis.load_zone]]\nfrom = 500\nto = 600\nload = 0\n"  # as before: blocked
                    "[[axis]]\nindex = 1\nblocked = true\n"
                    "[[axis]]\nindex = 2\nblocked = false\n")
    world = load_world(path)
    axis = world.axes[0]
    assert axis.load_zones == [LoadZone(100, 200, 0, True), LoadZone(300, 400, 0, False),
                               LoadZone(500, 600, 0)]
    assert [axis.load_at(x) for x in (150, 350, 550, 0)] == [BLOCKED_LOAD, 0, BLOCKED_LOAD, 500]
    assert world.axes[1].load_at(0) == BLOCKED_LOAD  # blocked everywhere
    assert world.axes[2].load_at(0) == 500  # not blocked: the default load
    stuck = AxisWorld(stuck=True, stuck_load=0)
    assert stuck.load_at(0) == BLOCKED_LOAD  # a stuck rotor reading 0 is blocked too


def test_a_blocked_zone_from_a_world_file_stalls_at_a_tuned_threshold(tmp_path: Path) -> None:
    path = tmp_path / "w.toml"
    path.write_text("[[axis]]\nindex = 2\n[[axis.load_zone]]\nfrom = 4000\nto = 90000\n"
                    "blocked = true\n[[axis.load_zone]]\nfrom = 1000\nto = 3000\nload = 0\n"
                    "blocked = false\n")
    module = TMCM6212(world=load_world(path))
    axis = module.axis(2)
    axis.set_parameter(AP.STALLGUARD_THRESHOLD, 12)
    axis.set_parameter(AP.STOP_ON_STALL, 1000)
    axis.rotate(51200)
    module.advance_to(NS_PER_S)
    status = axis.status()
    assert status.position == 4000 and status.velocity == 0  # through the partial 0, not the stop
    assert axis.get_parameter(AP.ERROR_FLAGS) == 1
