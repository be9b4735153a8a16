"""``tmcl-server`` with the CAN options: endpoints printed and in the ready file, clean stop."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import can

from tests.helpers.processes import wait_for_ready_file
from tmcl_server.cli import build_parser, config_from_args
from tmcl_server.protocol import Request, decode_can_reply
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import GP

WAIT_S = 10.0


def test_can_options_become_endpoints() -> None:
    args = build_parser().parse_args(["--no-tcp", "--can-bus", "line2", "--can", "virtual:x",
                                      "--slcan-pty", "/tmp/a", "--socketcand", "--socketcand",
                                      ":0"])
    config = config_from_args(args)
    assert config.endpoints == {"can": ["virtual:x"], "slcan": ["/tmp/a"],
                                "socketcand": ["127.0.0.1:29536", ":0"]}
    assert config.can_bus_name == "line2"


def test_server_lists_the_gateways_and_serves_the_named_bus(tmp_path: Path) -> None:
    ready, link = tmp_path / "ready.json", tmp_path / "ttySLCAN0"
    process = subprocess.Popen(
        [sys.executable, "-m", "tmcl_server", "--modules", "3", "--no-tcp", "--can-bus", "line2",
         "--socketcand", "127.0.0.1:0", "--slcan-pty", str(link), "--ready-file", str(ready)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        endpoints = wait_for_ready_file(process, ready, WAIT_S)
        assert endpoints["slcan"] == [str(link)] and endpoints["can_bus"] == ["line2"]
        host, port = endpoints["socketcand"][0].rsplit(":", 1)
        with can.Bus(interface="socketcand", host=host, port=int(port), channel="line2") as bus:
            data = Request(3, Opcode.GGP, GP.CAN_ID, 0, 0).encode_can()
            bus.send(can.Message(arbitration_id=3, is_extended_id=False, data=data))
            reply = bus.recv(WAIT_S)
            assert reply is not None and decode_can_reply(reply.data).value == 3
    finally:
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=WAIT_S)
    assert process.returncode == 0, err
    lines = out.splitlines()
    assert f"slcan {link}" in lines and "can_bus line2" in lines
    assert f"socketcand {endpoints['socketcand'][0]}" in lines
    assert not link.exists() and not ready.exists()
