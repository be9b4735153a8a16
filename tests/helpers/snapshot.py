"""The behaviour snapshot: one fixed script of host commands, run on the virtual clock for
every module type and chip core the command line accepts, written out as a transcript.

Each line is an instant and what happened then: a request and its reply, or an event of the
module (a target reached, a switch edge, a stall, the current switching).  The transcripts
live in ``tests/snapshots/<module>-<core>.txt``; ``tests/test_snapshots.py`` compares them, so
a change of behaviour shows in review as a diff of those files, made on purpose and explained
in its commit.  Regenerate them with ``.venv/bin/python scripts/update_snapshots.py`` (all, or
``--only tmcm-6212-tmc4210``).

The script is the same for every module; its values come from the module's own tables (a
speed is the row's default, a threshold half of it), so the TMC429 modules run it in their
register units and the TMCM-6212 in pps.  A command a module refuses is part of its record.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from interpreter.assembler import assemble
from tmcl_server.clock import VirtualClock
from tmcl_server.dispatch import Interface
from tmcl_server.module import ModuleEvent, TMCLModule
from tmcl_server.protocol import RawReply, Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode
from tmcl_spec.numbers import NS_PER_MS

SNAPSHOT_DIR = Path(__file__).resolve().parents[1] / "snapshots"

#: Every (module type, chip core) the command line accepts: the module types on their own
#: core and on the others that run them (docs/modules.md, "Module types and chip cores").
COMBINATIONS: tuple[tuple[str, str], ...] = (
    ("tmcm-6212", "tmc4210"), ("tmcm-6212", "tmc4361a"), ("tmcm-6212", "tmc429"),
    *((kind, core) for kind in ("tmcm-1110", "tmcm-3110", "tmcm-6110", "tmcm-1140", "tmcm-1141",
                                "tmcm-1160", "tmcm-1161") for core in ("tmc429", "tmc4210")),
    ("tmcm-1111", "tmc4361a"), ("tmcm-1111", "tmc4210"), ("tmcm-1111", "tmc429"),
    ("landungsbruecke-tmc4361a", "tmc4361a-eval"),
)


def snapshot_path(kind: str, core: str) -> Path:
    return SNAPSHOT_DIR / f"{kind}-{core}.txt"


class Session:
    """A host talking to one module on the virtual clock, every exchange written down."""

    def __init__(self, kind: str, core: str) -> None:
        self.module = TMCLModule(kind=kind, chip_core=core)
        self.sim = Simulation([self.module], VirtualClock())
        self.lines: list[str] = [f"# {self.module.type.name} on the {core} core"]
        self.module.listeners.append(self._event)

    def _stamp(self, time_ns: int) -> str:
        return f"{time_ns / NS_PER_MS:12.6f}"

    def _event(self, event: ModuleEvent) -> None:
        data = " ".join(f"{k}={v}" for k, v in sorted(event.data.items()))
        axis = "" if event.axis is None else f" axis {event.axis}"
        self.lines.append(f"{self._stamp(event.time_ns)}  event {event.kind}{axis} {data}".rstrip())

    def note(self, text: str) -> None:
        self.lines.append(f"## {text}")

    def send(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int | None:
        """One request; returns the reply's value (None: no reply or a special one)."""
        request = Request(self.module.address, opcode, type_, motor, value)
        routed = self.sim.execute_on([self.module], request, Interface.SERIAL)
        name = Opcode(opcode).name if opcode in Opcode._value2member_map_ else str(opcode)
        said = f"{name} {type_}, {motor}, {value}"
        if not routed:
            answer, result = "no reply", None
        else:
            reply = routed[0][1]
            if isinstance(reply, RawReply):
                answer, result = f"raw {reply.data.hex()}", None
            else:
                answer, result = f"{reply.status} {reply.value}", reply.value
        self.lines.append(f"{self._stamp(self.sim.now_ns)}  {said} -> {answer}")
        return result

    def wait(self, ms: float) -> None:
        self.sim.advance_to_ns(self.sim.now_ns + round(ms * NS_PER_MS))

    def mechanical(self) -> int:
        """Where the mechanics of axis 0 are (world units: switches and loads are placed so)."""
        return self.module.axis(0).status().mechanical_position

    def world(self, change: Callable[[TMCLModule], None], text: str) -> None:
        """Change the world around the module (switches, loads) from the test rig."""
        change(self.module)
        self.sim.notify_changed()
        self.lines.append(f"{self._stamp(self.sim.now_ns)}  world {text}")


def _default(module: TMCLModule, number: int, fallback: int) -> int:
    spec = module.type.axis_parameters.get(number)
    return fallback if spec is None else spec.default or fallback


def _read_all(s: Session) -> None:
    """Every readable axis parameter of axis 0, every readable global parameter of banks 0
    and 3, and the first user variables."""
    module = s.module
    for number, spec in sorted(module.type.axis_parameters.items()):
        if spec.readable:
            s.send(Opcode.GAP, number, 0)
    for bank in (0, 3):
        for number, spec in sorted(module.type.global_parameters.get(bank, {}).items()):
            if spec.readable:
                s.send(Opcode.GGP, number, bank)
    for number in range(3):
        s.send(Opcode.GGP, number, 2)


def _poll(s: Session, numbers: tuple[int, ...], every_ms: float, times: int, motor: int = 0) -> None:
    for _ in range(times):
        for number in numbers:
            s.send(Opcode.GAP, number, motor)
        s.wait(every_ms)


PROGRAM = """
    SAP 4, 0, {speed}
    MVP REL, 0, {distance}
Wait:
    WAIT POS, 0, 2000
    GAP 1, 0
    AGP 0, 2
    GAP 3, 0
    AGP 1, 2
    CALC ADD, 1
    AGP 2, 2
    MVP REL, 0, {back}
    WAIT POS, 0, 2000
    GAP 1, 0
    AGP 0, 2
    STOP
"""


def run_script(kind: str, core: str) -> str:
    """The whole script on one module type and core; the transcript."""
    s = Session(kind, core)
    module = s.module
    speed = _default(module, 4, 1000)
    acceleration = _default(module, 5, 500)
    distance = 20 * speed if speed < 10_000 else speed // 2  # about half a second
    s.note("identity")
    s.send(Opcode.GET_FIRMWARE_VERSION, 0)
    s.send(Opcode.GET_FIRMWARE_VERSION, 1)
    s.note("every parameter at power-up")
    _read_all(s)
    s.note("a move to a target and back")
    s.send(Opcode.SAP, 4, 0, speed)
    s.send(Opcode.SAP, 5, 0, acceleration)
    s.send(Opcode.MVP, 0, 0, distance)
    _poll(s, (1, 3, 8), 97.3, 12)
    s.send(Opcode.MVP, 1, 0, -distance // 2)
    _poll(s, (1, 3, 8), 151.1, 8)
    s.note("a rotation, its first speed reading, a stop")
    s.send(Opcode.ROR, 0, 0, speed)
    s.send(Opcode.GAP, 3, 0)
    s.wait(0.01)
    s.send(Opcode.GAP, 3, 0)
    s.wait(3.7)
    s.send(Opcode.GAP, 3, 0)
    s.send(Opcode.GAP, 2, 0)
    s.wait(400)
    _poll(s, (1, 3), 1, 2)
    s.send(Opcode.MST, 0, 0)
    _poll(s, (1, 3, 8), 50, 6)
    s.send(Opcode.ROL, 0, 0, speed // 2)
    s.wait(300)
    s.send(Opcode.MST, 0, 0)
    s.wait(600)
    s.send(Opcode.ROR, 0, 0, 3000)
    s.wait(50)
    _poll(s, (2, 3), 10, 2)
    s.send(Opcode.MST, 0, 0)
    s.wait(1500)
    s.note("switches")
    here = s.mechanical()
    s.world(lambda m: m.set_switch(0, "right", here + distance // 4), "right switch ahead")
    s.send(Opcode.ROR, 0, 0, speed)
    _poll(s, (1, 3, 9, 10, 11), 80, 8)
    s.send(Opcode.MST, 0, 0)
    s.send(Opcode.SAP, 12, 0, 1)
    s.send(Opcode.ROR, 0, 0, speed // 4)
    _poll(s, (1, 3, 10), 60, 3)
    s.send(Opcode.MST, 0, 0)
    s.send(Opcode.SAP, 12, 0, 0)
    s.wait(500)
    s.world(lambda m: m.set_switch(0, "right", None), "right switch removed")
    s.note("reference search: start, status, stop, then to the end")
    here = s.mechanical()
    s.world(lambda m: m.set_switch(0, "left", here - distance // 4), "left switch behind")
    s.send(Opcode.SAP, 193, 0, 1)
    s.send(Opcode.SAP, 194, 0, speed)
    s.send(Opcode.SAP, 195, 0, max(1, speed // 10))
    s.send(Opcode.RFS, 0, 0)
    _poll(s, (1, 3), 20, 2)
    s.send(Opcode.RFS, 2, 0)
    s.send(Opcode.RFS, 1, 0)
    s.send(Opcode.RFS, 2, 0)
    _poll(s, (1, 3), 100, 4)
    s.send(Opcode.RFS, 0, 0)
    for _ in range(12):
        s.send(Opcode.RFS, 2, 0)
        s.send(Opcode.GAP, 1, 0)
        s.wait(250)
    s.send(Opcode.GAP, 197, 0)
    s.send(Opcode.MST, 0, 0)
    s.wait(200)
    s.world(lambda m: m.set_switch(0, "left", None), "left switch removed")
    s.note("stallGuard: a blocked stretch ahead, stop on stall")
    here = s.mechanical()
    start, end = here + distance // 2, here + distance * 4
    s.world(lambda m: m.set_load(0, [(start, end, 0)]), f"blocked from {start} to {end}")
    s.send(Opcode.SAP, 174, 0, 4)
    s.send(Opcode.SAP, 173, 0, 1)
    s.send(Opcode.SAP, 181, 0, speed // 2)
    s.send(Opcode.ROR, 0, 0, speed)
    _poll(s, (1, 3, 206, 207), 50.3, 12)
    s.send(Opcode.GAP, 207, 0)
    s.send(Opcode.SAP, 181, 0, 0)
    s.world(lambda m: m.set_load(0, []), "load removed")
    s.note("coolStep")
    s.send(Opcode.SAP, 172, 0, 2)
    s.send(Opcode.SAP, 170, 0, 1)
    s.send(Opcode.SAP, 171, 0, 1)
    s.send(Opcode.SAP, 169, 0, 2)
    s.send(Opcode.SAP, 182, 0, speed // 4)
    s.send(Opcode.SAP, 183, 0, 64)
    s.send(Opcode.ROL, 0, 0, speed)
    _poll(s, (3, 180, 206), 37.7, 16)
    s.send(Opcode.MST, 0, 0)
    _poll(s, (3, 180), 100, 5)
    s.send(Opcode.SAP, 172, 0, 0)
    s.wait(3000)
    s.note("standalone program: download, run, stop")
    code = assemble(PROGRAM.format(speed=speed, distance=distance // 2, back=-distance // 2))
    s.send(Opcode.ENTER_DOWNLOAD_MODE)
    for opcode, type_, motor, value in code.instructions:
        s.send(opcode, type_, motor, value)
    s.send(Opcode.EXIT_DOWNLOAD_MODE)
    s.send(Opcode.RUN_APPLICATION)
    for _ in range(10):
        s.wait(200)
        s.send(Opcode.GET_APPLICATION_STATUS, 0)
        s.send(Opcode.GGP, 0, 2)
    s.send(Opcode.STOP_APPLICATION)
    for number in range(3):
        s.send(Opcode.GGP, number, 2)
    s.note("every axis's position and speed")
    for motor in range(module.type.number_of_axes):
        s.send(Opcode.GAP, 1, motor)
        s.send(Opcode.GAP, 3, motor)
    s.note("every parameter at the end")
    s.wait(5000)
    _read_all(s)
    return "\n".join(s.lines) + "\n"
