"""USB and RS-485 addressing on byte streams, and who owns a pty link (issue 14).

The module's USB port answers whatever the address byte says; an RS-485 bus filters by
address.  A pty or serial endpoint with one module behind it is the USB port, with several
modules a bus; ``,mode=`` chooses explicitly.  TCP is an Ethernet-to-serial converter on a bus.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import tty
from pathlib import Path

import pytest
import serial

from tests.helpers.processes import ServerProcess
from tests.tmcl_server.transports.test_wire import read_exact
from tmcl_server.cli import main
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import FRAME_LENGTH, Reply, Request, decode_reply
from tmcl_server.transports.pty import LinkInUseError
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.parameters import GP

#: What a host driver for USB modules sends first to find the module: address 0, opcode 0.
NINE_ZEROS = bytes(FRAME_LENGTH)


def open_port(path: str | Path) -> serial.Serial:
    return serial.Serial(str(path), 115200, timeout=2.0)


def ask(port: serial.Serial, frame: bytes) -> Reply:
    port.write(frame)
    data = port.read(FRAME_LENGTH)
    assert len(data) == FRAME_LENGTH, f"no reply to {frame.hex(' ')} (got {data.hex(' ')})"
    return decode_reply(data)


def silent(port: serial.Serial, frame: bytes, seconds: float = 0.2) -> bool:
    port.write(frame)
    port.timeout = seconds
    try:
        return port.read(FRAME_LENGTH) == b""
    finally:
        port.timeout = 2.0


# -- one module on a pty: its USB port -------------------------------------------------------------

def test_pty_with_one_module_answers_like_usb_whatever_the_address(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    with SimulatorThread(clock="virtual", addresses=[5], pty=[str(link)]) as sim, open_port(link) as port:
        reply = ask(port, NINE_ZEROS)  # the USB host's probe
        assert (reply.host, reply.module, reply.status, reply.opcode) == (2, 5, Status.INVALID_COMMAND, 0)
        assert ask(port, Request(0, Opcode.GGP, GP.SERIAL_ADDRESS, 0, 0).encode()).value == 5
        assert ask(port, Request(77, Opcode.GAP, 4, 0, 0).encode()).value == 51200
        bad = bytearray(Request(42, Opcode.GAP, 4, 0, 0).encode())
        bad[-1] ^= 0xFF
        assert ask(port, bytes(bad)).status == Status.WRONG_CHECKSUM
        assert sim.endpoints["pty"] == [str(link)]


def test_usb_replies_ignore_the_rs485_telegram_pause(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    with SimulatorThread(clock="virtual", pty=[str(link)]) as sim, open_port(link) as port:
        ask(port, Request(1, Opcode.SGP, GP.TELEGRAM_PAUSE, 0, 255).encode())
        port.timeout = 0.15  # a bound well below GP 75's 255 ms
        assert ask(port, Request(1, Opcode.GGP, GP.TELEGRAM_PAUSE, 0, 0).encode()).value == 255
        assert sim.call(lambda: sim.module(1).reply_delay_s) == 0.255


# -- several modules on a pty: a bus ----------------------------------------------------------------

def test_pty_with_several_modules_filters_like_rs485(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    with SimulatorThread(clock="virtual", modules=2, pty=[str(link)]), open_port(link) as port:
        assert silent(port, NINE_ZEROS)
        reply = ask(port, Request(2, Opcode.GGP, GP.SERIAL_ADDRESS, 0, 0).encode())
        assert (reply.module, reply.value) == (2, 2)


def test_explicit_rs485_on_a_pty_with_one_module(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    with SimulatorThread(clock="virtual", pty=[f"{link},mode=rs485"]) as sim, open_port(link) as port:
        assert sim.endpoints["pty"] == [str(link)]
        assert silent(port, NINE_ZEROS)
        assert ask(port, Request(1, Opcode.GAP, 4, 0, 0).encode()).value == 51200


def test_usb_mode_needs_exactly_one_module(tmp_path: Path):
    with pytest.raises(ValueError, match=r"mode=usb .* 2 modules; use mode=rs485"):
        SimulatorThread(clock="virtual", modules=2, pty=[f"{tmp_path / 'p'},mode=usb"]).start()
    with pytest.raises(ValueError, match=r"mode must be usb or rs485, got 'usb2'"):
        SimulatorThread(clock="virtual", pty=[f"{tmp_path / 'p'},mode=usb2"]).start()
    with pytest.raises(ValueError, match=r"unknown option 'speed'"):
        SimulatorThread(clock="virtual", pty=[f"{tmp_path / 'p'},speed=3"]).start()


# -- a real serial port (the other end of a pty pair) ---------------------------------------------

def test_serial_port_follows_the_same_rule():
    """--serial on one end of a pty pair; the host writes and reads the other end."""
    for mode, answered in (("", True), (",mode=rs485", False)):
        master, slave = os.openpty()
        tty.setraw(master)
        try:
            with SimulatorThread(clock="virtual", serial=[f"{os.ttyname(slave)}:115200{mode}"]):
                os.write(master, NINE_ZEROS)
                readable, _, _ = select.select([master], [], [], 2.0 if answered else 0.2)
                if answered:
                    assert readable, "no reply from the USB-like serial endpoint"
                    assert decode_reply(read_exact(master, FRAME_LENGTH)).status == Status.INVALID_COMMAND
                else:
                    assert not readable, "an RS-485 endpoint must not answer address 0"
        finally:
            os.close(master)
            os.close(slave)


# -- TCP: an Ethernet-to-serial converter on RS-485 ---------------------------------------------

def test_tcp_filters_by_address_unless_told_usb(raw_client_factory):
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0", "127.0.0.1:0,mode=usb"]) as sim:
        bus, usb = (raw_client_factory(endpoint) for endpoint in sim.endpoints["tcp"])
        bus.send_raw(NINE_ZEROS)
        bus.expect_silence(0.2)
        usb.send_raw(NINE_ZEROS)
        reply = decode_reply(usb.recv_exact(FRAME_LENGTH))
        assert (reply.module, reply.status) == (1, Status.INVALID_COMMAND)


# -- who owns a pty link ---------------------------------------------------------------------------

def test_a_second_server_on_the_same_pty_path_is_refused(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    with SimulatorThread(clock="virtual", pty=[str(link)]):
        device = os.readlink(link)
        with pytest.raises(LinkInUseError, match=rf"{link} is already served by another "
                                                 rf"tmcl-server \(pid {os.getpid()}"):
            SimulatorThread(clock="virtual", pty=[str(link)]).start()
        assert os.readlink(link) == device  # the first server's link is untouched
        with open_port(link) as port:
            assert ask(port, Request(1, Opcode.GAP, 4, 0, 0).encode()).value == 51200
    assert not link.exists() and not (tmp_path / ".ttyTMCL0.lock").exists()


def test_a_killed_servers_link_does_not_block_the_next_one(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    first = ServerProcess(tmp_path, "--no-tcp", "--pty", str(link))
    first.stop(signal.SIGKILL)  # no clean-up: the link dangles, the lock file stays behind
    assert link.is_symlink() and (tmp_path / ".ttyTMCL0.lock").exists()
    with SimulatorThread(clock="virtual", pty=[str(link)]), open_port(link) as port:
        assert ask(port, Request(1, Opcode.GAP, 4, 0, 0).encode()).value == 51200


def test_a_second_server_process_says_why_it_cannot_start(tmp_path: Path):
    link = tmp_path / "ttyTMCL0"
    first = ServerProcess(tmp_path, "--no-tcp", "--pty", str(link))
    try:
        second = subprocess.run(
            [sys.executable, "-m", "tmcl_server", "--no-tcp", "--pty", str(link)],
            capture_output=True, text=True, timeout=30)
        assert second.returncode == 1
        assert f"{link} is already served by another tmcl-server (pid {first.proc.pid}" \
            in second.stderr
    finally:
        code, _, err = first.stop()
    assert code == 0, err


def test_a_pty_in_a_missing_directory_fails_and_creates_nothing(tmp_path: Path, capsys):
    link = tmp_path / "nonexistent" / "dir" / "x"
    assert main(["--no-tcp", "--pty", str(link)]) == 2  # a bad value (issue 11 item 9)
    err = capsys.readouterr().err
    assert f"directory {link.parent} does not exist" in err
    assert not (tmp_path / "nonexistent").exists()

