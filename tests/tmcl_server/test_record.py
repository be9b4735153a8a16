"""The recorder: samples on simulated time, checked against the motion law; files; plots."""

from __future__ import annotations

import itertools
import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from interpreter.assembler import assemble
from tests.conftest import RawClient
from tests.helpers.clocks import ManualClock
from tests.helpers.processes import ServerProcess
from tmcl_server.clock import VirtualClock
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import TMCM6212, TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.record import Mark, Recorder, RecordWriter, Sample, read_record
from tmcl_server.simulation import PROGRAM_CHUNK_NS, RECORDER_SAMPLES_PER_TURN, Simulation
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.numbers import NS_PER_S
from tmcl_spec.parameters import AP

SPEED = 51200  # AP 4, pps
ACCELERATION = 25600  # AP 5, pps^2: the ramp to full speed takes SPEED / ACCELERATION = 2 s
#: The chip's velocity register rounds AP 4 to its own step (axes/chips/tmc42x/units.py): a read-back may
#: exceed AP 4 by that much (51208 for 51200 on the TMC4210 at 16 MHz).
VELOCITY_QUANTUM = 1e-3


def png_size(path: Path) -> tuple[int, int]:
    """Width and height from a PNG's IHDR chunk (and proof that it is a PNG)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG file"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _command(sim: SimulatorThread, client: RawClient, opcode: int, type_: int = 0, motor: int = 0,
             value: int = 0) -> int:
    reply = client.request(1, opcode, type_, motor, value)
    assert reply.status == Status.OK, reply
    return reply.value


def test_recorded_move_obeys_the_motion_law(tmcl_sim: SimulatorThread, raw_client_factory) -> None:
    client = raw_client_factory(tmcl_sim.tcp)
    _command(tmcl_sim, client, Opcode.SAP, AP.MAX_SPEED, 0, SPEED)
    _command(tmcl_sim, client, Opcode.SAP, AP.MAX_ACCELERATION, 0, ACCELERATION)
    with tmcl_sim.record(resolution=0.001, axes=[0]) as recording:
        _command(tmcl_sim, client, Opcode.MVP, 0, 0, 200_000)
        tmcl_sim.advance(7.0)
    rows = recording.axis(0)
    assert [round(r.t * 1000) for r in rows] == list(range(len(rows)))  # exactly every 1 ms
    assert len(rows) == 7001
    velocity = [r.velocity for r in rows]
    assert max(velocity) <= SPEED * (1 + VELOCITY_QUANTUM)
    assert min(velocity) == 0
    assert all(b.position >= a.position for a, b in itertools.pairwise(rows))
    cruise = max(velocity)
    cruising = [r.t for r in rows if r.velocity == cruise]
    stopped = next(r.t for r in rows if r.t > cruising[-1] and r.velocity == 0)
    assert cruising[0] - 0.0 == pytest.approx(SPEED / ACCELERATION, abs=0.0015)  # MVP at 0: v/a
    ramp = [r.acceleration for r in rows if 0.01 < r.t < cruising[0] - 0.01]
    assert sum(ramp) / len(ramp) == pytest.approx(ACCELERATION, rel=0.01)
    # the TMC4210 brakes with AP 5 too; the last steps crawl at the stop speed (docs/motion.md)
    assert stopped - cruising[-1] == pytest.approx(SPEED / ACCELERATION, abs=0.05)
    # the position is the integral of the velocity (trapezoids over 1 ms samples)
    travelled = 0.0
    for a, b in itertools.pairwise(rows):
        travelled += (a.velocity + b.velocity) / 2 * (b.t - a.t)
        assert abs(b.position - travelled) < 30, (b.t, b.position, travelled)
    (reached,) = recording.events("target_reached", axis=0)
    after = next(r for r in rows if r.t >= reached.t)
    before = [r for r in rows if r.t < reached.t][-1]
    assert (before.reached, after.reached, after.position) == (0, 1, 200_000)
    assert after.t - reached.t < 0.001
    assert rows[-1].current == 128 and rows[-1].target == 200_000


def test_sampling_does_not_move_event_times() -> None:
    """The same move with and without a 1 ms recorder: the same instants of every event."""
    times = []
    for resolution in (None, 0.001, 0.0007):
        with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
            client = RawClient(sim.tcp)
            events: list[tuple[str, int | None, int]] = []
            sim.call(lambda: sim.simulation.modules[0].listeners.append(
                lambda e: events.append((e.kind, e.axis, e.time_ns))))  # noqa: B023
            recording = sim.record(resolution=resolution) if resolution else None
            for axis, target in ((0, 30_000), (1, -12_345), (2, 777)):
                client.request(1, Opcode.MVP, 0, axis, target)
            sim.advance(3.0)
            if recording is not None:
                assert recording.stop()
            client.close()
            times.append(events)
    assert times[0] and times[0] == times[1] == times[2]


def test_a_ten_minute_program_records_and_plots_in_seconds(tmp_path: Path) -> None:
    program = tmp_path / "shuttle.tmc"
    program.write_text("""
        SAP 4, 0, 40000
        SAP 5, 0, 20000
    loop:
        MVP ABS, 0, 60000
        WAIT POS, 0, 0
        WAIT TICKS, 0, 50
        MVP ABS, 0, 0
        WAIT POS, 0, 0
        JA loop
    """)
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"]) as sim:
        assert tmcl(["--tcp", sim.tcp, "program", "upload", str(program), "--run"]) == 0
        record = tmp_path / "shuttle.csv"
        with record.open("w", newline="") as stream:
            writer = RecordWriter(stream, "csv")
            recorder = sim.call(lambda: Recorder(sim.simulation, 0.05, axes=[0], on_sample=writer.sample,
                                                 on_mark=writer.mark, keep=False).start())
            sim.advance(600.0)
            sim.call(recorder.stop)
    samples, marks = read_record(record)
    assert len(samples) == 12001 and samples[-1].t == 600.0
    assert max(abs(s.velocity) for s in samples) <= 40000 * (1 + VELOCITY_QUANTUM)
    arrivals = [m for m in marks if m.event == "target_reached"]
    assert len(arrivals) > 100  # a trip of ~4.5 s each way, for ten minutes
    image = tmp_path / "shuttle.png"
    assert tmcl(["plot", str(record), "-o", str(image), "--size", "8x4", "--dpi", "50"]) == 0
    assert png_size(image) == (400, 200)


def test_record_and_plot_from_the_command_line(tmp_path: Path) -> None:
    record = tmp_path / "move.jsonl"
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--speed", "10", "--record", str(record),
                           "--record-resolution", "0.005", "--record-axes", "0,1")
    try:
        tcp = server.endpoints["tcp"][0]
        send = [sys.executable, "-m", "tmcl_server.tool", "--tcp", tcp, "send"]
        moved = subprocess.run([*send, "MVP", "ABS", "1", "20000", "--wait"], capture_output=True,
                               text=True, timeout=60)
        assert moved.returncode == 0, moved.stderr
        assert moved.stdout.strip() == "MVP ABS m1 20000 → 100 OK"
    finally:
        code, _, err = server.stop()
    assert code == 0, err
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    samples = [line for line in lines if "event" not in line]
    assert {s["axis"] for s in samples} == {0, 1}
    axis1 = [s for s in samples if s["axis"] == 1]
    assert axis1[-1]["position"] == 20000 and axis1[-1]["reached"] == 1
    ticks = [round(s["t"] / 0.005, 6) for s in axis1]
    assert all(t == int(t) for t in ticks) and ticks == sorted(ticks)  # on the 5 ms grid
    assert any(line.get("event") == "target_reached" and line["axis"] == 1 for line in lines)
    image = tmp_path / "move.png"
    plotted = subprocess.run([sys.executable, "-m", "tmcl_server.tool", "plot", str(record),
                              "-o", str(image)], capture_output=True, text=True, timeout=60)
    assert plotted.returncode == 0, plotted.stderr
    assert plotted.stdout.strip() == f"{image}: 1 axes (axis 1)"  # axis 0 never moved
    assert png_size(image) == (1000, 600)


def test_switch_levels_are_recorded(tmcl_sim: SimulatorThread, raw_client_factory) -> None:
    client = raw_client_factory(tmcl_sim.tcp)
    tmcl_sim.call(lambda: tmcl_sim.module(1).set_switch(0, "left", -3000))
    with tmcl_sim.record(resolution=0.01, axes=[0]) as recording:
        client.request(1, Opcode.ROL, 0, 0, 20000)
        tmcl_sim.advance(1.0)
    rows = recording.rows
    assert rows[0].left == 0 and rows[-1].left == 1 and rows[-1].velocity == 0
    first = next(r for r in rows if r.left)
    assert first.position <= -3000
    assert [m.event for m in recording.events("left_switch")] == ["left_switch"]


def test_a_recorder_behind_a_real_clock_never_holds_up_a_request() -> None:
    clock = ManualClock()
    module = TMCM6212()
    simulation = Simulation([module], clock)
    recorder = Recorder(simulation, 0.001, axes=[0]).start()
    clock.t = 10 * NS_PER_S  # ten seconds nobody sampled: 10,000 instants behind
    routed = simulation.handle_serial_frame(Request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0).encode())
    assert routed and routed[0][1].status == Status.OK
    assert len(recorder.rows) <= RECORDER_SAMPLES_PER_TURN + 1  # a turn's worth, not 10,000
    assert recorder.skipped > 0  # and what lies beyond the lag bound is a gap, not a backlog
    while simulation.run_due(PROGRAM_CHUNK_NS):  # the server's timer catches up, turn by turn
        pass
    assert recorder.rows[-1].t == 10.0
    times = [round(row.t * 1000) for row in recorder.rows]
    assert times == sorted(set(times))  # on the grid, each instant once


#: Moves and a rotation that ramp while a program polls a moving speed through the ramp and
#: re-issues the move mid-ramp (a command that changes the axis between two samples), with
#: the module type's own units: (module type, axis core, speed, acceleration, threshold).
RAMPS = [("tmcm-6212", "tmc4210", 40000, 50000, 25000),
         ("tmcm-6212", "tmc4361a", 40000, 50000, 25000),
         ("tmcm-6110", None, 1000, 40, 600),
         ("tmcm-1111", None, 40000, 50000, 25000)]
RAMP_PROGRAM = """
    SAP 4, 0, {speed}
    SAP 5, 0, {acceleration}
    SAP 4, 1, {speed}
    SAP 5, 1, {acceleration}
Loop:
    ROR 1, {threshold}
    MVP ABS, 0, 400000
Up:
    GAP 3, 0
    COMP {threshold}
    JC LT, Up
    MVP ABS, 0, -30000
    ROR 1, -{threshold}
Back:
    GAP 8, 0
    COMP 1
    JC NE, Back
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2
    JA Loop
"""


def _recorded_ramps(kind: str, core: str | None, program: str, skip: bool, resolution: float,
                    modules: int = 1, seconds: float = 3.0) -> tuple[list[Sample], list[object],
                                                                      TMCLModule, Recorder]:
    """Rows and marks of ``program`` run on ``modules`` modules with a recorder whose samples
    and marks reach callbacks (in the order they are handed on), skipping (and a moving
    axis's samples of a steady stretch given at once) or stepping (each sample read from the
    axis brought to its instant)."""
    built = [TMCLModule(slot, kind=kind, chip_core=core) for slot in range(1, modules + 1)]
    sim = Simulation(built, VirtualClock())
    for module in built:
        module.program.interpreter.skip_loops = skip
        for ins in [(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0), *assemble(program).instructions,
                    (Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0), (Opcode.RUN_APPLICATION, 0, 0, 0)]:
            module.execute(Request(module.slot, *ins))
        sim.replan(module)
    handed: list[object] = []
    recorder = Recorder(sim, resolution, on_sample=handed.append, on_mark=handed.append)
    recorder.closed_forms = skip
    recorder.start()
    sim.advance(seconds / 2)
    sim.advance_to_ns(sim.now_ns + 1_234_567)  # an advance that ends between two instants
    sim.advance(seconds / 2)
    return recorder.stop(), handed, built[0], recorder


@pytest.mark.parametrize(("kind", "core", "speed", "acceleration", "threshold"), RAMPS)
def test_samples_inside_ramps_are_the_stepping_reference(kind: str, core: str | None, speed: int,
                                                          acceleration: int, threshold: int) -> None:
    """A recorder's instants no longer end the program's batches (docs/scheduling.md, point
    9): each axis is sampled at an instant when a command or an event is about to bring it
    past it, or once the module has reached the span's end.  Samples taken inside ramps, a
    move re-issued between two of them, a speed polled through the ramp (a moving read the
    loop skips to its crossing): every sample, and the order in which samples and marks
    reach the callbacks, is the stepping interpreter's (every instruction executed, the
    module brought to every instant)."""
    program = RAMP_PROGRAM.format(speed=speed, acceleration=acceleration, threshold=threshold)
    for resolution in (0.001, 0.0037):
        rows, handed, module, recorder = _recorded_ramps(kind, core, program, True, resolution)
        reference = _recorded_ramps(kind, core, program, False, resolution)
        assert rows == reference[0]
        assert handed == reference[1]
        assert module.program.interpreter.loops_skipped > 100  # the loops were skipped
        if core != "tmc4361a" and kind != "tmcm-1111":  # the TMC42x cores' closed form
            assert recorder.at_once > 0.05 * len(rows), recorder.at_once  # axis 1's rotation
        ramping = {row.velocity for row in rows if row.axis == 0}
        assert len(ramping) > 50  # samples inside the ramps, not only at rest or at speed
        assert any(0 < row.velocity < threshold for row in rows if row.axis == 0)
        assert sum(1 for item in handed if isinstance(item, Mark)) >= 2  # an arrival among them


def test_samples_of_several_modules_reach_the_callbacks_in_time_order() -> None:
    """Two modules, samples and marks to callbacks: instant by instant, module by module, as
    stepping hands them on."""
    kind, core, speed, acceleration, threshold = RAMPS[0]
    program = RAMP_PROGRAM.format(speed=speed, acceleration=acceleration, threshold=threshold)
    rows, handed, _, _ = _recorded_ramps(kind, core, program, True, 0.002, modules=2,
                                         seconds=1.0)
    reference = _recorded_ramps(kind, core, program, False, 0.002, modules=2, seconds=1.0)
    assert rows == reference[0] and handed == reference[1]
    assert {row.module for row in rows} == {1, 2}


def test_a_recorder_does_not_cut_the_programs_batches() -> None:
    """A 1 ms recorder over a loop polling "position reached": the loop's passes are skipped
    from one event to the next, in one go per ``advance`` call, not one batch (and one reuse
    of the plan) per sample instant as when each sample brought the module to its instant."""
    program = "SAP 4, 0, 2000\nMVP ABS, 0, 100000\nWait:\nGAP 8, 0\nCOMP 1\nJC NE, Wait\nSTOP"
    kind, core = "tmcm-6212", "tmc4210"
    rows, _, module, _ = _recorded_ramps(kind, core, program, True, 0.001, seconds=1.0)
    assert len(rows) == 6 * 1002  # six axes, every millisecond of 1.001 s
    skipper = module.program.interpreter.skipper
    assert skipper.analyses + skipper.reuses <= 30, (skipper.analyses, skipper.reuses)
