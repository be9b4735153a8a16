#!/usr/bin/env python3
"""Simulated seconds per wall second of TMCL programs on the virtual clock, each shape beside
the stepping reference (every instruction executed) in the same run.

Issue 23's goals: loops whose reads do not change >= 1,000 x real time; a moving position
polled against a threshold >= 200 x; a 1 ms timer interrupt >= 100 x; six axes in
program-driven back-and-forth moves, one simulated hour, <= 0.5 s of wall time on every core.

    .venv/bin/python scripts/bench_vtime.py [--seconds S] [--repeat N] [--only NAME,...]
                                            [--compare DIR ...]

Each shape runs ``--seconds`` of simulated time (default 600, ten minutes; the six-axis shape
one hour) with loop skipping on (the default) and, with the same program and world, in the
stepping reference (``Interpreter.skip_loops = False``), which is capped at a few simulated
seconds when it would take long (its rate is what matters).  Both runs must end in the same
state (the program's registers, user variables, axis positions, events): the benchmark says so.

``--compare DIR`` also runs each shape's skipping run on another checkout's code (a baseline
worktree), in a child process between this code's runs, and prints its rate below; given
more than once, each baseline's in turn.

Times are the process's CPU time (``time.process_time``): on a machine shared with other work
the wall clock also counts the others' turns; alone, the two agree.
"""

from __future__ import annotations

import argparse
import inspect
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

# The code that runs: this checkout's, or with ``--code DIR`` another's (``--compare``'s child
# process runs this script's shapes on a baseline checkout that may not have them).
sys.path.insert(0, str(Path(sys.argv[sys.argv.index("--code") + 1]).resolve()
                       if "--code" in sys.argv[:-1] else Path(__file__).resolve().parent.parent))

from interpreter.assembler import assemble
from tmcl_server.clock import VirtualClock
from tmcl_server.embed import SimulatorThread
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.record import Recorder, Sample
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode

NS = 1_000_000_000
_CODE = sys.path[0]


@dataclass(frozen=True)
class Shape:
    name: str
    goal: float  # simulated s per wall s the skipping run must reach (0: wall-time goal)
    source: str
    #: Called every simulated second with (simulation, module, second): the host's part.
    host: Callable[[Simulation, TMCLModule, int], None] | None = None
    kind: str = "tmcm-6212"
    core: str | None = None
    seconds: float | None = None  # overrides --seconds (the six-axis hour)
    wall_goal: float = 0.0  # wall seconds the skipping run may take (six axes)
    #: The test advances the clock in steps of this many seconds (None: one call).
    step_s: float | None = None
    #: A recorder samples every axis this often (seconds; None: no recorder).
    record_s: float | None = None
    #: The clock is advanced through ``SimulatorThread.advance`` (the embedding API), with
    #: these keywords.
    embed: bool = False
    advance: dict[str, bool] = field(default_factory=dict)
    #: The embedded simulator's endpoints (``SimulatorThread`` keywords, e.g. a TCP port).
    endpoints: dict[str, list[str]] = field(default_factory=dict)
    #: The world before the program starts (switches, load zones).
    world: Callable[[TMCLModule], None] | None = None


def _toggle_input(sim: Simulation, module: TMCLModule, second: int) -> None:
    if second % 60 == 59:  # a host presses the input once a minute, the program counts it
        module.set_digital_input(0, True)
        sim.replan(module)
    elif second % 60 == 0:
        module.set_digital_input(0, False)
        sim.replan(module)


SIX_AXES = """
    SAP 4, 0, 51200
    SAP 5, 0, 51200
    SAP 4, 1, 51200
    SAP 5, 1, 51200
    SAP 4, 2, 51200
    SAP 5, 2, 51200
    SAP 4, 3, 51200
    SAP 5, 3, 51200
    SAP 4, 4, 80000
    SAP 5, 4, 100000
    SAP 4, 5, 102400
    SAP 5, 5, 102400
Loop:
    MVP ABS, 0, 512000
    MVP ABS, 1, 512000
    MVP ABS, 2, 512000
    MVP ABS, 3, 512000
    MVP ABS, 4, 400000
    MVP ABS, 5, 512000
Wait1:
    GAP 8, 0
    COMP 1
    JC NE, Wait1
    WAIT POS, 1, 0
    WAIT POS, 2, 0
    WAIT POS, 3, 0
    WAIT POS, 4, 0
    WAIT POS, 5, 0
    MVP ABS, 0, -512000
    MVP ABS, 1, -512000
    MVP ABS, 2, -512000
    MVP ABS, 3, -512000
    MVP ABS, 4, -400000
    MVP ABS, 5, -512000
Wait2:
    GAP 8, 0
    COMP 1
    JC NE, Wait2
    WAIT POS, 1, 0
    WAIT POS, 2, 0
    WAIT POS, 3, 0
    WAIT POS, 4, 0
    WAIT POS, 5, 0
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2
    JA Loop
"""
#: The same on a TMC429 module: speeds and accelerations as register values (AP 154/153 set).
SIX_AXES_TMC429 = SIX_AXES.replace("SAP 4, 0, 51200", "SAP 4, 0, 839").replace(
    "SAP 5, 0, 51200", "SAP 5, 0, 200")
for _axis in range(1, 6):
    SIX_AXES_TMC429 = (SIX_AXES_TMC429
                       .replace(f"SAP 4, {_axis}, 51200", f"SAP 4, {_axis}, 839")
                       .replace(f"SAP 5, {_axis}, 51200", f"SAP 5, {_axis}, 200")
                       .replace(f"SAP 4, {_axis}, 80000", f"SAP 4, {_axis}, 1311")
                       .replace(f"SAP 5, {_axis}, 100000", f"SAP 5, {_axis}, 391")
                       .replace(f"SAP 4, {_axis}, 102400", f"SAP 4, {_axis}, 1678")
                       .replace(f"SAP 5, {_axis}, 102400", f"SAP 5, {_axis}, 400"))

def _light_load(module: TMCLModule) -> None:
    """A light load (stallGuard reads well above 0) over the whole travel of axis 0."""
    module.set_load(0, [(-10_000_000, 10_000_000, 900)])


def _joystick(sim: Simulation, module: TMCLModule, second: int) -> None:
    """The operator moves the stick (analogue inputs 0 and 1) every other second."""
    if second % 2 == 0:
        module.set_analog_input(0, 1000 + 37 * (second % 50))
        module.set_analog_input(1, 3000 - 29 * (second % 60))
        sim.replan(module)


#: Six axes polled in turn, each move re-issued as it arrives (no WAIT between the axes).
SIX_ROUND_ROBIN = "\n".join(
    [*(f"SAP 4, {axis}, {40000 + 10000 * axis}\nSAP 5, {axis}, 100000\n"
       f"MVP ABS, {axis}, {200000 + 30000 * axis}" for axis in range(6)), "Poll:"]
    + [f"GAP 8, {axis}\nCOMP 1\nJC EQ, Turn{axis}\nBack{axis}:" for axis in range(6)]
    + ["JA Poll"]
    + [f"Turn{axis}:\nGAP 0, {axis}\nCALC MUL, -1\nAAP 0, {axis}\nJA Back{axis}"
       for axis in range(6)])

#: Issue 33's axis-side shapes (forecasts: CALC/CALCX, a positioning move's speed, six axes
#: in turn, a joystick over analogue inputs; and stall-zone below).
AXIS_SHAPES = [
    Shape("pos-speed", 1000, """
    // a positioning move's speed polled while it ramps, moves re-issued
    SAP 4, 0, 100000
    SAP 5, 0, 20000
Loop:
    MVP ABS, 0, 1000000
Up:
    GAP 3, 0
    COMP 80000
    JC LT, Up
Down:
    GAP 3, 0
    COMP 0
    JC NE, Down
    MVP ABS, 0, 0
Back:
    GAP 3, 0
    COMP -80000
    JC GT, Back
Rest:
    GAP 3, 0
    COMP 0
    JC NE, Rest
    JA Loop
"""),
    Shape("distance", 1000, """
    // distance since the start of a move (GAP 1, CALCX SUB, COMP), moves re-issued
    SAP 4, 0, 100000
Loop:
    GAP 1, 0
    CALCX LOAD
    MVP REL, 0, 1000000
Far:
    GAP 1, 0
    CALCX SUB
    COMP 900000
    JC LT, Far
    WAIT POS, 0, 0
    GAP 1, 0
    CALCX LOAD
    MVP REL, 0, -1000000
Near:
    GAP 1, 0
    CALCX SUB
    COMP -900000
    JC GT, Near
    WAIT POS, 0, 0
    JA Loop
"""),
    Shape("six-poll", 2000, SIX_ROUND_ROBIN),
    Shape("joystick-ain", 2000, """
    // a joystick over analogue inputs 0 and 1 driving axes 0 and 1
Loop:
    GIO 0, 1
    CALC SUB, 2048
    CALC MUL, 20
    AAP 2, 0
    GIO 1, 1
    CALC SUB, 2048
    CALC MUL, 20
    AAP 2, 1
    JA Loop
""", host=_joystick),
]

SHAPES = [
    Shape("flag", 1000, """
    // poll "position reached" while the axis travels back and forth
Loop:
    MVP ABS, 0, 1000000
Wait1:
    GAP 8, 0
    COMP 1
    JC NE, Wait1
    MVP ABS, 0, 0
Wait2:
    GAP 8, 0
    COMP 1
    JC NE, Wait2
    JA Loop
"""),
    Shape("input", 1000, """
    // poll a digital input until a host changes it; count the presses
Loop:
    GIO 0, 0
    COMP 1
    JC NE, Loop
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2
Release:
    GIO 0, 0
    COMP 0
    JC NE, Release
    JA Loop
""", host=_toggle_input),
    Shape("refused", 1000, """
    // poll a parameter the module does not have (status 3 every time)
Loop:
    GAP 250, 0
    JA Loop
"""),
    Shape("spin", 1000, """
Loop:
    JA Loop
"""),
    Shape("joystick", 1000, """
    // a joystick controller: read an analogue input, write the same speed each pass
Loop:
    GIO 1, 1
    CALC MUL, 10
    AAP 2, 0
    SAP 4, 0, 100000
    JA Loop
"""),
    Shape("threshold", 200, """
    // a moving position against a threshold
Loop:
    MVP ABS, 0, 2000000
Out:
    GAP 1, 0
    COMP 1900000
    JC LT, Out
    MVP ABS, 0, 0
Back:
    GAP 1, 0
    COMP 100000
    JC GT, Back
    JA Loop
"""),
    Shape("speed", 200, """
    // a speed against a threshold: slow ramps, polled until the speed passes a value
Loop:
    SAP 5, 0, 2000
    ROR 0, 50000
Up:
    GAP 3, 0
    COMP 40000
    JC LT, Up
    ROR 0, -50000
Down:
    GAP 3, 0
    COMP -40000
    JC GT, Down
    JA Loop
"""),
    Shape("monitor", 1000, """
    // a field program's shape: three axes moved, a monitor loop checking a limit setting
    // and each axis's "position reached" with several exits, a host-set state variable
    SAP 4, 0, 40000
    SAP 4, 1, 60000
    SAP 4, 2, 80000
Cycle:
    MVP ABS, 0, 500000
    MVP ABS, 1, -300000
    MVP ABS, 2, 700000
WaitMove:
    GGP 10, 2
    COMP 99
    JC EQ, Halt
    GAP 212, 0
    COMP 50
    JC GT, Halt
    GAP 8, 0
    COMP 1
    JC NE, WaitMove
    GAP 8, 1
    COMP 1
    JC NE, WaitMove
    GAP 8, 2
    COMP 1
    JC NE, WaitMove
    WAIT TICKS, 0, 10
    MVP ABS, 0, 0
    MVP ABS, 1, 0
    MVP ABS, 2, 0
Back:
    GAP 8, 0
    COMP 1
    JC NE, Back
    WAIT POS, 1, 0
    WAIT POS, 2, 0
    JA Cycle
Halt:
    MST 0
    MST 1
    MST 2
    STOP
"""),
    Shape("timer", 100, """
    // a 1 ms timer interrupt whose handler counts in user variable 0
    VECT 0, Tick
    SGP 0, 3, 1
    EI 0
    EI 255
Main:
    JA Main
Tick:
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2
    RETI
"""),
    Shape("six-tmc4210", 0, SIX_AXES, seconds=3600, wall_goal=0.5),
    Shape("six-tmc4361a", 0, SIX_AXES, core="tmc4361a", seconds=3600, wall_goal=0.5),
    Shape("six-tmc429", 0, SIX_AXES_TMC429.replace("Loop:\n", "Loop:\n", 1), kind="tmcm-6110",
          seconds=3600, wall_goal=0.5),
    *AXIS_SHAPES,
]

#: A poll of "position reached" over moves back and forth (the flag shape), for the rows
#: that drive the clock or record.
FLAG = SHAPES[0].source
MONITOR = next(shape.source for shape in SHAPES if shape.name == "monitor")
#: A timer interrupt over the flag poll: its handler counts in user variable 0.
TIMER_FLAG = """
    VECT 0, Tick
    SGP 0, 3, {period}
    EI 0
    EI 255
""" + FLAG + """
Tick:
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2
    RETI
"""
# Issue 33's batch boundaries (items 2, 3, 4, 6): the clock advanced in steps, timers, the ms
# tick and recorders over loops that skip.
SHAPES += [
    Shape("flag-timer1", 500, TIMER_FLAG.format(period=1)),
    Shape("flag-timer10", 2000, TIMER_FLAG.format(period=10)),
    Shape("flag-step100", 2000, FLAG, step_s=0.1),
    Shape("flag-step10", 1000, FLAG, step_s=0.01),
    Shape("flag-step1", 100, FLAG, step_s=0.001),
    # (no transport: the default advance owes the time, as wait=False; with a TCP endpoint
    # it waits for the loop, so that a frame the test sent before is served first)
    Shape("stopped-step1", 200, "STOP", step_s=0.001, embed=True),
    Shape("stopped-owed1", 200, "STOP", step_s=0.001, embed=True, advance={"wait": False}),
    Shape("stopped-tcp1", 0, "STOP", step_s=0.001, embed=True,
          endpoints={"tcp": ["127.0.0.1:0"]}),
    Shape("tick-delay", 1000, """
    // a delay loop on the ms tick: GP 132 set to 0, polled until it reaches 500; a count
Loop:
    SGP 132, 0, 0
Delay:
    GGP 132, 0
    COMP 500
    JC LT, Delay
    GGP 0, 2
    CALC ADD, 1
    AGP 0, 2
    JA Loop
"""),
    Shape("flag-record10", 1000, FLAG, record_s=0.01),
    Shape("flag-record1", 200, FLAG, record_s=0.001),
    # a 1 ms timer whose handler counts (GGP / CALC ADD / AGP), the main loop idle
    Shape("timer-count", 1000, next(shape.source for shape in SHAPES if shape.name == "timer")),
    Shape("monitor-record10", 200, MONITOR, record_s=0.01),
    Shape("six-record10", 200, SIX_AXES, record_s=0.01, seconds=60),
    Shape("speed-record10", 200, SHAPES[6].source, record_s=0.01),
]
#: Issue 33: the "flag" poll with stop-on-stall armed (AP 181 above 10,000 pps, stallGuard
#: threshold 5), over a light-load zone.
SHAPES.insert(SHAPES.index(AXIS_SHAPES[0]), replace(
    next(shape for shape in SHAPES if shape.name == "flag"), name="stall-zone",
    source="\n    SAP 174, 0, 5\n    SAP 181, 0, 10000" + next(
        shape for shape in SHAPES if shape.name == "flag").source, world=_light_load))
#: TMC429 modules: the divisors that make the register values above the pps of the others.
TMC429_SETUP = [(154, axis, 4) for axis in range(6)] + [(153, axis, 10) for axis in range(6)]


#: The events a run saw: (instant, kind, how many, period) -- a run of like events (a timer's
#: dispatches left out by loop skipping) is one entry, as a listener of runs gets it.
Events = list[tuple[int, str, int, int]]


def build(shape: Shape, reference: bool) -> tuple[Simulation, TMCLModule, Events]:
    module = TMCLModule(kind=shape.kind, chip_core=shape.core)
    sim = Simulation([module], VirtualClock())
    interpreter = module.program.interpreter
    if hasattr(interpreter, "skip_loops"):
        interpreter.skip_loops = not reference
    return (sim, *load(sim, module, shape))


def load(sim: Simulation, module: TMCLModule, shape: Shape) -> tuple[TMCLModule, Events]:
    """Set the module up for ``shape`` and start its program; its event list."""
    events: Events = []

    def listen(event: ModuleEvent) -> None:
        if event.kind not in ("current_changed",):
            events.append((event.time_ns, event.kind, getattr(event, "repeat", 1),
                           getattr(event, "period_ns", 0)))

    # a listener of runs where the code has them (a baseline's listeners get each event)
    getattr(module, "run_listeners", module.listeners).append(listen)
    if shape.kind == "tmcm-6110":
        for number, axis, value in TMC429_SETUP:
            module.execute(Request(1, Opcode.SAP, number, axis, value))
    module.set_analog_input(1, 1234)
    if shape.world is not None:
        shape.world(module)
    program = assemble(shape.source).instructions
    module.execute(Request(1, Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0))
    for ins in program:
        module.execute(Request(1, *ins))
    module.execute(Request(1, Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0))
    module.execute(Request(1, Opcode.RUN_APPLICATION, 0, 0, 0))
    sim.replan(module)
    return module, events


def run(shape: Shape, seconds: float, reference: bool) -> tuple[float, tuple[object, ...]]:
    """Wall seconds for ``seconds`` simulated, and the state at the end (to compare)."""
    if shape.embed:
        return run_embedded(shape, seconds, reference)
    sim, module, events = build(shape, reference)
    recorder = Recorder(sim, shape.record_s).start() if shape.record_s else None
    start = time.process_time()
    if shape.step_s:  # the test advances the clock in steps (a lockstep host's sleeps)
        step = round(shape.step_s * NS)
        for _ in range(round(seconds * NS) // step):
            sim.advance_to_ns(sim.now_ns + step)
        sim.advance_to_ns(round(seconds * NS))
    elif shape.host is None:  # nobody acts from outside: one call, as a test would make it
        sim.advance_to_ns(round(seconds * NS))
    else:  # the host acts every simulated second
        whole = int(seconds)
        for second in range(whole):
            sim.advance_to_ns((second + 1) * NS)
            shape.host(sim, module, second)
        if seconds > whole:
            sim.advance_to_ns(round(seconds * NS))
    wall = time.process_time() - start
    samples = recorder.stop() if recorder is not None else []
    return wall, state_of(module, events, samples)


def state_of(module: TMCLModule, events: Events,
             samples: list[Sample]) -> tuple[object, ...]:
    """What both runs must end with: registers, variables, positions, the number of events
    and the last one (a run counted as its events), samples."""
    interp = module.program.interpreter
    axes = tuple(module.axis(i).get_parameter(1) for i in range(len(module.axes)))
    last = None
    if events:
        time_ns, kind, repeat, period_ns = events[-1]
        last = (time_ns + (repeat - 1) * period_ns, kind)
    return (interp.pc, interp.accumulator, interp.executed, module.globals[2][0], axes,
            sum(repeat for _, _, repeat, _ in events), last, len(samples),
            hash(tuple(samples)))


def run_embedded(shape: Shape, seconds: float,
                 reference: bool) -> tuple[float, tuple[object, ...]]:
    """As :func:`run`, the clock advanced through ``SimulatorThread.advance`` from this
    thread (CPU time of the whole process: both threads)."""
    with SimulatorThread(clock="virtual", module_type=shape.kind, axis_core=shape.core,
                         skip_loops=not reference, **shape.endpoints) as thread:
        sim = thread.simulation
        module, events = thread.call(lambda: load(sim, sim.modules[0], shape))
        step = shape.step_s or seconds
        start = time.process_time()
        keywords = shape.advance
        if any(name not in inspect.signature(thread.advance).parameters for name in keywords):
            keywords = {}  # a baseline without them: its plain advance
        for _ in range(round(seconds / step)):
            thread.advance(step, **keywords)
        state = thread.call(lambda: state_of(module, events, []))
        return time.process_time() - start, state


def _compared_run(checkout: str, name: str, seconds: float) -> float:
    """CPU seconds of one skipping run of shape ``name`` on another checkout's code (this
    script's shapes, that checkout's simulator: a child process)."""
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--code", checkout,
                          "--child", "--only", name, "--seconds", str(seconds)],
                         capture_output=True, text=True, check=True)
    return float(out.stdout.split()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=600.0,
                        help="simulated seconds per shape (default 600; six axes: 3600)")
    parser.add_argument("--reference-seconds", type=float, default=5.0,
                        help="simulated seconds of the stepping reference when it is slow "
                             "(default 5; it runs as long as the skipping run when that "
                             "takes less)")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each; the median counts")
    parser.add_argument("--only", default="", help="comma-separated shape names")
    parser.add_argument("--compare", metavar="DIR", action="append", default=[],
                        help="also run each shape's skipping run on another checkout's code "
                             "(a child process, alternating with this one's runs); may be "
                             "given more than once (each baseline in the same runs)")
    parser.add_argument("--compare-cpu", type=float, default=20.0,
                        help="CPU seconds a compared run may take (default 20): where the "
                             "compared code would take longer over the shape's span (it "
                             "steps what this code skips), it runs a shorter span")
    parser.add_argument("--code", metavar="DIR", default=_CODE,
                        help="the checkout whose simulator runs (default: this one; "
                             "--compare's child gets the compared one)")
    parser.add_argument("--child", action="store_true",
                        help="(internal) print the CPU seconds of one skipping run only")
    args = parser.parse_args()
    chosen = {n for n in args.only.split(",") if n}
    if args.child:
        (shape,) = [shape for shape in SHAPES if shape.name in chosen]
        print(run(shape, shape.seconds or args.seconds, False)[0])
        return 0
    for checkout in args.compare:
        if not Path(checkout, "interpreter").is_dir():
            parser.error(f"--compare {checkout}: not a tmcl-sim checkout")
    failed = False
    print(f"code: {args.code}")
    print(f"{'shape':<14} {'skipping':>16} {'stepping':>16} {'ratio':>8}  goal      same state")
    for shape in SHAPES:
        if chosen and shape.name not in chosen:
            continue
        seconds = shape.seconds or args.seconds
        fast = []
        compared: dict[str, list[float]] = {checkout: [] for checkout in args.compare}
        compared_seconds = dict.fromkeys(args.compare, seconds)
        for checkout in args.compare:  # a short run first: how long the whole span would take
            short = min(seconds, args.reference_seconds)
            rate_there = short / _compared_run(checkout, shape.name, short)
            compared_seconds[checkout] = min(seconds,
                                             max(short, round(args.compare_cpu * rate_there)))
        for _ in range(args.repeat):  # alternating with the compared code's runs
            fast.append(run(shape, seconds, False))
            for checkout in args.compare:
                compared[checkout].append(_compared_run(checkout, shape.name,
                                                        compared_seconds[checkout]))
        wall = statistics.median(w for w, _ in fast)
        ref_seconds = min(seconds, args.reference_seconds)
        slow = [run(shape, ref_seconds, True) for _ in range(args.repeat)]
        ref_wall = statistics.median(w for w, _ in slow)
        same = "-"
        if ref_seconds == seconds:
            same = "yes" if fast[0][1] == slow[0][1] else f"NO {fast[0][1]} != {slow[0][1]}"
        else:  # compare the skipping run over the reference's span
            short = run(shape, ref_seconds, False)
            same = "yes" if short[1] == slow[0][1] else f"NO {short[1]} != {slow[0][1]}"
        rate, ref_rate = seconds / wall, ref_seconds / ref_wall
        if shape.wall_goal:
            goal = f"<= {shape.wall_goal} s"
            met = wall <= shape.wall_goal
            shown = f"{wall:.3f} s/{seconds / 3600:.0f} h"
            ref_shown = f"{ref_wall * seconds / ref_seconds:.3f} s/{seconds / 3600:.0f} h"
        else:
            goal = f">= {shape.goal:,.0f} x" if shape.goal else "(none)"
            met = rate >= shape.goal
            shown, ref_shown = f"{rate:,.0f} x", f"{ref_rate:,.1f} x"
        failed |= not met or same != "yes"
        verdict = ("met" if met else "NOT MET") if shape.goal or shape.wall_goal else "-"
        print(f"{shape.name:<14} {shown:>16} {ref_shown:>16} {rate / ref_rate:>7.1f}x  "
              f"{goal:<9} {verdict}; {same}")
        for checkout, times in compared.items():
            base = statistics.median(times) * seconds / compared_seconds[checkout]
            base_shown = (f"{base:.3f} s/{seconds / 3600:.0f} h" if shape.wall_goal
                          else f"{seconds / base:,.0f} x")
            span = ("" if compared_seconds[checkout] == seconds
                    else f", over {compared_seconds[checkout]:g} s")
            print(f"{'':<14} {base_shown:>16}  (skipping, {checkout}, the same runs{span})")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
