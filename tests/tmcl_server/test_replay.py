"""``tmcl replay`` on captures made here on the virtual clock: a stand-in module that answers each
request at a random instant inside its round trip, as a real one on a real link does.

Exact and fast: the stand-in is a simulation of its own, the capture is written by the same
:class:`CaptureWriter` the proxy uses, and every instant is chosen by a seeded generator.  The
proxy in between, real time and real hosts: tests/tmcl_server/test_proxy.py.
"""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest

from tmcl_server.capture import NO_REPLY, REPLY, REQUEST, UNSOLICITED, CaptureWriter, open_capture
from tmcl_server.decode import CaptureError
from tmcl_server.protocol import Request, decode_reply
from tmcl_server.replay import DEFAULT_TOLERANCE_S, replay_capture
from tmcl_server.server import ServerConfig, build_simulation
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import Opcode
from tmcl_spec.modules import module_type
from tmcl_spec.numbers import NS_PER_MS, NS_PER_S
from tmcl_spec.parameters import AP, GP


def identity(key: str) -> dict[str, object]:
    """What the proxy writes into the header for a module of this type."""
    kind = module_type(key)
    major, minor = kind.firmware
    return {"version": f"{kind.module_number}V{major}{minor:02d}", "module_number": kind.module_number,
            "firmware": f"{major}.{minor:02d}", "type": kind.name}


class StandIn:
    """A module on a virtual clock behind a link whose round trips take ``rtt_ms`` (random
    within), answering each request at a random instant inside it; every frame captured."""

    def __init__(self, path: Path, seed: int = 1, rtt_ms: tuple[float, float] = (0.2, 4.0),
                 **config: object) -> None:
        self.simulation = build_simulation(ServerConfig(endpoints={}, clock="virtual", **config))  # type: ignore[arg-type]
        self.random = random.Random(seed)
        self.rtt_ms = rtt_ms
        self.t_ns = 0
        self.writer = CaptureWriter(path.open("wb", buffering=0), "virtual",
                                    identity(str(config.get("module_type", "tmcm-6212"))), start_ns=0)
        self.events: list[bytes] = []

    def send_unsolicited(self, reply: object) -> None:  # the stand-in's 138 events
        self.events.append(reply.encode())  # type: ignore[attr-defined]

    def request(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0,
                answered: bool = True) -> int | None:
        frame = Request(1, opcode, type_, motor, value).encode()
        rtt = round(self.random.uniform(*self.rtt_ms) * NS_PER_MS)
        executed = self.t_ns + self.random.randrange(rtt + 1)
        self.writer.frame(self.t_ns, REQUEST, "tcp host", 1, frame)
        self.simulation.advance_to_ns(executed)
        self._flush_events()
        routed = self.simulation.handle_serial_frame(frame, self)
        self.simulation.advance_to_ns(self.t_ns + rtt)
        value_read = None
        if routed and answered:
            data = routed[0][1].encode()
            self.writer.frame(self.t_ns + rtt, REPLY, "tcp host", 1, data)
            value_read = decode_reply(data).value if len(data) == 9 and opcode != 136 else 0
        else:
            self.writer.frame(self.t_ns + rtt, NO_REPLY, "tcp host", 1)
        self.t_ns += rtt + round(self.random.uniform(0.05, 3.0) * NS_PER_MS)
        self._flush_events()
        return value_read

    def _flush_events(self) -> None:
        for data in self.events:
            self.writer.frame(self.simulation.now_ns, UNSOLICITED, "tcp host", None, data)
        self.events.clear()

    def wait(self, seconds: float) -> None:
        self.t_ns += round(seconds * NS_PER_S)
        self.simulation.advance_to_ns(self.t_ns)
        self._flush_events()

    def close(self) -> None:
        self.writer.close()


def polled_moves(host: StandIn) -> None:
    """A host session: settings, a move polled while it runs, a rotation, a stop, reads."""
    host.request(Opcode.GET_FIRMWARE_VERSION, 0)
    host.request(Opcode.GET_FIRMWARE_VERSION, 1)
    host.request(Opcode.SAP, AP.MAX_SPEED, 0, 51200)
    host.request(Opcode.SAP, AP.MAX_ACCELERATION, 0, 20000)
    host.request(Opcode.MVP, 0, 0, 40000)
    while not host.request(Opcode.GAP, AP.POSITION_REACHED, 0):
        host.request(Opcode.GAP, AP.ACTUAL_POSITION, 0)
        host.request(Opcode.GAP, AP.ACTUAL_SPEED, 0)
    host.request(Opcode.ROR, 0, 1, 30000)
    for _ in range(40):
        host.request(Opcode.GAP, AP.ACTUAL_SPEED, 1)
        host.request(Opcode.GAP, AP.ACTUAL_POSITION, 1)
    host.request(Opcode.MST, 0, 1)
    for _ in range(20):
        host.request(Opcode.GAP, AP.ACTUAL_SPEED, 1)
    host.request(Opcode.GGP, GP.TICK_TIMER, 0)
    host.wait(0.5)
    host.request(Opcode.GGP, GP.TICK_TIMER, 0)
    host.request(Opcode.GAP, AP.MAX_SPEED, 0)


def capture_of(tmp_path: Path, session, seed: int = 1, **config: object) -> Path:
    path = tmp_path / f"session-{seed}.jsonl"
    host = StandIn(path, seed, **config)
    session(host)
    host.close()
    return path


@pytest.mark.parametrize(("seed", "rtt_ms"), [(1, (0.2, 4.0)), (2, (0.2, 4.0)), (3, (1.0, 60.0))])
def test_an_identical_module_answering_anywhere_in_its_round_trip_never_diverges(
        tmp_path: Path, seed: int, rtt_ms: tuple[float, float]) -> None:
    """Round trips of a loopback link, and of one on a machine at load 10 (up to 60 ms)."""
    path = capture_of(tmp_path, polled_moves, seed, rtt_ms=rtt_ms)
    result = replay_capture(path)
    assert result.divergences == [], result.report()
    positions = [json.loads(line)["bytes"] for line in path.read_text().splitlines()[1:]]
    assert result.summary.requests > 150 and len(set(positions)) > 100  # a move, polled
    assert result.summary.matched == result.summary.requests


def test_judged_at_the_request_instant_alone_the_same_session_diverges(tmp_path: Path) -> None:
    """The window is what makes it pass: without the round trips (the module answered late
    inside each), moving values differ."""
    path = capture_of(tmp_path, polled_moves, 4, rtt_ms=(3.0, 6.0))
    text = path.read_text().splitlines()
    squeezed = [text[0]]
    for line in text[1:]:  # every reply stamped at its request's instant: no window left
        record = json.loads(line)
        if record["dir"] == REQUEST:
            at = record["t"]
        else:
            record["t"] = at
        squeezed.append(json.dumps(record))
    narrow = tmp_path / "narrow.jsonl"
    narrow.write_text("\n".join(squeezed) + "\n")
    result = replay_capture(narrow, tolerance_s=0)
    moving = {d.request.split()[2] for d in result.divergences}
    assert result.summary.diverged > 20 and moving <= {"ActualPosition", "ActualSpeed",
                                                       "TargetPositionReached", "TMCLTickTimer"}
    assert replay_capture(path, tolerance_s=0).divergences == []


def test_a_program_upload_and_its_run_replay_as_such(tmp_path: Path) -> None:
    program = [Request(0, Opcode.SGP, 0, 2, 0), Request(0, Opcode.SAP, AP.MAX_SPEED, 0, 51200),
               Request(0, Opcode.MVP, 1, 0, 10000), Request(0, Opcode.WAIT, 1, 0, 0),
               Request(0, Opcode.SGP, 0, 2, 42), Request(0, Opcode.STOP, 0, 0, 0)]

    def session(host: StandIn) -> None:
        host.request(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0)
        for ins in program:
            host.request(ins.opcode, ins.type, ins.motor, ins.value)
        host.request(Opcode.EXIT_DOWNLOAD_MODE)
        for address in range(len(program)):
            host.request(Opcode.READ_PROGRAM_MEMORY, 0, 0, address)
        host.request(Opcode.RUN_APPLICATION, 1, 0, 0)
        while host.request(Opcode.GGP, 0, 2) != 42:
            host.request(Opcode.GET_APPLICATION_STATUS, 1)
            host.request(Opcode.GAP, AP.ACTUAL_POSITION, 0)
        host.request(Opcode.GET_APPLICATION_STATUS, 1)

    path = capture_of(tmp_path, session, 5)
    result = replay_capture(path)
    assert result.divergences == [], result.report()
    commands = result.summary.by_command
    assert commands["ENTER_DOWNLOAD_MODE"] == [1, 0] and commands["RUN_APPLICATION"] == [1, 0]
    assert commands["GAP"][0] > 10  # polled while the program moved the motor



def test_a_program_stored_by_the_module_and_not_by_the_simulator_is_listed(tmp_path: Path) -> None:
    """The simulator executes the stored commands as a program, not as reads: a stored GAP
    reads nothing, and a stored command the module rejected shows."""
    def session(host: StandIn) -> None:
        host.request(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, 0)
        host.request(Opcode.GAP, AP.ACTUAL_POSITION, 0)  # stored, not read
        host.request(Opcode.EXIT_DOWNLOAD_MODE)
        host.request(Opcode.READ_PROGRAM_MEMORY, 0, 0, 0)

    path = capture_of(tmp_path, session, 7)
    lines = path.read_text().splitlines()
    records = [json.loads(line) for line in lines[1:]]
    stored = next(r for r in records if r["dir"] == REPLY and r["bytes"][4:6] == "65")
    assert stored  # status 101 LOADED: the stand-in stored it
    result = replay_capture(path)
    assert result.divergences == [] and result.summary.by_command["GAP"] == [1, 0]


def test_events_the_module_sends_unasked_are_compared(tmp_path: Path) -> None:
    def session(host: StandIn) -> None:
        host.request(Opcode.TARGET_REACHED_EVENT, 0, 0, 1)
        host.request(Opcode.MVP, 1, 0, 5000)
        host.wait(2.0)
        host.request(Opcode.GAP, AP.ACTUAL_POSITION, 0)

    path = capture_of(tmp_path, session, 8)
    result = replay_capture(path)
    assert result.divergences == [] and result.summary.events_captured == 1
    assert result.summary.events_simulated == 1
    records = path.read_text().splitlines()
    without = tmp_path / "lost-event.jsonl"
    without.write_text("\n".join(r for r in records if '"unsolicited"' not in r) + "\n")
    lost = replay_capture(without)
    assert [(d.request, d.module) for d in lost.divergences] == [("(unasked frame)", "(nothing)")]
    assert "128 TARGET_REACHED_EVENT axes 0" in lost.divergences[0].simulator


def test_a_different_module_type_lists_exactly_its_differences(tmp_path: Path) -> None:
    def session(host: StandIn) -> None:
        host.request(Opcode.GET_FIRMWARE_VERSION, 0)
        host.request(Opcode.SAP, AP.MAX_SPEED, 0, 51200)
        host.request(Opcode.GAP, AP.MAX_SPEED, 0)
        host.request(Opcode.SGP, 0, 2, 7)
        host.request(Opcode.GGP, 0, 2)

    path = capture_of(tmp_path, session, 9, module_type="tmcm-1140")
    result = replay_capture(path, module_type_name="tmcm-6212")
    assert [d.request for d in result.divergences] == [
        "GET_FIRMWARE_VERSION type 0", "SAP 4 MaxPositioningSpeed m0 = 51200",
        "GAP 4 MaxPositioningSpeed m0"]
    assert result.divergences[0].module == '→ "1140V127"'
    assert result.divergences[0].simulator == '→ "6212V105"'
    assert result.summary.requests == 5 and result.summary.diverged == 3


def test_replies_the_capture_lost_and_no_replies_the_module_gave(tmp_path: Path) -> None:
    def session(host: StandIn) -> None:
        host.request(Opcode.GAP, AP.MAX_SPEED, 0, answered=False)
        host.request(Opcode.GAP, AP.MAX_SPEED, 0)

    path = capture_of(tmp_path, session, 10)
    (divergence,) = replay_capture(path).divergences
    assert divergence.module == "(no reply)" and divergence.simulator.startswith("→ 100 OK = ")
    assert divergence.t == 0.0


def test_the_cli_lines_json_and_exit_codes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    def session(host: StandIn) -> None:
        host.request(Opcode.SAP, AP.MAX_SPEED, 0, 51200)
        host.request(Opcode.GAP, AP.MAX_SPEED, 0)

    path = capture_of(tmp_path, session, 11, module_type="tmcm-1140")
    assert tmcl(["replay", str(path)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("2 requests: 2 matched, 0 diverged (GAP 1, SAP 1)\n")
    assert f"reply + {DEFAULT_TOLERANCE_S:g} s]" in out
    assert tmcl(["replay", str(path), "--module-type", "tmcm-6212", "--json"]) == 1
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [set(line) for line in lines[:-1]] == [{"t", "request", "module", "simulator"}] * 2
    assert lines[-1]["summary"]["by_command"] == {"GAP": {"requests": 1, "diverged": 1},
                                                  "SAP": {"requests": 1, "diverged": 1}}
    with pytest.raises(SystemExit) as usage:  # argparse's way, as every tmcl subcommand's
        tmcl(["replay", str(path), "--module-type", "tmcm-9999"])
    assert usage.value.code == 2 and "invalid choice: 'tmcm-9999'" in capsys.readouterr().err


def _run_cli(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str]:
    code = tmcl(["replay", *argv])
    err = capsys.readouterr().err
    return code, err


def test_an_unreadable_capture_is_one_line_and_exit_2(tmp_path: Path, capsys) -> None:
    good = capture_of(tmp_path, lambda host: host.request(Opcode.GAP, AP.MAX_SPEED, 0), 12)
    header, *frames = good.read_text().splitlines()
    cases = {
        "missing.jsonl": None,
        "newer.jsonl": header.replace('"version": 1', '"version": 2') + "\n",
        "middle.jsonl": "\n".join([header, frames[0][:20], frames[1]]) + "\n",
        "binary.bin": "\x00\x01\x02",
        "empty.txt": "",
        "badbytes.jsonl": "\n".join([header, frames[0].replace('"bytes": "', '"bytes": "zz')]) + "\n",
    }
    expected = {"missing.jsonl": "no such file", "newer.jsonl": "capture version 2",
                "middle.jsonl": "line 2: not a JSON line", "binary.bin": "no TMCL request",
                "empty.txt": "no TMCL request", "badbytes.jsonl": "line 2: 'bytes' must be hex"}
    for name, text in cases.items():
        path = tmp_path / name
        if text is not None:
            path.write_text(text)
        code, err = _run_cli(capsys, str(path))
        assert code == 2, (name, err)
        assert err.count("\n") == 1 and "Traceback" not in err, err
        assert str(path) in err and expected[name] in err, err
    assert _run_cli(capsys, str(tmp_path))[0] == 2  # a directory


def test_a_last_line_cut_short_is_left_out_with_a_note(tmp_path: Path) -> None:
    path = capture_of(tmp_path, polled_moves, 13)
    text = path.read_text()
    path.write_text(text[:-25])  # the proxy stopped while writing the last reply
    capture = open_capture(path)
    frames = list(capture.frames())
    assert frames[-1].direction == REQUEST and "cut short" in capture.notes[0]
    result = replay_capture(path)
    assert result.divergences == []
    assert any("has no outcome" in note for note in result.summary.notes)
    with pytest.raises(CaptureError, match="cut short"):
        (tmp_path / "header.jsonl").write_text(text[:40])
        open_capture(tmp_path / "header.jsonl")


def test_a_world_with_a_switch_pressed_shows_in_the_switch_reads(tmp_path: Path) -> None:
    world = tmp_path / "pressed.toml"
    world.write_text("[[axis]]\nindex = 0\nleft = { position = 100 }\n")

    def session(host: StandIn) -> None:
        for axis in (0, 1):
            for number in (AP.HOME_SWITCH, AP.RIGHT_SWITCH, AP.LEFT_SWITCH):
                host.request(Opcode.GAP, number, axis)

    path = capture_of(tmp_path, session, 14, world=str(world))
    (divergence,) = replay_capture(path).divergences
    assert divergence.request == "GAP 11 LeftLimitSwitchState m0"
    assert (divergence.module, divergence.simulator) == ("→ 100 OK = 1", "→ 100 OK = 0")
    assert replay_capture(path, world=str(world)).divergences == []


def test_the_pytest_helper_passes_a_matching_capture_and_fails_with_the_divergences(
        tmp_path: Path, tmcl_replay) -> None:
    def session(host: StandIn) -> None:
        host.request(Opcode.SAP, AP.MAX_SPEED, 0, 51200)
        host.request(Opcode.GAP, AP.MAX_SPEED, 0)

    path = capture_of(tmp_path, session, 15, module_type="tmcm-1140")
    assert tmcl_replay(path).summary.matched == 2
    with pytest.raises(pytest.fail.Exception) as failed:
        tmcl_replay(path, module_type="tmcm-6212")
    assert str(path) in str(failed.value) and "SAP 4 MaxPositioningSpeed m0 = 51200: module " \
        "→ 4 INVALID_VALUE; simulator → 100 OK" in str(failed.value)
    with pytest.raises(pytest.fail.Exception, match=r"tmcl_replay: .*no such file"):
        tmcl_replay(tmp_path / "missing.jsonl")


def test_the_committed_capture_replays_beside_its_test(tmcl_replay) -> None:
    """The round trip docs/capture.md shows: a capture committed beside the test, replayed
    in CI by its relative path (this one was taken through the proxy from a simulator)."""
    result = tmcl_replay("captures/move-polled.jsonl")
    assert result.summary.requests > 20 and result.summary.diverged == 0


def test_a_python_can_log_replays_with_its_timestamps(tmp_path: Path) -> None:
    """A CAN log from python-can (what ``python -m can.logger`` writes): requests on the
    module's id, replies on the reply id, told apart as ``tmcl decode`` does."""
    import can

    simulation = build_simulation(ServerConfig(endpoints={}, clock="virtual"))
    path = tmp_path / "session.log"
    with can.Logger(str(path)) as log:
        t = 1700000000.0
        for opcode, type_, motor, value in ((Opcode.SAP, AP.MAX_SPEED, 0, 51200),
                                            (Opcode.MVP, 0, 0, 5000), (Opcode.GAP, AP.ACTUAL_POSITION, 0, 0),
                                            (Opcode.GAP, AP.MAX_SPEED, 0, 0)):
            request = Request(1, opcode, type_, motor, value)
            log(can.Message(timestamp=t, arbitration_id=1, is_extended_id=False,
                            data=request.encode_can()))
            simulation.advance_to_ns(round((t - 1700000000.0) * NS_PER_S) + 200_000)
            (_, reply), = simulation.handle_can_request(request)
            log(can.Message(timestamp=t + 0.0004, arbitration_id=2, is_extended_id=False,
                            data=reply.encode_can()))
            t += 0.05
    result = replay_capture(path)
    assert result.divergences == [] and result.summary.requests == 4, result.report()
    assert result.summary.by_command == {"SAP": [1, 0], "MVP": [1, 0], "GAP": [2, 0]}
    other = replay_capture(path, module_type_name="tmcm-1140")  # refuses 51200: slower, lower
    assert [d.request.split()[0] for d in other.divergences] == ["SAP", "GAP", "GAP"]


def test_a_hex_dump_replays_without_instants(tmp_path: Path) -> None:
    """A ``tmcl decode`` dump has no instants: settings are compared, moving values are not
    judged (counted)."""
    dump = tmp_path / "session.txt"
    dump.write_text("01 05 04 00 00 00 c8 00 d2\n02 01 64 05 00 00 c8 00 34\n"  # SAP 4, 0, 51200
                    "01 06 04 00 00 00 00 00 0b\n02 01 64 06 00 00 c8 00 35\n"  # GAP 4 -> 51200
                    "01 06 01 00 00 00 00 00 08\n02 01 64 06 00 00 00 07 75\n")  # GAP 1 -> 7
    result = replay_capture(dump)
    assert result.divergences == [] and result.summary.not_judged == 1
    assert result.summary.lines(DEFAULT_TOLERANCE_S)[0] == (
        "3 requests: 2 matched, 0 diverged, 1 not judged (no instants) (GAP 2, SAP 1)")
    dump.write_text(dump.read_text().replace("02 01 64 06 00 00 c8 00 35", "02 01 64 06 00 00 c8 01 36"))
    (divergence,) = replay_capture(dump).divergences
    assert divergence.t is None and divergence.module == "→ 100 OK = 51201"
