"""``tmcl proxy`` between real hosts and a stand-in module, then ``tmcl replay`` of its capture.

The stand-in is a second simulator on the real clock behind a TCP port on a free loopback port;
the proxy runs as its own process (``python -m tmcl_server.tool ... proxy``), stopped with
Ctrl-C; the hosts are pytrinamic (over the proxy's TCP port and its pty) and the ``tmcl`` tool.
The wire forces real time here: hosts poll until a condition holds, and nothing asserted
depends on how fast the machine is (the replay judges each answer over its own round trip).
Exact instants and many round trips: tests/tmcl_server/test_replay.py.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from pytrinamic.connections import ConnectionManager

from tests.helpers.processes import wait_for_ready_file
from tmcl_server.embed import SimulatorThread
from tmcl_server.tool import main as tmcl
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP

#: The proxy's wait for a reply: generous (a loaded machine), never reached here.
PROXY_TIMEOUT = "5"


class ProxyProcess:
    """``tmcl --tcp MODULE proxy`` with a TCP port and a pty for hosts, capturing."""

    def __init__(self, tmp_path: Path, module: str, *extra: str) -> None:
        self.capture = tmp_path / "session.jsonl"
        self.pty = tmp_path / "ttyPROXY"
        ready = tmp_path / "proxy-ready.json"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tmcl_server.tool", "--tcp", module, "--timeout", PROXY_TIMEOUT,
             "proxy", "--listen-tcp", "127.0.0.1:0", "--listen-pty", str(self.pty),
             "--capture", str(self.capture), "--ready-file", str(ready), *extra],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # Ctrl-C reaches it
        self.tcp = wait_for_ready_file(self.proc, ready, 30, "proxy")["tcp"][0]

    def stop(self, sig: int = signal.SIGINT) -> tuple[int, str, str]:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=30)
        return self.proc.returncode, out, err


@pytest.fixture
def standin() -> Iterator[Callable[..., SimulatorThread]]:
    started: list[SimulatorThread] = []

    def make(**settings: object) -> SimulatorThread:
        sim = SimulatorThread(clock="real", tcp=["127.0.0.1:0"], **settings).start()  # type: ignore[arg-type]
        started.append(sim)
        return sim

    yield make
    for sim in started:
        sim.stop()


def replay(capsys: pytest.CaptureFixture[str], capture: Path, *options: str) -> tuple[int, list[dict]]:
    code = tmcl(["replay", str(capture), "--json", *options])
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    return code, lines


def send(capsys: pytest.CaptureFixture[str], where: list[str], *line: str) -> str:
    tmcl([*where, "send", *line])
    return capsys.readouterr().out


def test_pytrinamic_and_tmcl_hosts_through_the_proxy_replay_without_a_divergence(
        tmp_path: Path, standin, capsys) -> None:
    module = standin()
    proxy = ProxyProcess(tmp_path, module.tcp)
    try:
        with ConnectionManager(f"--interface socket_serial_tmcl --port {proxy.tcp}").connect() as iface:
            assert iface.get_version_string() == "6212V105"
            iface.set_axis_parameter(AP.MAX_SPEED, 0, 51200)
            iface.set_axis_parameter(AP.MAX_ACCELERATION, 0, 20000)
            iface.send(Opcode.MVP, 0, 0, 40000)
            polled = set()
            while not iface.get_axis_parameter(AP.POSITION_REACHED, 0):  # a move, polled as it runs
                polled.add(iface.get_axis_parameter(AP.ACTUAL_POSITION, 0, signed=True))
                iface.get_axis_parameter(AP.ACTUAL_SPEED, 0, signed=True)
                time.sleep(0.002)
        with ConnectionManager(f"--interface serial_tmcl --port {proxy.pty} --data-rate 115200"
                               ).connect() as serial_host:
            assert serial_host.get_axis_parameter(AP.ACTUAL_POSITION, 0) == 40000
            serial_host.send(Opcode.ROR, 0, 1, 20000)
            for _ in range(20):
                serial_host.get_axis_parameter(AP.ACTUAL_SPEED, 1, signed=True)
            serial_host.send(Opcode.MST, 0, 1, 0)
        program = tmp_path / "flag.tmc"
        program.write_text("SGP 0, 2, 0\nMVP REL, 0, -8000\nWAIT POS, 0, 0\nSGP 0, 2, 42\nSTOP\n")
        tool = ["--serial", str(proxy.pty), "--timeout", "5"]
        assert tmcl([*tool, "program", "upload", str(program), "--verify", "--run"]) == 0
        while send(capsys, tool, "GGP", "0", "2", "--value").strip() != "42":  # the program's flag
            send(capsys, tool, "GAP", "1", "0")
        assert tmcl([*tool, "send", "MVP", "REL", "0", "3000", "--wait"]) == 0
        capsys.readouterr()
    finally:
        code, out, err = proxy.stop(signal.SIGINT)  # Ctrl-C
    assert code == 0 and "tmcl proxy: stopped after" in out, err
    assert not proxy.pty.exists(), "the pty link is removed on the way out"
    assert len(polled) > 5
    lines = proxy.capture.read_text().splitlines()
    header = json.loads(lines[0])
    assert (header["format"], header["version"]) == ("tmcl-capture", 1)
    assert header["identity"] == {"version": "6212V105", "module_number": 6212,
                                  "firmware": "1.05", "type": "TMCM-6212"}
    endpoints = {json.loads(line)["endpoint"].split()[0] for line in lines[1:]}
    assert endpoints == {"tcp", "pty"}
    code, result = replay(capsys, proxy.capture)
    summary = result[-1]["summary"]
    assert (code, result[:-1]) == (0, []), result
    assert summary["diverged"] == 0 and summary["requests"] == summary["matched"] > 50
    assert {"ENTER_DOWNLOAD_MODE", "EXIT_DOWNLOAD_MODE", "RUN_APPLICATION", "MVP", "ROR",
            "READ_PROGRAM_MEMORY"} <= set(summary["by_command"])


def _switch_reads(capsys, tool: list[str]) -> None:
    for axis in ("0", "1"):
        for number in ("9", "10", "11"):
            send(capsys, tool, "GAP", number, axis)


def _type_session(capsys, tool: list[str]) -> None:
    send(capsys, tool, "GET_FIRMWARE_VERSION")
    send(capsys, tool, "SAP", "4", "0", "51200")
    send(capsys, tool, "GAP", "4", "0")
    send(capsys, tool, "SGP", "0", "2", "7")
    send(capsys, tool, "GGP", "0", "2")


def _fault_session(capsys, tool: list[str]) -> None:
    for line in (("GAP", "4", "0"), ("GAP", "4", "0"), ("SAP", "4", "0", "1000"), ("GAP", "4", "0")):
        send(capsys, tool, *line)


PRESSED = "[[axis]]\nindex = 0\nleft = { position = 100 }\n"


@pytest.mark.parametrize(("name", "settings", "session", "options", "expected"), [
    ("another module type", {"module_type": "tmcm-1140"}, _type_session,
     ["--module-type", "tmcm-6212"],
     [("GET_FIRMWARE_VERSION type 0", '→ "1140V127"', '→ "6212V105"'),
      ("SAP 4 MaxPositioningSpeed m0 = 51200", "→ 4 INVALID_VALUE", "→ 100 OK"),
      ("GAP 4 MaxPositioningSpeed m0", "→ 100 OK = 1000", "→ 100 OK = 51200")]),
    ("a world with a switch pressed", {"world": "WORLD"}, _switch_reads, [],
     [("GAP 11 LeftLimitSwitchState m0", "→ 100 OK = 1", "→ 100 OK = 0")]),
    ("an injected fault", {"faults": ["status:opcode=GAP,type=4,count=1,status=INVALID_VALUE"]},
     _fault_session, [], [("GAP 4 MaxPositioningSpeed m0", "→ 4 INVALID_VALUE", "→ 100 OK = 51200")]),
])
def test_a_module_that_differs_on_purpose_gives_exactly_those_divergences(
        tmp_path: Path, standin, capsys, name, settings, session, options, expected) -> None:
    world = tmp_path / "pressed.toml"
    world.write_text(PRESSED)
    settings = {key: str(world) if value == "WORLD" else value for key, value in settings.items()}
    module = standin(**settings)
    proxy = ProxyProcess(tmp_path, module.tcp)
    try:
        session(capsys, ["--tcp", proxy.tcp, "--timeout", "5"])
    finally:
        code, _, err = proxy.stop(signal.SIGTERM)
    assert code == 0, err
    code, result = replay(capsys, proxy.capture, *options)
    found = [(d["request"], d["module"], d["simulator"]) for d in result[:-1]]
    assert (code, found) == (1, expected), name
    assert result[-1]["summary"]["diverged"] == len(expected)
    same = ["--world", str(world)] if "world" in settings else []  # the stand-in's own setting
    if "faults" not in settings:
        code, result = replay(capsys, proxy.capture, *same)
        assert (code, result[:-1]) == (0, []), (name, result)


def test_proxy_errors_are_one_line(tmp_path: Path, standin, capsys) -> None:
    code = tmcl(["--tcp", "127.0.0.1:1", "proxy", "--listen-tcp", "127.0.0.1:0"])
    assert code == 3 and "cannot reach the module (tcp 127.0.0.1:1)" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # argparse: a value is missing
        tmcl(["proxy", "--listen-tcp"])
    assert tmcl(["proxy"]) == 2
    assert "give at least one --listen-tcp" in capsys.readouterr().err
    module = standin(addresses=[3])  # nobody answers address 1 on its RS-485 port: no identity
    code = tmcl(["--tcp", module.tcp, "--timeout", "0.3", "proxy", "--listen-tcp", "127.0.0.1:0"])
    err = capsys.readouterr().err
    assert code == 3 and "--no-identify skips it" in err and err.count("\n") == 1
    code = tmcl(["--tcp", module.tcp, "proxy", "--listen-tcp", "127.0.0.1:0", "--capture",
                 str(tmp_path / "no" / "such" / "dir.jsonl"), "--no-identify"])
    assert code == 4 and "does not exist" in capsys.readouterr().err


def test_listen_pty_is_refused_in_one_line_on_windows(tmp_path: Path, standin) -> None:
    module = standin()
    env = {**os.environ, "TMCL_SIM_EMULATE_WINDOWS": "1"}
    result = subprocess.run(
        [sys.executable, "-m", "tmcl_server.tool", "--tcp", module.tcp, "proxy", "--listen-pty",
         str(tmp_path / "ttyX")], capture_output=True, text=True, env=env, timeout=60)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert "pseudo-terminal needs a POSIX system" in result.stderr
    assert not (tmp_path / "ttyX").exists()


def test_a_pty_host_that_reads_nothing_does_not_hold_the_other_hosts(tmp_path: Path, standin) -> None:
    """Its replies fill the pty and are dropped whole; a TCP host is served all along."""
    import serial

    from tmcl_server.protocol import Request, decode_reply

    module = standin()
    proxy = ProxyProcess(tmp_path, module.tcp)
    try:
        with serial.Serial(str(proxy.pty), 115200, timeout=1) as silent:
            request = Request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0).encode()
            silent.write(request * 12000)  # 108 kB of replies: more than a pty holds
            silent.flush()
            with ConnectionManager(f"--interface socket_serial_tmcl --port {proxy.tcp}").connect() as iface:
                iface._socket.settimeout(120)  # (each waits its turn behind the flood)
                for _ in range(3):
                    assert iface.get_axis_parameter(AP.MAX_SPEED, 0) > 0
            first = silent.read(9)  # what it does read is whole frames
            assert decode_reply(first).opcode == Opcode.GAP
    finally:
        code, _, err = proxy.stop()
    assert code == 0, err
    lines = proxy.capture.read_text().splitlines()
    tcp_replies = [line for line in lines if '"dir": "reply", "endpoint": "tcp' in line]
    assert len(tcp_replies) == 3  # the last one too: a stop waits for its line
    pty_requests = {json.loads(line)["bytes"] for line in lines if '"request", "endpoint": "pty' in line}
    assert pty_requests == {request.hex()}  # read in pieces, however late: never cut apart
