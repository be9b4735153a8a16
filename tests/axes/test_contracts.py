"""The contracts every chip core keeps (axes/interface.py, axes/core.py), checked on each entry of
CHIP_CORES: what its axes, chips and drivers are, that nothing abstract is left, and one common
behaviour (commands, time, the rig around the axis).  A new core is covered by its line in
CHIP_CORES alone.
"""

from __future__ import annotations

import inspect
from functools import cache

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from axes.core import ChipDriver, ChipModel, MotorDriverLink
from axes.cores import CHIP_CORES, axis_class, make_axes, make_axis
from axes.firmware import AxisFirmware
from axes.interface import Axis, AxisControl, AxisEvent, AxisEventKind, AxisRig, AxisStatus
from axes.world import INFINITY, AxisWorld, LoadZone, Switch
from tmcl_spec.modules import DEFAULT_MODULE_TYPE, MODULE_TYPES, ModuleType, module_type
from tmcl_spec.numbers import NS_PER_S
from tmcl_spec.parameters import AP

CORES = sorted(CHIP_CORES)
#: ROR speed and MVP distance every core reaches in a few simulated seconds with its module
#: type's defaults (pps, or the TMC429 modules' register units: a few thousand pps there too).
SPEED = 1000
DISTANCE = 3000


@cache
def profile(core: str) -> ModuleType:
    """The module type that runs ``core`` with the most axes; a core no module type names
    runs a TMCL module's axes (``--axis-core``): the default module type's."""
    users = [module_type(key) for key in MODULE_TYPES if module_type(key).chip_core == core]
    return max(users, key=lambda t: t.number_of_axes) if users else module_type(DEFAULT_MODULE_TYPE)


def build(core: str) -> list[Axis]:
    kind = profile(core)
    return make_axes(core, kind.number_of_axes, kind.axis_parameters)


def one_axis(core: str, world: AxisWorld | None = None) -> Axis:
    return make_axis(core, 0, profile(core).axis_parameters, world=world)


def implements_everything(obj: object, *contracts: type) -> None:
    """No abstract member is left, and the attributes the contracts declare are set."""
    cls = type(obj)
    assert not inspect.isabstract(cls), f"{cls.__name__} leaves {sorted(cls.__abstractmethods__)}"
    for contract in contracts:
        assert isinstance(obj, contract), f"{cls.__name__} is no {contract.__name__}"
        for name in contract.__abstractmethods__:
            member = inspect.getattr_static(cls, name)
            assert not getattr(member, "__isabstractmethod__", False), f"{cls.__name__}.{name}"
        for name in inspect.get_annotations(contract):
            if not name.startswith("_"):
                assert hasattr(obj, name), f"{cls.__name__} has no {name} ({contract.__name__})"


def advance(axis: Axis, now: int, until: int) -> list[AxisEvent]:
    """From ``now`` to ``until`` from event to event, as the module does; no event is dated
    after the time it was asked for."""
    events: list[AxisEvent] = []
    for _ in range(100_000):
        due = axis.next_event_ns()
        if due is None or due > until:
            break
        now = max(due, now)
        batch = axis.advance_to(now)
        assert all(event.time_ns <= now for event in batch)
        events += batch
    else:
        pytest.fail("the axis never stops asking for the same instant")
    events += axis.advance_to(until)
    assert all(event.time_ns <= until for event in events)
    return events


def test_every_core_is_an_axis_class() -> None:
    for core in CORES:
        assert issubclass(axis_class(core), Axis)


@pytest.mark.parametrize("core", CORES)
def test_a_cores_axes_chips_and_drivers_are_the_contracts(core: str) -> None:
    axes = build(core)
    assert [axis.index for axis in axes] == list(range(profile(core).number_of_axes))
    for axis in axes:
        implements_everything(axis, Axis, AxisControl, AxisRig)
        chip = axis.chip  # type: ignore[attr-defined]  # every core has one; not part of Axis
        implements_everything(chip, ChipModel)
        assert chip.clock_hz > 0 and isinstance(chip.t, int) and isinstance(chip.motor_position, int)
        if isinstance(axis, AxisFirmware):
            implements_everything(axis.driver, ChipDriver)
            assert axis.driver.chip is chip
            assert axis.driver.lookahead_ns > 0
            link = axis.driver.motor_driver
            if link is not None:
                implements_everything(link, MotorDriverLink)


@pytest.mark.parametrize("core", CORES)
def test_a_rotation_moves_and_a_move_reaches_its_target_on_the_time_given(core: str) -> None:
    axis = one_axis(core)
    axis.advance_to(0)
    axis.rotate(SPEED)
    advance(axis, 0, NS_PER_S)
    assert axis.get_parameter(AP.ACTUAL_POSITION) > 0
    axis.stop()
    advance(axis, NS_PER_S, 10 * NS_PER_S)
    start = axis.get_parameter(AP.ACTUAL_POSITION)
    target = start + DISTANCE
    axis.move_to(target)
    events = advance(axis, 10 * NS_PER_S, 40 * NS_PER_S)
    assert axis.get_parameter(AP.ACTUAL_POSITION) == target
    assert axis.status().position == target
    if isinstance(axis, AxisFirmware):  # the TMCL firmware tells; the evaluation board has no events
        assert [e.kind for e in events].count(AxisEventKind.TARGET_REACHED) == 1
    axis.emergency_stop()
    assert axis.reference_search(2) == 0
    assert isinstance(axis.register_access(0x01), int)
    axis.reset_board()  # the evaluation board's re-detection; nothing on a TMCL module
    assert axis.next_event_ns() is None or axis.next_event_ns() >= 40 * NS_PER_S


def rig(core: str, call, *args) -> bool:
    """Call a rig method: it works (True), or the core says clearly it cannot (False)."""
    try:
        call(*args)
    except ValueError as error:
        assert core in str(error), f"{call.__name__}: {error} (names no core)"
        return False
    return True


@pytest.mark.parametrize("core", CORES)
def test_every_rig_method_works_on_every_core(core: str) -> None:
    axis = one_axis(core, AxisWorld(free_load=300))
    axis.advance_to(0)
    assert axis.world.free_load == 300
    assert isinstance(axis.status(), AxisStatus)

    axis.rotate(SPEED)
    advance(axis, 0, NS_PER_S)
    if rig(core, axis.set_stuck, True):
        before = axis.status()
        advance(axis, NS_PER_S, 2 * NS_PER_S)
        after = axis.status()
        assert after.position != before.position  # the chip counts on ...
        assert after.mechanical_position == before.mechanical_position  # ... the mechanics stay
        rig(core, axis.set_stuck, False)
        advance(axis, 2 * NS_PER_S, 3 * NS_PER_S)
        assert axis.status().mechanical_position != after.mechanical_position
    axis.stop()
    advance(axis, 3 * NS_PER_S, 13 * NS_PER_S)
    if rig(core, axis.place_mechanics, 12_345):
        assert axis.status().mechanical_position == 12_345

    # switches last: on the TMC4361A a stop event latched at standstill blocks motion toward
    # that side until the firmware next reads EVENTS (docs/motion.md, "The TMC4361A core")
    if rig(core, axis.set_switch, "left", Switch(-INFINITY, INFINITY)):
        assert axis.status().left_switch
        rig(core, axis.set_switch, "left", None)
        assert not axis.status().left_switch
    if rig(core, axis.break_switch, "right", True):
        assert axis.status().right_switch
        rig(core, axis.break_switch, "right", None)
        assert not axis.status().right_switch
    zones = [LoadZone(100, 200, 0)]
    if rig(core, axis.set_load, zones, 500):
        assert axis.world.load_zones == zones and axis.world.free_load == 500
    if rig(core, axis.set_encoder_slip, 0.25):
        assert axis.world.encoder_slip == 0.25
    with pytest.raises(ValueError, match="slip"):
        axis.set_encoder_slip(1.5)
    world = AxisWorld(switches={"home": Switch(-INFINITY, INFINITY)})
    if rig(core, axis.set_world, world):
        assert axis.world is world and axis.status().home_switch


#: Where each core's AP 1 wraps (the TMC429 modules count 24 bits, the others 32).
_WRAPS = {"tmc429": 1 << 23}


@pytest.mark.parametrize("core", CORES)
@settings(max_examples=15, deadline=None)
@given(speed=st.sampled_from([SPEED, -SPEED, 7 * SPEED, 1]), step_ns=st.integers(1, 3_000_000),
       count=st.integers(1, 60), offset_ns=st.integers(0, 10_000_000))
def test_samples_at_once_are_the_samples_one_by_one(core: str, speed: int, step_ns: int,
                                                    count: int, offset_ns: int) -> None:
    """Axis.samples_at (a recorder's samples of a steady stretch at once): each is what
    bringing the axis to its instant and sampling reads, AP 1 across the position's wrap
    (the firmware's 32-bit count, 24 bits on the TMC429 modules), at odd instants; and the
    axis goes on as if it had been sampled one by one."""
    wrap = _WRAPS.get(core, 1 << 31)
    start = wrap - 300 if speed > 0 else -wrap + 300
    twins = [one_axis(core), one_axis(core)]
    for axis in twins:
        axis.advance_to(0)
        axis.rotate(speed)
        advance(axis, 0, NS_PER_S)  # at speed (or still ramping at 7,000)
        axis.set_parameter(AP.ACTUAL_POSITION, start)  # short of the wrap
        axis.sample()  # as a recorder's first instant: the chip brought to the present
    _sampled_at_once_and_one_by_one(twins, NS_PER_S + offset_ns, step_ns, count)


def _sampled_at_once_and_one_by_one(twins: list[Axis], first: int, step_ns: int,
                                    count: int) -> list:
    """``samples_at`` on the first twin, each sample the second's brought to its instant and
    sampled, and both going on alike afterwards (events, status, AP 1)."""
    at_once, one_by_one = twins
    given = at_once.samples_at(first, step_ns, count)
    assert len(given) <= count
    for k, sample in enumerate(given):
        assert one_by_one.advance_to(first + k * step_ns) == []
        assert one_by_one.sample() == sample, k
    later = first + count * step_ns + 1_000_000
    events = [advance(axis, first, later) for axis in twins]
    assert events[0] == events[1]
    assert at_once.status() == one_by_one.status()
    assert at_once.get_parameter(AP.ACTUAL_POSITION) == one_by_one.get_parameter(
        AP.ACTUAL_POSITION)
    return given


def _ramp_ahead(axis: Axis, kind: str, sign: int, wrap: int) -> None:
    """A ramp under way: from rest towards the position's wrap, a reversal through zero, a
    stop (each started at 1 s), or a long positioning move (up, cruise, the curve)."""
    axis.advance_to(0)
    if kind == "rotate":
        axis.set_parameter(AP.ACTUAL_POSITION, sign * (wrap - 300))
        advance(axis, 0, NS_PER_S)
        axis.rotate(sign * 2 * SPEED)
    elif kind == "move":
        _long_brake(axis, sign * 40 * DISTANCE)
        advance(axis, 0, NS_PER_S)
    else:
        axis.rotate(sign * 3 * SPEED)
        advance(axis, 0, NS_PER_S)
        if kind == "reverse":
            axis.rotate(-sign * 3 * SPEED)
        else:
            axis.stop()
    advance(axis, NS_PER_S, _RAMPING)  # past the firmware's timer after a command
    axis.sample()  # as a recorder's first instant: the chip brought to the present


#: Where _ramp_ahead leaves the axis: 5 ms into the ramp.
_RAMPING = NS_PER_S + 5_000_000


@pytest.mark.parametrize("core", CORES)
@settings(max_examples=12, deadline=None)
@given(kind=st.sampled_from(["rotate", "move", "reverse", "stop"]), sign=st.sampled_from([1, -1]),
       step_ns=st.one_of(st.integers(1, 3_000_000), st.just(1_000_000)),
       count=st.integers(1, 400), offset_ns=st.integers(0, 3_000_000))
def test_samples_at_once_through_ramps_are_the_samples_one_by_one(
        core: str, kind: str, sign: int, step_ns: int, count: int, offset_ns: int) -> None:
    """Axis.samples_at through ramps (a TMC42x core reads a linear slew in closed form, a
    speed per sample; the rest the plain way): the same samples as one by one, AP 1 across
    its wrap while the axis accelerates, a reversal through zero, a stop, a positioning
    move's acceleration, cruise and braking."""
    wrap = _WRAPS.get(core, 1 << 31)
    twins = [one_axis(core), one_axis(core)]
    for axis in twins:
        _ramp_ahead(axis, kind, sign, wrap)
    _sampled_at_once_and_one_by_one(twins, _RAMPING + offset_ns, step_ns, count)


@pytest.mark.parametrize("core", ["tmc4210", "tmc429"])
def test_an_acceleration_is_sampled_at_once_across_the_wrap(core: str) -> None:
    """Not a vacuous prefix: on the TMC42x cores a rotation's acceleration from rest gives
    every instant (each its own speed, rising), the position through its wrap."""
    wrap = _WRAPS.get(core, 1 << 31)
    twins = [one_axis(core), one_axis(core)]
    for axis in twins:
        _ramp_ahead(axis, "rotate", 1, wrap)
    given = _sampled_at_once_and_one_by_one(twins, _RAMPING + 1, 1_000_003, 200)
    assert len(given) == 200
    assert given[0].position > 0 > given[-1].position
    speeds = [sample.velocity for sample in given]
    assert speeds == sorted(speeds) and len(set(speeds)) > 10  # (at speed after 13-36 ms)


@pytest.mark.parametrize("core", ["tmc4210", "tmc429"])
def test_a_steady_rotation_is_sampled_at_once_across_the_wrap(core: str) -> None:
    """Not a vacuous prefix: on the TMC42x cores a rotation at speed gives every instant,
    the position through its wrap."""
    wrap = _WRAPS.get(core, 1 << 31)
    axis = one_axis(core)
    axis.advance_to(0)
    axis.rotate(SPEED)
    advance(axis, 0, NS_PER_S)
    axis.set_parameter(AP.ACTUAL_POSITION, wrap - 300)
    axis.sample()
    given = axis.samples_at(NS_PER_S + 1, 1_000_003, 900)
    assert len(given) == 900
    assert given[0].position > 0 > given[-1].position


#: The cores whose axes run the TMCL firmware layer (the evaluation board has no forecast).
FIRMWARE_CORES = [core for core in CORES if issubclass(axis_class(core), AxisFirmware)]


def _long_brake(axis: Axis, target: int = 400 * DISTANCE) -> None:
    """A move whose ramps outlast a look-ahead's work budget (fast, gently accelerated)."""
    axis.advance_to(0)
    axis.set_parameter(AP.MAX_SPEED, axis.get_parameter(AP.MAX_SPEED) * 4)
    axis.set_parameter(AP.MAX_ACCELERATION, max(1, axis.get_parameter(AP.MAX_ACCELERATION) // 8))
    axis.move_to(target)


@pytest.mark.parametrize("core", FIRMWARE_CORES)
@settings(max_examples=8, deadline=None)
@given(levels=st.lists(st.integers(-10, 1000), min_size=1, max_size=6),
       pause_ms=st.integers(0, 400))
def test_a_read_where_a_search_ended_goes_on_from_its_copy_as_the_chip_itself(
        core: str, levels: list[int], pause_ms: int) -> None:
    """F9 (axes/forecast.py): a program polling a positioning move's speed (AP 3 against a
    level, in per mille of the top speed) sleeps until the forecast's answer; the read there
    brings the chip on from the search's last copy, and reads, events and the state are
    those of an axis that runs the whole way itself."""
    taken, plain = one_axis(core), one_axis(core)
    assert isinstance(taken, AxisFirmware) and isinstance(plain, AxisFirmware)
    plain.forecast.copy_on_the_way = lambda since, until: None  # type: ignore[method-assign]
    for axis in (taken, plain):
        _long_brake(axis)
    top = taken.get_parameter(AP.MAX_SPEED)
    now = pause_ms * 1_000_000
    for level in levels * 3:
        seen = []
        for axis in (taken, plain):
            events = advance(axis, 0 if now == pause_ms * 1_000_000 else now, now)
            speed = axis.get_parameter(AP.ACTUAL_SPEED)
            axis.steady_until(AP.ACTUAL_SPEED)  # a moving read: kept for the search
            seen.append((events, speed, axis.first_time_at(
                AP.ACTUAL_SPEED, (top * level // 1000,), now)))
        assert seen[0] == seen[1]
        answer = seen[0][2]
        if not now < answer < 90 * NS_PER_S:
            break  # (no promise, or none before the end)
        after = [(advance(axis, now, answer), axis.get_parameter(AP.ACTUAL_POSITION),
                  axis.get_parameter(AP.ACTUAL_SPEED), axis.status())
                 for axis in (taken, plain)]
        assert after[0] == after[1], answer
        now = answer
    end = [(advance(axis, now, 90 * NS_PER_S), axis.status()) for axis in (taken, plain)]
    assert end[0] == end[1]


@pytest.mark.parametrize("core", FIRMWARE_CORES)
def test_a_polled_brake_goes_on_from_the_searchs_copies(core: str) -> None:
    """Not a vacuous F9: the polls of the test above through a whole move (the speed below
    its top, then at 0) take copies on every core (that test compares what they give)."""
    axis = one_axis(core)
    assert isinstance(axis, AxisFirmware)
    taken = []
    offer = axis.forecast.copy_on_the_way

    def counted(since: int, until: int) -> ChipModel | None:
        copy = offer(since, until)
        taken.append(copy is not None)
        return copy

    axis.forecast.copy_on_the_way = counted  # type: ignore[method-assign]
    _long_brake(axis)
    now = NS_PER_S // 10
    for level in [900, 0] * 4:
        advance(axis, now, now)
        axis.get_parameter(AP.ACTUAL_SPEED)
        axis.steady_until(AP.ACTUAL_SPEED)
        answer = axis.first_time_at(AP.ACTUAL_SPEED, (axis.get_parameter(AP.MAX_SPEED) * level
                                                      // 1000,), now)
        if not now < answer < 90 * NS_PER_S:
            break
        now = answer
    assert any(taken)
