"""The firmware's own clock (axes/tasks.py, issue 34): its periodic tasks run on their
cadence, never as a side effect of a host's or a program's reads.

Each scenario is run with reads at different rates (none, every 0.9 ms, every 1.1 ms, ...) by
a host, or by a program with loop skipping and in the stepping reference: what the module
does and what it answers at the same instants must not depend on how often it was read.
"""

from __future__ import annotations

from collections.abc import Callable

import pytest

from interpreter.assembler import assemble
from tmcl_server.clock import VirtualClock
from tmcl_server.dispatch import Interface
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import Reply, Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode
from tmcl_spec.numbers import NS_PER_MS
from tmcl_spec.parameters import AP

US = 1_000


class Rig:
    def __init__(self, kind: str = "tmcm-6212", core: str | None = None) -> None:
        self.module = TMCLModule(kind=kind, chip_core=core)
        self.sim = Simulation([self.module], VirtualClock())
        self.events: list[tuple[int, str, int | None]] = []
        self.module.listeners.append(self._event)

    def _event(self, event: ModuleEvent) -> None:
        self.events.append((event.time_ns, event.kind, event.axis))

    def ask(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        (_, reply), = self.sim.execute_on([self.module], Request(1, opcode, type_, motor, value),
                                          Interface.SERIAL)
        assert isinstance(reply, Reply) and reply.status in (100, 101), reply
        return reply.value

    def polled(self, until_ns: int, every_ns: int | None, read: Callable[[], object]) -> None:
        """Advance to ``until_ns``, reading every ``every_ns`` on the way (None: not at all)."""
        while every_ns is not None and self.sim.now_ns + every_ns < until_ns:
            self.sim.advance_to_ns(self.sim.now_ns + every_ns)
            read()
        self.sim.advance_to_ns(until_ns)

    def run_program(self, source: str, skip: bool) -> None:
        self.module.program.interpreter.skip_loops = skip
        for opcode, type_, motor, value in [(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0),
                                            *assemble(source).instructions,
                                            (Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0),
                                            (Opcode.RUN_APPLICATION, 0, 0, 0)]:
            self.module.execute(Request(1, opcode, type_, motor, value))
        self.sim.replan(self.module)


# -- item 2: stallGuard with its filter on, whatever a host reads ------------------------------

def _stall_through_a_blocked_zone(every_ns: int | None) -> tuple[object, ...]:
    """Issue 34's item 2 (a load-0 zone from -400,000 to -300,000 there; ten times nearer
    here, the same shape), the filter on."""
    rig = Rig()
    rig.module.set_load(0, [(-40_000, -30_000, 0)])
    rig.sim.notify_changed()
    for number, value in ((173, 1), (174, 1), (181, 29_000)):
        rig.ask(Opcode.SAP, number, 0, value)
    rig.ask(Opcode.ROL, 0, 0, 30_000)
    rig.polled(2_000 * NS_PER_MS, every_ns, lambda: rig.ask(Opcode.GAP, AP.ACTUAL_SPEED))
    stall = [event for event in rig.events if event[1] == "stall"]
    return (tuple(stall), rig.ask(Opcode.GAP, AP.ACTUAL_POSITION), rig.ask(Opcode.GAP, 207))


def test_a_host_reading_faster_than_the_stall_sample_does_not_prevent_the_stall() -> None:
    quiet = _stall_through_a_blocked_zone(None)
    (stall,), position, flags = quiet
    assert -40_000 < position < -30_000 and flags == 1  # stopped inside the zone
    assert stall[0] % NS_PER_MS == 0  # on the firmware's millisecond samples
    for every in (900 * US, 1_100 * US, 333 * US):
        assert _stall_through_a_blocked_zone(every) == quiet, every


def test_a_program_polling_the_speed_stalls_as_a_quiet_module_does() -> None:
    """The published ventilator shape: the stall armed, a main loop polling AP 3."""
    source = """
        SAP 173, 0, 1
        SAP 174, 0, 1
        SAP 181, 0, 29000
        ROL 0, 30000
        WAIT TICKS, 0, 10
    Loop:
        GAP 3, 0
        COMP 0
        JC NE, Loop
        GAP 1, 0
        AGP 0, 2
        STOP
    """
    results = []
    for skip in (True, False):
        rig = Rig()
        rig.module.set_load(0, [(-40_000, -30_000, 0)])
        rig.sim.notify_changed()
        rig.run_program(source, skip)
        rig.sim.advance_to_ns(2_000 * NS_PER_MS)
        results.append((rig.events, rig.module.globals[2][0], rig.ask(Opcode.GAP, 207)))
    assert results[0] == results[1]
    stall = [event for event in results[0][0] if event[1] == "stall"]
    assert len(stall) == 1 and -40_000 < results[0][1] < -30_000


# -- item 3 and issue 33's D1: coolStep on the firmware's clock --------------------------------

#: (speed, acceleration, AP 182) in each module's units: the TMC429 modules' registers, pps.
UNITS = {"tmcm-6212": (40_000, 20_000, 10_000), "tmcm-1111": (40_000, 20_000, 10_000),
         "tmcm-1110": (1000, 2000, 250)}


#: A light load (coolStep lowers the current) with a heavy stretch in it (it raises it again).
HEAVY_STRETCH = [(15_000, 40_000, 10)]


def coolstep_setup(kind: str) -> list[tuple[int, int]]:
    _, acceleration, threshold = UNITS[kind]
    return [(172, 2), (170, 1), (171, 1), (169, 2), (173, 1), (174, 0), (182, threshold),
            (5, acceleration)]  # a slow ramp: coolStep switches on part of the way up


def _coolstep_reading(kind: str, every_ns: int | None) -> list[int]:
    """AP 180 at fixed instants after a ROR with coolStep set up, the axis read in between."""
    rig = Rig(kind)
    rig.module.set_load(0, HEAVY_STRETCH, free_load=600)
    rig.sim.notify_changed()
    for number, value in coolstep_setup(kind):
        rig.ask(Opcode.SAP, number, 0, value)
    rig.ask(Opcode.ROR, 0, 0, UNITS[kind][0])
    seen = []
    for at_ms in (100, 400, 900, 2_000, 3_500):
        rig.polled(at_ms * NS_PER_MS, every_ns, lambda: rig.ask(Opcode.GAP, AP.ACTUAL_POSITION))
        seen.append(rig.ask(Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT))
    return seen


@pytest.mark.parametrize("kind", sorted(UNITS))
def test_coolstep_is_the_same_whatever_a_host_reads(kind: str) -> None:
    quiet = _coolstep_reading(kind, None)
    assert len(set(quiet)) > 1, quiet  # it regulates: the scale moves
    for every in (1 * NS_PER_MS, 3_700 * US, 20 * NS_PER_MS):
        assert _coolstep_reading(kind, every) == quiet, (kind, every)


#: Programs that showed it: (exit position, AP 169, AP 173, the heavy stretch or not).
D1_SHAPES = [(5_000, 2, 0, False), (42_000, 2, 1, True)]


@pytest.mark.parametrize("shape", D1_SHAPES)
@pytest.mark.parametrize("kind", sorted(UNITS))
def test_coolstep_read_by_a_program_is_the_same_skipping_and_stepping(
        kind: str, shape: tuple[int, int, int, bool]) -> None:
    """Issue 33's D1: a program polls AP 1 through a ramp with AP 172 > 0, then reads AP 180
    (it read 11 stepping and 7 skipping on the TMCM-6212: each position read moved coolStep
    on, and the passes left out did not read)."""
    stop_at, down_step, filtered, stretch = shape
    settings = {**dict(coolstep_setup(kind)), 169: down_step, 173: filtered}
    setup = "\n".join(f"SAP {n}, 0, {v}" for n, v in settings.items())
    source = f"""
        {setup}
        ROR 0, {UNITS[kind][0]}
    Loop:
        GAP 1, 0
        COMP {stop_at}
        JC LT, Loop
        GAP 180, 0
        AGP 0, 2
        WAIT TICKS, 0, 50
        GAP 180, 0
        AGP 1, 2
        STOP
    """
    results = []
    for skip in (True, False):
        rig = Rig(kind)
        rig.module.set_load(0, HEAVY_STRETCH if stretch else [], free_load=600)
        rig.run_program(source, skip)
        rig.sim.advance_to_ns(3_000 * NS_PER_MS)
        results.append((rig.events, dict(rig.module.globals[2]),
                        rig.ask(Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT)))
    assert results[0] == results[1]


# -- the current on the firmware's pass -------------------------------------------------------

def test_standby_and_run_current_switch_at_the_passes_one_axis_at_a_time() -> None:
    """TMCL-LITE-1110 SysControl.c: every 11 ms one axis in turn; at power-up the standby
    timer is INT_MAX, so each axis switches to standby at its first pass."""
    rig = Rig("tmcm-6110")
    rig.sim.advance_to_ns(200 * NS_PER_MS)
    standby = [(t, axis) for t, kind, axis in rig.events if kind == "current_changed"]
    assert standby == [(11 * (axis + 1) * NS_PER_MS, axis) for axis in range(6)]
    rig.events.clear()
    rig.ask(Opcode.ROR, 0, 2, 500)  # axis 2's passes: 33 ms + k x 66 ms
    rig.sim.advance_to_ns(400 * NS_PER_MS)
    # back to the run current at axis 2's first pass after the command (231 ms), not at it
    assert rig.events == [(231 * NS_PER_MS, "current_changed", 2)]


def test_slow_run_current_below_ap_182_on_a_tmc429_module() -> None:
    """Item 4: AP 183 is the current below the AP 182 speed (SysControl.c lines 72-77)."""
    rig = Rig("tmcm-1110")
    rig.ask(Opcode.SAP, 182, 0, 500)
    rig.ask(Opcode.SAP, 183, 0, 80)
    rig.ask(Opcode.ROR, 0, 0, 200)
    rig.sim.advance(0.5)
    assert rig.ask(Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 80 >> 3
    assert rig.module.axis(0).status().current == 80
    rig.ask(Opcode.ROR, 0, 0, 1500)
    rig.sim.advance(0.5)
    assert rig.ask(Opcode.GAP, AP.SMARTENERGY_ACTUAL_CURRENT) == 255 >> 3
    assert rig.module.axis(0).status().current == 255
