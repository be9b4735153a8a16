"""Every reference-search mode (AP 193) against a world with switches, through the module,
on both chip cores (the search is the generic firmware's; the cores only start and stop).

World (mechanical positions = microsteps at power-on):
  left limit cam  active on [-24000, -20000]    (switching point -20000 seen from inside)
  home cam        active on [  4000,   6000]    (middle 5000)
  right limit cam active on [ 30000,  34000]    (switching point 30000 seen from inside)

A switching point found by backing out and re-entering lies between the last inactive and the
first active microstep; the firmware floors that half step (docs/motion.md).
"""

from __future__ import annotations

import pytest

from axes.world import AxisWorld, Switch, World
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import Request
from tmcl_spec.commands import Opcode

NS = 1_000_000_000


CORES = ("tmc4210", "tmc4361a")


def make_module(home_normally_closed: bool = False, home_at: int = 5000,
                core: str = "tmc4210") -> TMCLModule:
    world = World(axes={0: AxisWorld(switches={
        "left": Switch.place(-20_000, 4000, "below"),
        "right": Switch.place(30_000, 4000, "above"),
        "home": Switch.place(home_at, 2000, "centre", normally_closed=home_normally_closed),
    })})
    return TMCLModule(world=world, kind="tmcm-6212", chip_core=core)


def command(module: TMCLModule, opcode: int, type_: int, value: int = 0) -> int:
    reply = module.execute(Request(1, opcode, type_, 0, value))
    assert reply is not None and reply.status == 100
    return reply.value


def search(module: TMCLModule, mode: int, start: int = 0) -> list[ModuleEvent]:
    events: list[ModuleEvent] = []
    module.listeners.append(events.append)
    command(module, Opcode.SAP, 193, mode)
    command(module, Opcode.SAP, 194, 100_000)
    command(module, Opcode.SAP, 195, 5_000)
    if start:
        command(module, Opcode.MVP, 0, start)
        module.advance_to(module.now_ns + 5 * NS)
    command(module, Opcode.RFS, 0)
    assert command(module, Opcode.RFS, 2) != 0
    deadline = module.now_ns + 60 * NS
    while command(module, Opcode.RFS, 2) != 0:
        assert module.now_ns < deadline, "reference search did not finish"
        nxt = module.next_event_ns()
        module.advance_to(deadline if nxt is None else max(nxt, module.now_ns))
    return events


def mechanical(module: TMCLModule) -> int:
    return module.axis(0).status().mechanical_position


# mode, where the zero point lands (mechanical), AP 196 (None: not set by this mode)
CASES = [
    (1, -20_000, None),  # left switching point
    (2, -20_000, 49_999),  # right point 29 999, then left point; AP 196 = distance
    (3, -22_000, 51_999),  # middle of the left cam, distance from the right point
    (4, -22_000, None),  # middle of the left cam
    (5, 3_999, None),  # home edge; the search reversed at the left switch
    (6, 3_999, None),  # home edge found going right
    (7, 5_000, None),  # middle of the home cam, searching right
    (65, 29_999, None),  # right switching point
    (66, 29_999, 49_999),  # left first, right is the zero point
    (67, 32_000, 52_000),  # middle of the right cam
    (68, 32_000, None),
]


@pytest.mark.parametrize("core", CORES)
@pytest.mark.parametrize(("mode", "zero", "distance"), CASES)
def test_zero_point_of_every_mode(mode: int, zero: int, distance: int | None, core: str) -> None:
    module = make_module(core=core)
    events = search(module, mode)
    assert mechanical(module) == zero
    assert command(module, Opcode.GAP, 1) == 0  # the counter is zero at the reference point
    assert command(module, Opcode.GAP, 197) == zero  # the position just before zeroing
    assert command(module, Opcode.GAP, 209) == 0  # encoder cleared too
    if distance is not None:
        assert command(module, Opcode.GAP, 196) == distance
    done = [e for e in events if e.kind == "reference_search_done"]
    assert len(done) == 1 and done[0].axis == 0
    assert "target_reached" not in [e.kind for e in events if e.time_ns > 0 and e.axis == 0][-1:]


def test_mode_8_searches_negative_for_the_home_cam() -> None:
    module = make_module(home_at=-5000)
    search(module, 8)
    assert mechanical(module) == -5000


@pytest.mark.parametrize(("inverted", "base"), [(133, 5), (134, 6), (135, 7), (136, 8), (129, 5)])
def test_plus_128_inverts_the_home_switch(inverted: int, base: int) -> None:
    """A normally-closed home switch searched with +128 lands where the normal one does."""
    home_at = -5000 if base == 8 else 5000
    plain = make_module(home_at=home_at)
    search(plain, base)
    closed = make_module(home_normally_closed=True, home_at=home_at)
    search(closed, inverted)
    assert mechanical(closed) == mechanical(plain)


@pytest.mark.parametrize("core", CORES)
def test_starting_on_the_switch_and_from_the_far_side(core: str) -> None:
    inside = make_module(core=core)
    search(inside, 4, start=-22_500)  # starts inside the left cam
    assert mechanical(inside) == -22_000
    beyond = make_module(core=core)
    events = search(beyond, 6, start=8000)  # home is behind: right switch, turn, find home
    assert mechanical(beyond) == 6000  # the edge seen coming back from the right
    assert ("right_switch", True) in [(e.kind, e.data.get("active")) for e in events]


def test_limit_switch_disable_does_not_influence_the_search() -> None:
    module = make_module()
    command(module, Opcode.SAP, 13, 1)
    search(module, 1)
    assert mechanical(module) == -20_000
    assert command(module, Opcode.GAP, 13) == 1


@pytest.mark.parametrize("core", CORES)
def test_rfs_stop_aborts_and_motion_commands_cancel(core: str) -> None:
    module = make_module(core=core)
    command(module, Opcode.SAP, 193, 1)
    command(module, Opcode.RFS, 0)
    module.advance_to(module.now_ns + NS // 10)
    command(module, Opcode.RFS, 1)
    assert command(module, Opcode.RFS, 2) == 0
    module.advance_to(module.now_ns + 2 * NS)
    assert command(module, Opcode.GAP, 3) == 0
    assert command(module, Opcode.GAP, 1) != 0  # not zeroed: the search was aborted
