"""The server on uvloop (the ``fast`` extra) as on asyncio's loop: every transport serves."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import can
import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.modules import TMCM6212

from tests.conftest import RawClient
from tests.helpers.processes import wait_for_ready_file
from tmcl_server.embed import SimulatorThread
from tmcl_server.loops import new_event_loop, uvloop_available
from tmcl_server.protocol import Request, decode_can_reply
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import AP, GP

pytestmark = pytest.mark.skipif(not uvloop_available(), reason="uvloop is not installed")
WAIT_S = 10.0


@pytest.mark.parametrize("kind", ["asyncio", "uvloop"])
def test_pytrinamic_moves_a_motor_over_tcp_and_pty(kind: str, tmp_path: Path) -> None:
    with SimulatorThread(clock="virtual", loop=kind, tcp=["127.0.0.1:0"],
                         pty=[str(tmp_path / "tty")]) as sim:
        assert type(sim.call(lambda: __import__("asyncio").get_running_loop())).__module__ \
            .startswith("uvloop" if kind == "uvloop" else "asyncio")
        for spec in (f"--interface socket_serial_tmcl --port {sim.tcp}",
                     f"--interface serial_tmcl --port {sim.pty} --data-rate 115200"):
            with ConnectionManager(spec).connect() as iface:
                motor = TMCM6212(iface).motors[0]
                start = motor.actual_position
                motor.move_by(1000)
                sim.advance(1.0)
                assert motor.actual_position == start + 1000
                assert iface.get_version_string() == "6212V105"


def test_socketcand_and_many_tcp_clients_on_uvloop() -> None:
    with SimulatorThread(clock="virtual", loop="uvloop", tcp=["127.0.0.1:0"],
                         socketcand=["127.0.0.1:0"]) as sim:
        clients = [RawClient(sim.tcp) for _ in range(8)]
        for n, client in enumerate(clients):
            reply = client.request(1, Opcode.SGP, 10 + n, 2, n * 7)
            assert reply.status == 100
        assert [c.request(1, Opcode.GGP, 10 + n, 2).value for n, c in enumerate(clients)] == \
            [n * 7 for n in range(8)]
        for client in clients:
            client.close()
        host, port = sim.endpoints["socketcand"][0].rsplit(":", 1)
        with can.Bus(interface="socketcand", host=host, port=int(port), channel="can0") as bus:
            data = Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0).encode_can()
            bus.send(can.Message(arbitration_id=1, is_extended_id=False, data=data))
            reply = bus.recv(WAIT_S)
            assert reply is not None and decode_can_reply(reply.data).value == 51200


def test_the_command_line_runs_on_uvloop_by_default_and_on_asyncio_when_asked(tmp_path: Path) -> None:
    for extra, expected in (([], "uvloop"), (["--loop", "asyncio"], "asyncio")):
        ready = tmp_path / f"ready-{expected}.json"
        process = subprocess.Popen(
            [sys.executable, "-m", "tmcl_server", "--tcp", "127.0.0.1:0", "--ready-file", str(ready),
             "--log-level", "DEBUG", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            client = RawClient(wait_for_ready_file(process, ready, WAIT_S)["tcp"][0])
            assert client.request(1, Opcode.GGP, GP.SERIAL_ADDRESS, 0).value == 1
            client.close()
        finally:
            process.send_signal(signal.SIGTERM)
            _, err = process.communicate(timeout=WAIT_S)
        assert process.returncode == 0, err
        assert f"event loop: {expected}" in err


def test_asking_for_an_unknown_or_missing_loop_is_an_error() -> None:
    with pytest.raises(ValueError, match="unknown event loop"):
        new_event_loop("trio")
