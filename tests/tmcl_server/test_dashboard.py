"""The dashboard without a browser: what a page gets, what its actions do, the update protocol
over a real WebSocket, the command line (tests/test_architecture.py checks that a server
without ``--http`` imports nothing of it)."""

from __future__ import annotations

import asyncio
import io
import json

import pytest

from axes.world import World
from interpreter.assembler import assemble
from tests.conftest import RawClient
from tmcl_server.clock import VirtualClock
from tmcl_server.dashboard.core import WIRE_PER_FRAME, ActionError, Dashboard, Viewer
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCM6212, TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.simulation import Simulation
from tmcl_server.trace import Tracer
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP, GP

aiohttp = pytest.importorskip("aiohttp")
PAGE = "http 127.0.0.1:5000"


def make(modules: int = 1, world: World | None = None) -> tuple[Dashboard, Simulation]:
    simulation = Simulation([TMCM6212(slot, world=world) for slot in range(1, modules + 1)],
                            VirtualClock())
    return Dashboard(simulation), simulation


def test_hello_describes_every_module_with_the_manuals_tables_by_compact_name() -> None:
    dashboard, _ = make(modules=2)
    hello = dashboard.hello()
    assert hello["clock"] == "virtual" and [m["slot"] for m in hello["modules"]] == [1, 2]
    module = hello["modules"][0]
    assert (module["type"], module["axes"], module["inputs"], module["outputs"]) == ("TMCM-6212", 6, 4, 4)
    rows = {row["number"]: row for row in module["axis_parameters"]}
    assert rows[4]["name"] == "MaxPositioningSpeed" and rows[4]["title"] == "Maximum positioning speed"
    assert set(module["banks"]) == {"0", "2", "3"}
    assert {row["name"] for row in module["banks"]["2"]} >= {"UserVariable0", "UserVariable55"}
    assert module["vectors"]["0"] == "TI_TIMER0" and module["vectors"]["8"] == "TI_TARGET5"
    json.dumps(hello)  # what goes over the socket


def test_every_module_type_is_shown_with_its_own_tables_and_axes() -> None:
    simulation = Simulation([TMCLModule(1, kind="tmcm-3110")], VirtualClock())
    dashboard = Dashboard(simulation)
    module = dashboard.hello()["modules"][0]
    assert (module["type"], module["axes"]) == ("TMCM-3110", 3)
    assert "TI_TARGET2" in module["vectors"].values() and "TI_TARGET3" not in module["vectors"].values()
    frame = dashboard.frame(Viewer(PAGE, 1), parameters=True)
    assert len(frame["axes"]) == 3 and all(len(v) == 3 for v in frame["parameters"]["axis"].values())
    json.dumps(frame)


def test_frames_carry_only_what_is_new_samples_on_simulated_time_and_the_listing() -> None:
    dashboard, simulation = make()
    module = simulation.modules[0]
    viewer = Viewer(PAGE, 1)
    dashboard.watch()
    module.program.interpreter.load(assemble("L: CALC ADD, 1\nJA L").instructions)
    module.execute(Request(1, Opcode.MVP, 0, 0, 10000))
    simulation.replan()
    for _ in range(3):
        dashboard.sample({1})
        simulation.advance(0.1)
    dashboard.sample({1})
    dashboard.sample({1})  # time has not moved: no second sample at the same instant
    frame = dashboard.frame(viewer)
    assert frame["samples"]["t"] == pytest.approx([0.0, 0.1, 0.2, 0.3])
    positions = frame["samples"]["position"][0]
    assert positions[0] == 0 and positions == sorted(positions) and frame["samples"]["target"][0][-1] == 10000
    assert frame["axes"][0]["position"] == positions[-1] and frame["axes"][0]["max_speed"] == 51200
    assert [line[1:] for line in frame["listing"]] == [["L1", "CALC ADD, 1"], [None, "JA L1"]]
    again = dashboard.frame(viewer)
    assert again["samples"]["t"] == [] and "listing" not in again and again["wire"] == []
    json.dumps(frame)


def test_a_command_from_the_page_is_validated_answered_and_traced_like_a_hosts() -> None:
    dashboard, simulation = make()
    stream = io.StringIO()
    Tracer(stream).attach(simulation)  # as --trace does
    dashboard.watch()
    viewer = Viewer(PAGE, 1)
    answer = dashboard.act({"op": "command", "id": 7, "cmd": "SAP", "type": 4, "motor": 0,
                            "value": 1000}, viewer)
    assert answer == {"type": "reply", "id": 7, "module": 1, "status": 100, "value": 1000,
                      "text": "SAP 4 MaxPositioningSpeed m0 = 1000 → 100 OK",
                      "request": "SAP 4 MaxPositioningSpeed m0 = 1000", "status_name": "OK"}
    assert simulation.modules[0].axis(0).get_parameter(AP.MAX_SPEED) == 1000
    refused = dashboard.act({"op": "command", "cmd": 5, "type": 6, "motor": 0, "value": 300}, viewer)
    assert refused["status"] == 4 and refused["text"].endswith("→ 4 INVALID_VALUE")
    lines = stream.getvalue().splitlines()
    assert len(lines) == 2 and all(PAGE in line for line in lines)
    assert "SAP 4 MaxPositioningSpeed m0 = 1000 → 100 OK" in lines[0]
    wire = dashboard.frame(viewer)["wire"]  # the same lines, decoded once, for the page
    assert [(endpoint, kind, text) for _, _, endpoint, _, kind, text in wire] == [
        (PAGE, "cmd", "SAP 4 MaxPositioningSpeed m0 = 1000 → 100 OK"),
        (PAGE, "cmd", "SAP 6 MaxCurrent m0 = 300 → 4 INVALID_VALUE")]
    with pytest.raises(ActionError, match="unknown mnemonic"):
        dashboard.act({"op": "command", "cmd": "FLY"}, viewer)


def test_a_flood_of_telegrams_is_counted_and_only_the_newest_are_decoded_for_the_page() -> None:
    dashboard, simulation = make()
    dashboard.watch()
    viewer = Viewer(PAGE, 1)
    dashboard.frame(viewer)
    for value in range(250):
        simulation.handle_serial_frame(Request(1, Opcode.SAP, AP.MAX_SPEED, 0, value).encode())
    frame = dashboard.frame(viewer)
    assert (len(frame["wire"]), frame["wire_skipped"]) == (WIRE_PER_FRAME, 250 - WIRE_PER_FRAME)
    assert [line[5] for line in frame["wire"][-2:]] == [
        "SAP 4 MaxPositioningSpeed m0 = 248 → 100 OK", "SAP 4 MaxPositioningSpeed m0 = 249 → 100 OK"]
    assert dashboard.frame(viewer)["wire"] == []


def test_the_page_watches_through_a_tracer_only_while_it_is_open() -> None:
    dashboard, simulation = make()
    dashboard.watch()
    dashboard.watch()
    tracer = simulation.tracer
    assert tracer is not None and tracer.stream is None and len(tracer.listeners) == 1
    dashboard.unwatch()
    assert simulation.tracer is tracer
    dashboard.unwatch()
    assert simulation.tracer is None  # the last page closed: nothing costs anything
    own = Tracer(io.StringIO()).attach(simulation)  # --trace: shared, never detached by the page
    dashboard.watch()
    assert simulation.tracer is own and len(own.listeners) == 1
    dashboard.unwatch()
    assert simulation.tracer is own and own.listeners == []
    own.detach()
    second = Dashboard(simulation)  # two --http endpoints share one stream-less tracer
    dashboard.watch()
    second.watch()
    shared = simulation.tracer
    assert shared is not None and len(shared.listeners) == 2
    dashboard.unwatch()
    assert simulation.tracer is shared
    second.unwatch()
    assert simulation.tracer is None


def test_a_pressed_switch_is_held_and_letting_go_restores_the_world() -> None:
    world = World.from_dict({"axis": [{"index": 1, "left": {"position": -25000, "width": 3000}}]})
    dashboard, simulation = make(world=world)
    module = simulation.modules[0]
    placed = module.axis_world(1).switches["left"]
    viewer = Viewer(PAGE, 1)
    dashboard.act({"op": "switch", "axis": 1, "name": "left"}, viewer)
    assert module.axis(1).status().left_switch  # pressed wherever the axis is
    assert dashboard.frame(viewer)["axes"][1]["held"] == ["left"]
    dashboard.act({"op": "switch", "axis": 1, "name": "left"}, viewer)
    assert module.axis_world(1).switches["left"] == placed and not module.axis(1).status().left_switch
    dashboard.act({"op": "switch", "axis": 2, "name": "home"}, viewer)
    dashboard.act({"op": "switch", "axis": 2, "name": "home"}, viewer)
    assert "home" not in module.axis_world(2).switches
    with pytest.raises(ActionError):
        dashboard.act({"op": "switch", "axis": 6, "name": "left"}, viewer)
    with pytest.raises(ActionError):
        dashboard.act({"op": "switch", "axis": 0, "name": "middle"}, viewer)


def test_the_load_slider_sets_the_free_load_and_keeps_the_worlds_zones() -> None:
    world = World.from_dict({"axis": [{"index": 0, "load_zone": [{"from": 100, "to": 200, "load": 0}]}]})
    dashboard, simulation = make(world=world)
    module = simulation.modules[0]
    dashboard.act({"op": "load", "axis": 0, "value": 321}, Viewer(PAGE, 1))
    axis_world = module.axis_world(0)
    assert axis_world.free_load == 321 and [(z.low, z.high, z.load) for z in axis_world.load_zones] == [
        (100, 200, 0)]
    assert module.axis(0).status().load == 321


def test_inputs_from_the_page() -> None:
    dashboard, simulation = make()
    module = simulation.modules[0]
    viewer = Viewer(PAGE, 1)
    dashboard.act({"op": "input", "port": 2, "active": True}, viewer)
    dashboard.act({"op": "analog", "port": 1, "value": 1234}, viewer)
    io_state = dashboard.frame(viewer)["io"]
    assert io_state["inputs"] == [0, 0, 1, 0] and io_state["analog"][1] == 1234
    assert module.read_input(2, 0) == 1
    with pytest.raises(ActionError):
        dashboard.act({"op": "analog", "port": 1, "value": 70000}, viewer)


def test_parameter_values_are_read_without_side_effects() -> None:
    dashboard, simulation = make()
    other = TMCM6212(1)  # the same random sequence, never looked at
    module = simulation.modules[0]
    values = dashboard.parameters(module)
    assert values["axis"][str(AP.MAX_SPEED)] == [51200] * 6
    assert values["banks"]["0"][str(GP.RANDOM_NUMBER)] is None
    assert values["banks"]["0"][str(GP.SERIAL_ADDRESS)] == 1
    assert module.read_global(GP.RANDOM_NUMBER, 0) == other.read_global(GP.RANDOM_NUMBER, 0)
    json.dumps(values)


def test_breakpoints_from_the_page_and_the_program_state_a_frame_shows() -> None:
    dashboard, simulation = make()
    module = simulation.modules[0]
    interp = module.program.interpreter
    interp.load(assemble("CALC LOAD, 5\nL: CALC ADD, 1\nJA L").instructions)
    viewer = Viewer(PAGE, 1)
    dashboard.act({"op": "breakpoint", "address": 2, "set": True}, viewer)
    assert interp.breakpoints == {2}
    dashboard.act({"op": "command", "cmd": 129, "type": 1, "value": 0}, viewer)
    simulation.advance(0.01)
    program = dashboard.frame(viewer)["program"]
    assert (program["state"], program["pc"], program["accumulator"]) == ("STEP", 2, 6)
    assert program["breakpoints"] == [2] and program["flags"]["NZ"] and not program["flags"]["ZE"]
    dashboard.act({"op": "breakpoint", "address": 2}, viewer)  # no "set": toggles
    assert interp.breakpoints == set()
    with pytest.raises(ActionError):
        dashboard.act({"op": "breakpoint", "address": 6144}, viewer)


def test_the_update_protocol_over_a_real_websocket() -> None:
    """hello once; a frame, and the next only after an ack; replies to commands at once."""
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], http=["127.0.0.1:0"]) as sim:
        url = sim.endpoints["http"][0]

        async def talk() -> None:
            async with aiohttp.ClientSession() as session:
                async with session.get(url) as response:
                    assert response.status == 200 and "tmcl-sim dashboard" in await response.text()
                async with session.get(f"{url}static/vendor/uPlot.iife.min.js") as response:
                    assert response.status == 200
                async with session.ws_connect(f"{url}ws") as ws:
                    hello = await ws.receive_json(timeout=5)
                    assert hello["type"] == "hello" and hello["modules"][0]["slot"] == 1
                    first = await ws.receive_json(timeout=5)
                    assert first["type"] == "frame" and first["t"] == 0.0
                    with pytest.raises(asyncio.TimeoutError):  # no ack: no next frame yet
                        await ws.receive_json(timeout=0.3)
                    await ws.send_json({"op": "command", "id": 1, "cmd": "GAP", "type": 4, "motor": 0})
                    reply = await ws.receive_json(timeout=5)
                    assert reply == {"type": "reply", "id": 1, "module": 1, "status": 100,
                                     "value": 51200, "text": "GAP 4 MaxPositioningSpeed m0 → 100 OK = 51200",
                                     "request": "GAP 4 MaxPositioningSpeed m0", "status_name": "OK"}
                    await ws.send_json({"op": "switch", "axis": 9, "name": "left", "id": 2})
                    error = await ws.receive_json(timeout=5)
                    assert error["type"] == "error" and "axis must be 0..5" in error["message"]
                    wire: list[list[object]] = []
                    for _ in range(40):  # the trace decodes in batches, within 50 ms
                        await ws.send_json({"op": "ack"})
                        frame = await ws.receive_json(timeout=5)
                        assert frame["type"] == "frame"
                        wire += frame["wire"]
                        if wire:
                            break
                    assert [line[4:] for line in wire] == [
                        ["cmd", "GAP 4 MaxPositioningSpeed m0 → 100 OK = 51200"]]
                    assert wire[0][2].startswith("http 127.0.0.1:")

        asyncio.run(talk())
        client = RawClient(sim.tcp)  # the host's own connection is untouched throughout
        assert client.request(1, Opcode.GAP, AP.MAX_SPEED, 0).value == 51200
        client.close()
        assert sim.call(lambda: sim.simulation.tracer) is None  # the page closed


def test_the_command_line_option(monkeypatch: pytest.MonkeyPatch) -> None:
    from tmcl_server.cli import build_parser, config_from_args

    config = config_from_args(build_parser().parse_args(["--http", "8080", "--no-tcp", "--pty", "/tmp/x"]))
    assert config.endpoints == {"pty": ["/tmp/x"], "http": ["8080"]}
    with pytest.raises(SystemExit, match="no transport"):  # a page alone serves no host
        config_from_args(build_parser().parse_args(["--http", "8080", "--no-tcp"]))
    monkeypatch.setattr("importlib.util.find_spec", lambda name: None)
    with pytest.raises(SystemExit, match=r"tmcl-sim\[http\]"):
        config_from_args(build_parser().parse_args(["--http", "8080"]))
