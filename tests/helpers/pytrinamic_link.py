"""pytrinamic reaching a simulator the two ways a host on a desk does: its TCP port (the
Ethernet-to-serial interface) or its pty (the USB/RS-485 serial interface)."""

from __future__ import annotations

from typing import Any

from pytrinamic.connections import ConnectionManager

from tmcl_server.embed import SimulatorThread


def connect(sim: SimulatorThread, path: str) -> Any:
    """pytrinamic's connection to ``sim`` over ``"tcp"``, or else its pty at 115200 baud."""
    if path == "tcp":
        return ConnectionManager(f"--interface socket_serial_tmcl --port {sim.tcp}").connect()
    return ConnectionManager(f"--interface serial_tmcl --port {sim.pty} --data-rate 115200").connect()
