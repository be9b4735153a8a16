"""Random parameter combinations against every chip core, with the CPU time of each operation.

Shared by ``tests/tmcl_server/test_bounded_work.py`` (a short seeded run in the suite) and
``scripts/fuzz_work.py`` (long runs, profiles, the worst sequences).  A trial builds a module
on the virtual clock, maybe places or forces a switch or sticks the axis, writes random axis
parameters (range ends and extreme values, motion rows more often), maybe raw chip registers
(command 146), starts motions (MVP, ROL/ROR, RFS) and advances the clock by up to 10 s,
asking for the position on the way.  Each operation's CPU time (``time.process_time``) is
recorded with the operations that led to it.  On the TMC42x cores a trial may also write the
axis's own chip registers with values picked to reach the engine's corners (slow pulse and
ramp dividers, soft stops, V_MIN, far targets) and advance by up to 30 s.

:func:`engine_trial` goes one level down: a TMC42x motor engine put straight into a random
register-level state (any speed, dividers, switch levels, tolerance window, target) and run
for up to 30 s of clk32 ticks the way the firmware runs it (look-aheads with a work budget,
then a catch-up without one).
"""

from __future__ import annotations

import random
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from axes.chips.tmc42x.engine import RampMode
from axes.chips.tmc42x.tmc4210 import TMC4210
from tmcl_server.clock import VirtualClock
from tmcl_server.eeprom import Eeprom
from tmcl_server.module import TMCLModule
from tmcl_server.protocol import Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import ParamSpec

#: (module type, chip core) pairs: every core the simulator has, on the modules it serves.
CORES: list[tuple[str, str | None]] = [
    ("tmcm-6212", None), ("tmcm-1110", None), ("tmcm-6110", None), ("tmcm-6212", "tmc4361a")]
#: Rows that shape the motion (speeds, accelerations, dividers, switches, reference search).
MOTION_PARAMETERS = frozenset({4, 5, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26,
                               27, 28, 31, 130, 135, 138, 140, 149, 153, 154, 193, 194, 195,
                               200, 254, 255})
EXTREMES = (0, 1, -1, 2, 2**31 - 1, -2**31, 2047, 2048, 65535, 1 << 23, -(1 << 23))
ADVANCES = (0.001, 0.1, 1.0, 4.0, 10.0)
#: Advances after raw TMC42x register writes: longer, as slow dividers stretch everything.
LONG_ADVANCES = (0.1, 1.0, 10.0, 30.0)
#: Values for the TMC42x axis registers (IDX -> pool): the engine's corners.
TMC42X_REGISTERS: dict[int, tuple[int, ...]] = {
    0x0: (0, 1, 1000, -1000, 1 << 23, (1 << 23) - 1, (1 << 23) + 1),  # X_TARGET
    0x2: (0, 1, 2, 61, 2047),  # V_MIN
    0x3: (0, 1, 2, 314, 2047),  # V_MAX
    0x4: (0, 2, -2, 1020, -2047),  # V_TARGET
    0x6: (0, 1, 2, 3, 51, 2047),  # A_MAX
    0x9: (0x8000, 0xA602, 0xF60F, 0xFF00, 0xC40B),  # PMUL / PDIV
    0xA: (0, 1, 2, 0x400, 0x401, 0x402, 0xC00, 0xC02, 0x300, 0x700, 0x100),  # REF_CONF / mode
    0xC: (0x0000, 0x3000, 0x6000, 0xC200, 0xE300, 0xF000, 0xF100, 0x9200, 0x8500, 0x0F00),
    0xD: (0, 1, 3, 300, 4095),  # DX_REF_TOLERANCE
}
TMC42X_CORES = frozenset({"tmc4210", "tmc429"})


@dataclass
class Cost:
    """One operation: its CPU seconds (inf: it ran past the limit), what it was, the trial's
    operations up to it, and the trial's number."""

    seconds: float
    label: str
    ops: list[str]
    trial: int


class OverLimit(Exception):
    """An operation ran past the CPU limit (the alarm of :func:`arm_limit`)."""


def arm_limit() -> None:
    """Let :func:`trial` interrupt an operation that passes its CPU limit (main thread)."""

    def _alarm(signum: int, frame: object) -> None:
        raise OverLimit

    signal.signal(signal.SIGPROF, _alarm)


def _value(spec: ParamSpec, rng: random.Random) -> int:
    pool = list(EXTREMES)
    if spec.allowed:
        pool += sorted(spec.allowed)
    else:
        pool += [spec.minimum, spec.maximum, spec.minimum + 1, spec.maximum - 1]
        if spec.maximum - spec.minimum > 2:
            pool.append(rng.randint(spec.minimum, spec.maximum))
    return rng.choice(pool)


def trial(number: int, rng: random.Random, kind: str, core: str | None, directory: Path,
          costs: list[Cost], limit: float | None = None) -> None:
    """One random sequence on a fresh module; every operation's cost goes to ``costs``.
    With ``limit`` (after :func:`arm_limit`) an operation past it raises :class:`OverLimit`."""
    module = TMCLModule(1, Eeprom(directory), kind=kind, chip_core=core)
    sim = Simulation([module], VirtualClock())
    ops: list[str] = []
    params = [s for s in module.type.axis_parameters.values() if s.writable]
    motion = [s for s in params if s.number in MOTION_PARAMETERS]

    def timed(label: str, action: Callable[[], object]) -> None:
        ops.append(label)
        if limit is not None:
            signal.setitimer(signal.ITIMER_PROF, limit)
        start = time.process_time()
        try:
            action()
        except OverLimit:
            costs.append(Cost(float("inf"), label, list(ops), number))
            raise
        finally:
            if limit is not None:
                signal.setitimer(signal.ITIMER_PROF, 0)
        costs.append(Cost(time.process_time() - start, label, list(ops), number))

    def send(op: int, type_: int, motor: int, value: int) -> None:
        value = (value + 2**31) % 2**32 - 2**31
        frame = Request(1, op, type_, motor, value).encode()
        name = Opcode(op).name if op in Opcode._value2member_map_ else str(op)
        timed(f"{kind}/{core} {name} {type_} {motor} {value}",
              lambda: sim.handle_serial_frame(frame))

    motor = rng.randrange(len(module.axes))
    if rng.random() < 0.3:
        side = rng.choice(["left", "right", "home"])
        where = rng.choice([None, 0, 100, -100, 10_000, -10_000])
        if where is None:
            module.force_switch(motor, side, True)
        else:
            module.set_switch(motor, side, where, rng.choice([None, 1, 1000]))
        sim.notify_changed()
        ops.append(f"switch {side} at {'forced' if where is None else where}")
    stuck = rng.random() < 0.1
    if stuck:
        module.set_axis_stuck(motor, True, rng.choice([None, 0]))
        sim.notify_changed()
        ops.append("stuck")
    for _ in range(rng.randint(1, 10)):
        spec = rng.choice(motion if motion and rng.random() < 0.6 else params)
        send(Opcode.SAP, spec.number, motor, _value(spec, rng))
    if rng.random() < 0.3:
        for _ in range(rng.randint(1, 4)):
            send(Opcode.WRITE_MC, rng.randrange(0x80), motor,
                 rng.choice((*EXTREMES, rng.getrandbits(24))))
    advances = ADVANCES
    # (not with a stuck axis: stallGuard2 sampled every ms costs in proportion to the time)
    if module.chip_core in TMC42X_CORES and not stuck and rng.random() < 0.4:
        advances = LONG_ADVANCES
        for _ in range(rng.randint(2, 8)):
            idx = rng.choice(list(TMC42X_REGISTERS))
            send(Opcode.WRITE_MC, idx, motor, rng.choice(TMC42X_REGISTERS[idx]))
    for _ in range(rng.randint(1, 3)):
        choice = rng.random()
        if choice < 0.35:
            send(Opcode.MVP, rng.choice([0, 1]), motor, rng.choice((*EXTREMES, 1000, -1000)))
        elif choice < 0.7:
            send(rng.choice([Opcode.ROR, Opcode.ROL]), 0, motor, rng.choice((*EXTREMES, 1000)))
        elif choice < 0.85:
            send(Opcode.RFS, 0, motor, 0)
        else:
            spec = rng.choice(params)
            send(Opcode.SAP, spec.number, motor, _value(spec, rng))
        for _ in range(rng.randint(1, 3)):
            dt = rng.choice(advances)
            timed(f"advance {dt}", lambda dt=dt: sim.advance(dt))
            send(Opcode.GAP, 1, motor, 0)


def trial_rng(seed: int, number: int) -> random.Random:
    """Trial ``number`` of a run with ``seed``: reproducible alone (``--only``)."""
    return random.Random(seed * 1_000_003 + number)


# -- one level down: a TMC42x motor engine in a random register-level state --------------------

#: clk32 ticks per second at the TMC4210's 16 MHz.
TICKS_PER_S = 500_000
#: The firmware's look-ahead budget (axes/forecast.py LOOKAHEAD_BUDGET).
BUDGET = 2_000


def engine_state(rng: random.Random) -> dict[str, int | bool]:
    """A random state of the motor engine's registers and internal speed (reachable: a speed
    above V_MAX is what lowering V_MAX in flight leaves; switch levels stay put)."""
    return {
        "v_min": rng.choice([0, 1, 2, rng.randrange(2048), 2047]),
        "v_max": rng.choice([0, 1, 2, rng.randrange(2048), 2047]),
        "a_max": rng.choice([0, 1, 2, 3, rng.randrange(2048), 2047]),
        "pmul": rng.randrange(128, 256), "pdiv": rng.randrange(16),
        "pulse_div": rng.randrange(16), "ramp_div": rng.randrange(16),
        "mode": rng.choice(list(RampMode)),
        "ref_conf": rng.choice([0, 0x100, 0x200, 0x300, 0x400, 0x800, 0xC00, 0x700]),
        "x_target": rng.choice([0, 1, -1, 1000, -1000, 1 << 23, rng.getrandbits(24)]) & 0xFFFFFF,
        "x_actual": rng.choice([0, 1, -1, 1000, -1000, rng.getrandbits(24)]) & 0xFFFFFF,
        "v": rng.choice([0, rng.randrange(-2047, 2048) << 8,
                         rng.randrange(-2047 * 256, 2047 * 256)]),
        "v_target": rng.randrange(-2048, 2048),
        "dx_ref_tolerance": rng.choice([0, 1, 3, 300, 4095]),
        "int_mask": rng.choice([0, 0xFF, 4]),
        "right_wired": rng.random() < 0.5,
        "ref_l": rng.random() < 0.3, "ref_r": rng.random() < 0.3,
    }


def engine_for(state: dict[str, int | bool]) -> TMC4210:
    """A TMC4210 (steps out) whose motor engine is in ``state``."""
    chip = TMC4210()
    chip.steps_out = True
    for name, value in state.items():
        setattr(chip, name, value)
    chip.mode = RampMode(state["mode"])
    chip.ramp_next = 1 << chip.ramp_div
    return chip


def run_engine(chip: TMC4210, ticks: int) -> None:
    """What an axis does over ``ticks``: look-aheads with the budget up to the end."""
    until = chip.t + ticks
    while chip.t < until:
        chip.run(until, BUDGET)


def engine_trial(number: int, rng: random.Random, costs: list[Cost],
                 limit: float | None = None) -> None:
    """One random engine state run for up to 30 s in a few advances; each advance's CPU
    time goes to ``costs`` (label: the ticks; ops: the state)."""
    state = engine_state(rng)
    chip = engine_for(state)
    ops = [f"engine {state}"]
    for _ in range(rng.randint(1, 3)):
        ticks = int(rng.choice(LONG_ADVANCES) * TICKS_PER_S)
        ops.append(f"run {ticks}")
        if limit is not None:
            signal.setitimer(signal.ITIMER_PROF, limit)
        start = time.process_time()
        try:
            run_engine(chip, ticks)
        except OverLimit:
            costs.append(Cost(float("inf"), f"run {ticks}", list(ops), number))
            raise
        finally:
            if limit is not None:
                signal.setitimer(signal.ITIMER_PROF, 0)
        costs.append(Cost(time.process_time() - start, f"run {ticks}", list(ops), number))
