"""tmcl-server under Windows' constraints, emulated on Linux, end to end in a child process.

tests/helpers/windows_site/sitecustomize.py takes away what Windows lacks (pty, fcntl, termios,
tty, resource, uvloop; signal handlers on the loop; readers on anything but a socket; opening
a directory); the child's console is cp1252 and Ctrl-C reaches it as KeyboardInterrupt.  Each
test runs twice: with ``TMCL_SIM_EMULATE_WINDOWS=1`` (the server takes its Windows branches,
as on Windows) and with the constraints alone (os.name stays "posix": what a foreign
emulation that knows nothing of our switch sees).  docs/windows.md says what this covers.
"""

from __future__ import annotations

import json
import os
import queue
import signal
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.helpers.mosquitto import Broker
from tests.helpers.mosquitto import missing_reason as mosquitto_missing
from tests.helpers.requirements import needs
from tmcl_server.embed import SimulatorThread
from tmcl_server.platform import EMULATE_WINDOWS
from tmcl_server.protocol import Reply, Request, decode_can_reply, decode_reply
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.parameters import AP

SITE = Path(__file__).resolve().parents[1] / "helpers" / "windows_site"
ROOT = Path(__file__).resolve().parents[2]
WAIT_S = 20.0  # a fail-safe for what is due, never a pause to hope in
USER_BANK = 2  # global parameters bank 2: user variables, stored with STGP


def emulated_env(variant: str, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("TMCL_SIM_EMULATE", "COV"))}
    env["PYTHONPATH"] = os.pathsep.join([str(SITE), str(ROOT), env.get("PYTHONPATH", "")])
    env["PYTHONIOENCODING"] = "cp1252"
    env.pop("PYTHONUTF8", None)
    if variant == "switch":
        env[EMULATE_WINDOWS] = "1"
    env.update(extra)
    return env


class Child:
    """tmcl-server in a child process under the emulation; its first output line means it is
    up (the ready file is written before it)."""

    def __init__(self, tmp: Path, variant: str, *args: str, **env: str) -> None:
        self.ready = tmp / f"ready-{os.urandom(4).hex()}.json"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tmcl_server", "--ready-file", str(self.ready), *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=emulated_env(variant, **env),
            cwd=tmp)

    def endpoints(self) -> dict[str, list[str]]:
        assert self.proc.stdout is not None
        first = self.proc.stdout.readline()  # blocks until the server is up (or gone)
        if not first:
            _, err = self.proc.communicate(timeout=WAIT_S)
            pytest.fail(f"server did not start: {err.decode('cp1252', 'replace')}")
        assert first.startswith(b"tmcl-server: "), first
        return json.loads(self.ready.read_text())

    def interrupt(self) -> tuple[str, str]:
        """Ctrl-C: the child ends by itself, status 0, nothing but its own lines."""
        self.proc.send_signal(signal.SIGINT)
        out, err = self.proc.communicate(timeout=WAIT_S)
        text_out, text_err = out.decode("cp1252"), err.decode("cp1252")
        assert self.proc.returncode == 0, (self.proc.returncode, text_err)
        assert text_out.rstrip().endswith("tmcl-server: stopped"), text_out
        assert "Traceback" not in text_err and "Error" not in text_err, text_err
        return text_out, text_err

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


@pytest.fixture(params=["switch", "constraints"])
def variant(request: pytest.FixtureRequest) -> str:
    return request.param


@pytest.fixture
def children(tmp_path: Path) -> Iterator[list[Child]]:
    started: list[Child] = []
    yield started
    for child in started:
        child.kill()


class TcpHost:
    def __init__(self, endpoint: str) -> None:
        host, port = endpoint.rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=WAIT_S)

    def command(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> Reply:
        self.sock.sendall(Request(1, opcode, type_, motor, value).encode())
        data = b""
        while len(data) < 9:
            chunk = self.sock.recv(9 - len(data))
            assert chunk, "connection closed"
            data += chunk
        return decode_reply(data)

    def close(self) -> None:
        self.sock.close()


def test_serves_tcp_and_keeps_eeprom_stores_across_a_restart(tmp_path: Path, variant: str,
                                                            children: list[Child]) -> None:
    state = tmp_path / "state"
    args = ("--tcp", "127.0.0.1:0", "--state-dir", str(state), "--trace")
    children.append(first := Child(tmp_path, variant, *args))
    host = TcpHost(first.endpoints()["tcp"][0])
    assert host.command(Opcode.GET_FIRMWARE_VERSION, 1).value == (6212 << 16 | 0x0105)  # 6212, V1.05
    assert host.command(Opcode.SAP, AP.MAX_SPEED, 0, 12345).status == Status.OK
    assert host.command(Opcode.STAP, AP.MAX_SPEED, 0).status == Status.OK
    assert host.command(Opcode.SGP, 7, USER_BANK, -4242).status == Status.OK
    assert host.command(Opcode.STGP, 7, USER_BANK).status == Status.OK
    host.close()
    _, trace = first.interrupt()
    # the trace went to a cp1252 standard error: its arrows became "->", nothing failed
    assert "STAP 4 MaxPositioningSpeed m0 -> 100 OK" in trace, trace
    assert sorted(p.name for p in (state / "module-1").iterdir()) == ["eeprom.json"]

    children.append(second := Child(tmp_path, variant, *args))
    host = TcpHost(second.endpoints()["tcp"][0])
    assert host.command(Opcode.GAP, AP.MAX_SPEED, 0).value == 12345
    assert host.command(Opcode.GGP, 7, USER_BANK).value == -4242
    host.close()
    second.interrupt()


def test_pty_says_in_one_line_that_it_needs_posix(tmp_path: Path, variant: str) -> None:
    done = subprocess.run([sys.executable, "-m", "tmcl_server", "--no-tcp", "--pty", str(tmp_path / "tty")],
                          capture_output=True, env=emulated_env(variant), timeout=WAIT_S)
    err = done.stderr.decode("cp1252")
    assert done.returncode == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert "needs a POSIX system" in err and "--serial COMx" in err, err
    assert list(tmp_path.iterdir()) == []  # no lock file, no link left behind


def test_serial_port_through_pyserial(tmp_path: Path, variant: str,
                                      children: list[Child]) -> None:
    """A port without a descriptor the loop can watch (a COM port on Windows; here pyserial's
    socket:// handler, whose reads block as a COM port's do) is read by a thread."""
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        children.append(child := Child(tmp_path, variant, "--no-tcp", "--serial",
                                       f"socket://127.0.0.1:{port}",
                                       TMCL_SIM_EMULATE_PYSERIAL="1"))
        listener.settimeout(WAIT_S)
        line, _ = listener.accept()
    assert child.endpoints()["serial"] == [f"socket://127.0.0.1:{port}@9600"]
    with line:
        line.settimeout(WAIT_S)
        line.sendall(Request(1, Opcode.GAP, AP.MAX_CURRENT, 0, 0).encode())
        data = b""
        while len(data) < 9:
            data += line.recv(9 - len(data))
        reply = decode_reply(data)
    assert (reply.status, reply.value) == (Status.OK, 128)
    child.interrupt()


def test_can_through_python_can(tmp_path: Path, variant: str, children: list[Child]) -> None:
    """``--can socketcand:can0``: python-can's socketcand client (pure sockets, as on Windows)
    joins the child's modules to a hub; a host on the hub reaches module 1 over CAN."""
    import can

    with SimulatorThread(addresses=[9], socketcand=["127.0.0.1:0"]) as hub:
        host_name, port = hub.endpoints["socketcand"][0].rsplit(":", 1)
        config = json.dumps({"host": host_name, "port": int(port)})
        children.append(child := Child(tmp_path, variant, "--no-tcp", "--can", "socketcand:can0",
                                       CAN_CONFIG=config))
        assert child.endpoints()["can"] == ["socketcand:can0"]
        bus = can.Bus(interface="socketcand", host=host_name, port=int(port), channel="can0",
                      can_filters=[{"can_id": 2, "can_mask": 0x7FF, "extended": False}])
        try:
            bus.send(can.Message(arbitration_id=1, is_extended_id=False,
                                 data=Request(1, Opcode.GAP, AP.MAX_CURRENT, 0, 0).encode_can()))
            frame = bus.recv(timeout=WAIT_S)
        finally:
            bus.shutdown()
        child.interrupt()
    assert frame is not None, "no reply over CAN"
    reply = decode_can_reply(frame.data)
    assert (reply.opcode, reply.status, reply.value) == (Opcode.GAP, Status.OK, 128)


@needs(mosquitto_missing())
def test_mqtt_bridge(tmp_path: Path, variant: str, children: list[Child]) -> None:
    """aiomqtt (paho) watches its socket with add_reader: the loop chosen on Windows must
    have it (the selector loop, not the proactor)."""
    import paho.mqtt.client as mqtt

    broker = Broker(tmp_path)
    received: queue.Queue[tuple[str, bytes]] = queue.Queue()
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2)
    client.on_message = lambda _c, _u, message: received.put((message.topic, message.payload))
    client.connect("127.0.0.1", broker.port)
    client.subscribe("win/#", qos=1)
    client.loop_start()
    try:
        children.append(child := Child(tmp_path, variant, "--no-tcp", "--mqtt",
                                       f"{broker.url}/win"))
        child.endpoints()

        def next_on(topic: str) -> bytes:
            while True:
                got, payload = received.get(timeout=WAIT_S)
                if got == topic:
                    return payload

        assert next_on("win/status") == b"online"
        client.publish("win/1/request", Request(1, Opcode.GAP, AP.MAX_CURRENT, 0, 0).encode(),
                       qos=1)
        reply = decode_reply(next_on("win/1/reply"))
        assert (reply.status, reply.value) == (Status.OK, 128)
        child.interrupt()
        assert next_on("win/status") == b"offline"  # a clean stop, not the broker's last will
    finally:
        client.loop_stop()
        client.disconnect()
        broker.stop()


def test_the_tool_prints_decoded_frames_on_a_cp1252_console(variant: str) -> None:
    """``tmcl decode`` prints arrows; a cp1252 console shows "->" instead of failing."""
    frames = "01 06 04 00 00 00 00 00 0b 02 01 64 06 00 00 c8 00 35"
    done = subprocess.run([sys.executable, "-m", "tmcl_server.tool", "decode", frames],
                          capture_output=True, env=emulated_env(variant), timeout=WAIT_S)
    out, err = done.stdout.decode("cp1252"), done.stderr.decode("cp1252")
    assert done.returncode == 0 and not err, err
    assert "module 1 -> host 2: GAP 4 MaxPositioningSpeed m0 -> 100 OK = 51200" in out, out
