"""The TMC42x engine's fast shortcut against its own law, on the whole motor state.

``MotorEngine.run`` (closed forms, batches of ramp ticks, a work budget) must equal
``MotorLaw.step`` (one clk32 tick at a time, :mod:`axes.chips.tmc42x.law`): wherever ``run``
returns, the law stepped to the same tick returns the same ``Stop`` there (and none before),
and every attribute of the motor is the same (position, velocity and its fraction, the
accumulator, V_TARGET, A_ACTUAL, interrupt flags, the latch, the position compare, the
microstep counter, the pins a board drives).  ``tests/axes/test_tmc4210.py`` holds the
engine to the independent reference transcription on positions and velocities; this file
holds it to the product's law on everything, from states anywhere in the register space.
"""

from __future__ import annotations

from collections.abc import Callable
from itertools import accumulate

from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from axes.chips.tmc42x.registers import HALF24, MASK24, Irq, RampMode, Reg
from axes.chips.tmc42x.tmc4210 import TMC4210
from axes.core import ChipModel, Stop
from tests.axes.test_tmc4210 import _Strip

#: Attributes that are the engine's bookkeeping, not the chip's state.
_BOOKKEEPING = {"_work"}


def _state(chip: ChipModel) -> dict:
    return {name: value for name, value in vars(chip).items() if name not in _BOOKKEEPING}


_speeds = st.one_of(st.just(0), st.integers(-(2047 << 8) - 255, (2047 << 8) + 255),
                    st.sampled_from([1, -1, 255, 256, -256, 2047 << 8, -(2047 << 8)]))
_positions = st.one_of(st.integers(-3000, 3000), st.integers(HALF24 - 60, HALF24 + 60),
                       st.integers(-HALF24, HALF24 - 1))
motor_states = st.fixed_dictionaries({
    "v_min": st.one_of(st.sampled_from([0, 1, 2, 2047]), st.integers(0, 2047)),
    "v_max": st.one_of(st.sampled_from([0, 1, 2, 2047]), st.integers(0, 2047)),
    "a_max": st.one_of(st.sampled_from([0, 1, 2, 3, 2047]), st.integers(0, 2047)),
    "pmul": st.integers(128, 255), "pdiv": st.integers(0, 13),
    "pulse_div": st.integers(0, 5), "ramp_div": st.integers(0, 5),
    "mode": st.sampled_from(list(RampMode)),
    "x_actual": _positions, "x_target": _positions, "v": _speeds,
    "v_target": st.integers(-2048, 2047), "acc": st.integers(0, 2047),
    "dx_ref_tolerance": st.sampled_from([0, 1, 3, 300, 4095]),
    "ref_conf": st.integers(0, 15).map(lambda bits: bits << 8),  # disables, soft, ref_RnL
    "int_mask": st.integers(0, 255), "latch_pending": st.booleans(), "usrs": st.integers(0, 7),
    "pos_comp": _positions, "pos_comp_on": st.booleans(), "inv_ref": st.booleans(),
    "right_wired": st.booleans(), "steps_out": st.booleans(), "t": st.integers(0, 300),
})
#: A left and a right switch (levels by position, or None) and marks, near the start.
boards = st.one_of(st.none(), st.builds(
    _Strip, st.one_of(st.none(), st.integers(-3000, 0)), st.one_of(st.none(), st.integers(1, 3000)),
    st.lists(st.integers(-3000, 3000), max_size=6)))
writes = st.one_of(
    st.tuples(st.sampled_from([Reg.X_TARGET, Reg.X_ACTUAL, Reg.POS_COMP]),
              st.integers(-4000, 4000).map(lambda x: x & MASK24)),
    st.tuples(st.sampled_from([Reg.V_MAX, Reg.V_MIN, Reg.A_MAX]), st.integers(0, 2047)),
    st.tuples(st.sampled_from([Reg.V_TARGET, Reg.V_ACTUAL]), st.integers(0, 0xFFF)),
    st.tuples(st.just(Reg.REF_CONF_RAMP_MODE), st.integers(0, 0xFFF)),
    st.tuples(st.just(Reg.DIVIDERS), st.builds(lambda p, r: p << 12 | r << 8,
                                               st.integers(0, 5), st.integers(0, 5))),
    st.tuples(st.just(Reg.INTERRUPT), st.integers(0, 0xFFFF)),
    st.tuples(st.sampled_from([Reg.X_LATCHED, Reg.POWER_DOWN]), st.just(0)),
)
#: (clk32 ticks to run, work budget or None, a register write after it or None)
steps = st.lists(st.tuples(st.one_of(st.integers(1, 40), st.integers(1, 6000)),
                           st.one_of(st.none(), st.integers(1, 6)),
                           st.one_of(st.none(), writes)), min_size=1, max_size=5)


def _chip(state: dict, board: _Strip | None) -> TMC4210:
    chip = TMC4210(board=board)
    for name, value in state.items():
        setattr(chip, name, value)
    chip.x_actual &= MASK24
    chip.x_target &= MASK24
    chip.pos_comp &= MASK24
    chip.ramp_next = (chip.t >> chip.ramp_div) + 1 << chip.ramp_div
    chip._refresh_pins()
    return chip


def run_beside_the_law(chip: ChipModel, law: ChipModel, until: int, budget: int | None,
                       state: Callable[[ChipModel], dict]) -> None:
    """Run ``chip`` to ``until`` (on a work ``budget``) and, at each return of ``run`` (a stop,
    the budget spent, or ``until``), step ``law`` (its copy) to the same tick by the law:
    the same ``Stop`` there and none before, the same ``state``.  (Both chips' tests.)"""
    while chip.t < until:
        stop = chip.run(until, budget)
        assert chip.t <= until
        assert law.step(chip.t) is stop, f"at tick {chip.t}"
        assert law.t == chip.t
        assert state(law) == state(chip), f"at tick {chip.t}"


def _hold_equal(state: dict, board: _Strip | None, script: list) -> None:
    chip = _chip(state, board)
    law = chip.clone()
    for ticks, budget, write in script:
        run_beside_the_law(chip, law, chip.t + ticks, budget, _state)
        if write is not None:
            chip.write(*write)
            law.write(*write)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(state={"v_min": 2, "v_max": 300, "a_max": 3, "pmul": 236, "pdiv": 4, "pulse_div": 5,
                "ramp_div": 0, "mode": RampMode.RAMP, "x_actual": 5, "x_target": HALF24 + 4,
                "v": -401664, "v_target": 0, "acc": 0, "dx_ref_tolerance": 0, "ref_conf": 0,
                "int_mask": 0xFF, "latch_pending": False, "usrs": 0, "pos_comp": 0,
                "pos_comp_on": False, "inv_ref": False, "right_wired": False, "steps_out": True,
                "t": 0}, board=None, script=[(6000, None, None)])  # a target 2**23 - 1 behind
@example(state={"v_min": 61, "v_max": 2047, "a_max": 2, "pmul": 166, "pdiv": 2, "pulse_div": 3,
                "ramp_div": 0, "mode": RampMode.VELOCITY, "x_actual": 2000, "x_target": 0,
                "v": 510464, "v_target": 1020, "acc": 0, "dx_ref_tolerance": 3, "ref_conf": 0x400,
                "int_mask": 0xFF, "latch_pending": True, "usrs": 2, "pos_comp": 0,
                "pos_comp_on": True, "inv_ref": False, "right_wired": True, "steps_out": True,
                "t": 0}, board=_Strip(None, 2200, [2100]),
         script=[(6000, 3, None), (6000, None, None)])  # a soft stop at a switch, on a budget
@example(state={"v_min": 5, "v_max": 900, "a_max": 300, "pmul": 200, "pdiv": 3, "pulse_div": 0,
                "ramp_div": 2, "mode": RampMode.RAMP, "x_actual": 0, "x_target": 3000,
                "v": 0, "v_target": 0, "acc": 0, "dx_ref_tolerance": 0, "ref_conf": 0,
                "int_mask": 0, "latch_pending": False, "usrs": 0, "pos_comp": 0,
                "pos_comp_on": False, "inv_ref": False, "right_wired": False, "steps_out": True,
                "t": 0}, board=None, script=[(5, 1, None), (1, 1, None), (3, 1, None),
                                             (40, 2, None), (6000, 1, None)])
@example(state={"v_min": 0, "v_max": 2047, "a_max": 2047, "pmul": 128, "pdiv": 0, "pulse_div": 0,
                "ramp_div": 0, "mode": RampMode.RAMP, "x_actual": 0, "x_target": 2, "v": 0,
                "v_target": 0, "acc": 0, "dx_ref_tolerance": 0, "ref_conf": 0, "int_mask": 0,
                "latch_pending": False, "usrs": 0, "pos_comp": 0, "pos_comp_on": False,
                "inv_ref": False, "right_wired": False, "steps_out": False, "t": 0},
         board=None, script=[(29, 1, None)])  # a batch that holds the speed: A_ACTUAL 0
@given(state=motor_states, board=boards, script=steps)
def test_run_is_the_law_ticked_clock_by_clock(state: dict, board: _Strip | None,
                                              script: list) -> None:
    """Any register state (12-bit speeds and their fractions, V_MIN above V_MAX, A_MAX 0, hold
    mode, targets across the 24-bit wrap), switches ahead or behind, hard or soft, inside or
    outside the tolerance window, board marks, interrupts and the latch armed, any dividers,
    odd tick counts and small work budgets, register writes between runs: ``run`` lands where
    the law's ticks do, on every attribute, and stops where they stop."""
    _hold_equal(state, board, script)


def test_a_run_cut_short_by_its_budget_leaves_the_laws_state() -> None:
    """A single ramp tick taken the plain way leaves ``t`` one tick short of it; a run whose
    budget ends there finishes that tick, so the state it returns is the law's at ``t``.  It
    used to hold the tick's new velocity one tick early (here at clk32 tick 1150 of a
    one-step move): a look-ahead cut by its budget, adopted, showed it to a read."""
    chip = _chip({"v_max": 2047, "v_min": 5, "a_max": 1, "pmul": 200, "pdiv": 3,
                  "x_target": 1, "steps_out": True}, None)
    law = chip.clone()
    stop = None
    while stop is None:
        stop = chip.run(10**6, budget=1)
        assert law.step(chip.t) is stop
        assert (chip.t, chip.v, chip.x_actual) == (law.t, law.v, law.x_actual)
        assert _state(chip) == _state(law)
    assert stop is Stop.ARRIVED and chip.x_actual == 1


def test_a_actual_after_ticks_that_hold_the_speed_is_zero() -> None:
    """Ticks that hold the speed on a flat stretch of the curve (here V_TARGET 22 for a move of
    one step) write A_ACTUAL 0, as the law's last tick does; a batch of them used to leave
    the A_ACTUAL of the tick before (1538 here, on the code before the law was split out)."""
    chip = _chip({"v_max": 2047, "a_max": 2047, "pmul": 128, "pdiv": 6, "x_target": 1}, None)
    law = chip.clone()
    assert chip.run(5) is None and law.step(5) is None
    assert chip.v == law.v == 22 << 8
    assert chip.read(Reg.A_ACTUAL) == law.read(Reg.A_ACTUAL) == 0


def test_the_laws_ticks_stop_where_a_move_ends() -> None:
    """The law itself: a positioning move ends at its target with POS_END (ARRIVED), a hard
    switch ahead stops the motor at the step it turns active (MARK, then rest)."""
    chip = _chip({"v_max": 900, "v_min": 40, "a_max": 300, "pmul": 200, "pdiv": 3,
                  "x_target": 700, "int_mask": 0xFF, "steps_out": True}, None)
    while (stop := chip.step(10**6)) is None:
        pass
    assert stop is Stop.ARRIVED and chip.x_actual == 700 and chip.v == 0
    assert chip.int_flags & 1 << Irq.POS_END
    walled = _chip({"v_max": 900, "v_min": 40, "a_max": 300, "pmul": 200, "pdiv": 3,
                    "x_target": 700, "right_wired": True, "steps_out": True},
                   _Strip(None, 400, []))
    assert walled.step(10**6) is Stop.MARK
    assert walled.motor_position == 399 and walled.v != 0  # the edge before the switch
    assert walled.step(10**6) is Stop.MARK
    assert walled.motor_position == 400 and walled.v == 0  # active: a hard stop at once


def _hold_readings(state: dict, board: _Strip | None, ticks: list[int]) -> list[int]:
    """``readings`` at ``ticks`` (ascending, none before the motor's present): the motor
    unchanged, and each reading the law's (X_ACTUAL and V_ACTUAL), the law's ticks stopping
    nowhere on the way."""
    chip = _chip(state, board)
    before = _state(chip)
    positions, v_bits = chip.readings(iter(ticks))
    assert _state(chip) == before  # nothing ran, nothing was read
    assert len(positions) == len(v_bits) <= len(ticks)
    law = chip.clone()
    for tick, position, bits in zip(ticks, positions, v_bits, strict=False):  # a prefix
        assert law.step(tick) is None, f"a notable instant before tick {tick}"
        assert (law.t, law.x_actual, law.v_actual & 0xFFF) == (tick, position, bits)
    return positions


def _ticks_after(start: int, offsets: list[int]) -> list[int]:
    return list(accumulate(offsets, initial=start))[1:]


#: A cruise in velocity mode at V 1000 (PULSE_DIV 2): X_ACTUAL across its 24-bit wrap.
_CRUISE = {"v_min": 0, "v_max": 1000, "a_max": 10, "pmul": 128, "pdiv": 0, "pulse_div": 2,
           "ramp_div": 3, "mode": RampMode.VELOCITY, "x_actual": MASK24 - 40, "x_target": 0,
           "v": 1000 << 8, "v_target": 1000, "acc": 2000, "dx_ref_tolerance": 0,
           "ref_conf": 0, "int_mask": 0, "latch_pending": False, "usrs": 0, "pos_comp": 0,
           "pos_comp_on": False, "inv_ref": False, "right_wired": False, "steps_out": True,
           "t": 5}


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(state=_CRUISE, board=None, offsets=[0, 1, 3, 7, 101, 4095, 3])
@example(state={**_CRUISE, "mode": RampMode.RAMP, "x_target": 200, "v": -(1000 << 8)},
         board=None, offsets=[1] * 12)  # a ramp move: only up to the next ramp tick
@example(state={**_CRUISE, "x_actual": 3, "pos_comp_on": True, "pos_comp": 40, "int_mask": 0xFF,
                "x_target": 0}, board=_Strip(None, None, [30]), offsets=[3] * 150)  # marks ahead
@example(state={**_CRUISE, "mode": RampMode.RAMP, "x_actual": 0, "x_target": 11400,
                "v_max": 300, "v": 300 << 8, "v_target": 300, "pmul": 255, "pdiv": 13},
         board=None, offsets=[40] * 200)  # at V_MAX, then braking for the target
@given(state=motor_states, board=boards,
       offsets=st.lists(st.one_of(st.integers(0, 40), st.integers(0, 6000)), min_size=1,
                        max_size=12))
def test_readings_are_the_laws_positions_and_speeds(state: dict, board: _Strip | None,
                                                    offsets: list[int]) -> None:
    """A recorder's samples at once (MotorEngine.readings): from any register state (ramps,
    hold mode, A_MAX 0, switches and their tolerance window, marks, the compare position,
    REF_MISS, targets across the 24-bit wrap) and at any ticks (odd ones, repeated ones),
    every X_ACTUAL and V_ACTUAL it gives is the law's at its tick, no notable instant lies
    before it, and the motor is left as it was."""
    _hold_readings(state, board, _ticks_after(state["t"], offsets))


def test_steady_readings_give_a_whole_cruise_across_the_wrap() -> None:
    """Not a vacuous prefix: a cruise gives every tick asked, X_ACTUAL wrapping past 2**24."""
    positions = _hold_readings(_CRUISE, None, _ticks_after(5, [0, 1, 3, 7, 101, 4095, 3, 9000]))
    assert len(positions) == 8
    assert positions[0] > HALF24 > positions[-1]  # through the wrap


#: States on a full-A_MAX slew, or near one: starting from rest or at speed, towards a
#: velocity-mode target (up, down, through zero) or a far positioning target (up to V_MAX,
#: or until the curve takes over), with slow and fast dividers both ways round.
slew_states = st.fixed_dictionaries({
    "v_min": st.one_of(st.just(0), st.integers(0, 60), st.just(2047)),
    "v_max": st.one_of(st.sampled_from([1, 255, 256, 2047]), st.integers(1, 2047)),
    "a_max": st.one_of(st.sampled_from([1, 2, 255, 256, 257, 2047]), st.integers(1, 2047)),
    "pmul": st.integers(128, 255), "pdiv": st.integers(0, 13),
    "pulse_div": st.integers(0, 6), "ramp_div": st.integers(0, 6),
    "mode": st.sampled_from([RampMode.RAMP, RampMode.SOFT, RampMode.VELOCITY]),
    "x_actual": _positions,
    "x_target": st.one_of(_positions, st.integers(-HALF24, HALF24 - 1)),
    "v": st.one_of(st.just(0), _speeds, st.integers(-3000, 3000)),
    "v_target": st.one_of(st.integers(-2048, 2047), st.sampled_from([0, 1, -1, 2047, -2048])),
    "acc": st.integers(0, 2047),
    "dx_ref_tolerance": st.sampled_from([0, 300]),
    "ref_conf": st.sampled_from([0, 0x400, 0x300]),  # hard, soft, both stops off
    "int_mask": st.sampled_from([0, 0xFF]), "latch_pending": st.booleans(),
    "usrs": st.integers(0, 7), "pos_comp": _positions, "pos_comp_on": st.booleans(),
    "inv_ref": st.just(False), "right_wired": st.booleans(), "steps_out": st.booleans(),
    "t": st.integers(0, 300),
})
#: Sample ticks: (gap, where it lands: anywhere, on a ramp tick, on a pulse tick, or the tick
#: before either), the gaps short and long.
sample_gaps = st.lists(st.tuples(st.one_of(st.integers(0, 40), st.integers(0, 3000),
                                           st.integers(0, 60_000)),
                                 st.sampled_from(["free", "ramp", "pulse", "ramp-1", "pulse-1"])),
                       min_size=1, max_size=40)


def _aligned_ticks(state: dict, gaps: list[tuple[int, str]]) -> list[int]:
    """The ticks ``gaps`` say, each moved onto the ramp or pulse grid (or just before it)."""
    tick = state["t"]
    ticks = []
    for gap, where in gaps:
        tick += gap
        if where != "free":
            grain = 1 << state["ramp_div" if where.startswith("ramp") else "pulse_div"]
            aligned = -(-tick // grain) * grain - where.endswith("-1")
            tick = max(tick, aligned)
        ticks.append(tick)
    return ticks


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@example(state={**_CRUISE, "v": 0, "v_target": 1000, "x_actual": MASK24 - 400, "a_max": 3,
                "ramp_div": 0, "pulse_div": 0}, board=None,
         gaps=[(97, "free")] * 40)  # from rest to speed, across the wrap, onto the target
@example(state={**_CRUISE, "v": 0, "mode": RampMode.RAMP, "x_actual": 0, "x_target": 900_000,
                "v_max": 2047, "a_max": 1, "ramp_div": 2, "pulse_div": 5}, board=None,
         gaps=[(1, "ramp"), (0, "ramp-1"), (1, "pulse")] * 10)  # PULSE_DIV > RAMP_DIV
@example(state={**_CRUISE, "v": -(500 << 8), "v_target": 200, "a_max": 700, "ramp_div": 5,
                "pulse_div": 1}, board=None, gaps=[(31, "ramp")] * 30)  # down through zero
@given(state=slew_states, board=boards, gaps=sample_gaps)
def test_readings_across_a_slew_are_the_laws(state: dict, board: _Strip | None,
                                              gaps: list[tuple[int, str]]) -> None:
    """The readings of a ramp (the speed moving by A_MAX each ramp tick, up or down, onto
    V_MAX or a velocity-mode target and held there, or until the positioning curve takes
    over), at ticks on the ramp and pulse grid and just before it, are the law's, with
    switches, marks, the compare position and REF_MISS on the way."""
    _hold_readings(state, board, _aligned_ticks(state, gaps))


def test_a_whole_acceleration_is_read_at_once() -> None:
    """Not a vacuous prefix: a move from rest gives every sample of its acceleration to V_MAX
    (each with its own speed) and of the cruise after it, up to the ramp tick where braking
    along the curve begins (the plain path reads there); a rotation's slew down through
    zero gives every sample short of its last 1/256 of speed."""
    move = {**_CRUISE, "v": 0, "mode": RampMode.RAMP, "x_actual": MASK24 - 5000,
            "x_target": 50_000, "v_max": 2000, "a_max": 40, "ramp_div": 4, "pulse_div": 3,
            "pmul": 200, "pdiv": 6, "acc": 0}
    law = _chip(move, None)
    while law.step(law.t + 16) is None and law.v >= law.a_actual >= 0:  # ramp tick by tick
        pass
    braking = law.t  # the first ramp tick whose speed falls (V_MAX after 204,800 ticks)
    assert 400_000 < braking < 600_000
    ticks = _ticks_after(5, [1600] * 400)
    given = _hold_readings(move, None, ticks)
    assert len(given) == sum(tick < braking for tick in ticks)
    assert given[0] > HALF24 > given[-1]  # X_ACTUAL across its wrap
    speeds = _chip(move, None).readings(iter(ticks))[1]
    assert len(set(speeds[:128])) == 128  # a speed per sample on the way up
    turning = {**_CRUISE, "v": 900 << 8, "v_target": -900, "a_max": 256, "ramp_div": 3}
    readings = _hold_readings(turning, None, _ticks_after(5, [1] * 8 * 901))
    assert len(readings) == 8 * 900 - 6  # ticks 6.. up to the ramp tick (8 * 900) that sets 0
