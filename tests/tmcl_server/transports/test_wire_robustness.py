"""Issue 11, items 2, 6 and 11, on real sockets and ptys: the 5 ms resynchronisation under load,
wire-driven log floods and the connection limit, memory per connection."""

from __future__ import annotations

import os
import select
import time
import tty
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.loops import uvloop_available
from tmcl_server.protocol import Request, decode_reply
from tmcl_spec.commands import Opcode

GAP = Request(1, Opcode.GAP, 4, 0, 0).encode()  # maximum speed: 51200 by default
LOOPS = ["asyncio", pytest.param("uvloop", marks=pytest.mark.skipif(
    not uvloop_available(), reason="uvloop not installed"))]
#: 0xEE addresses nobody: the server works through it and answers nothing.
JUNK = bytes([0xEE]) * (9 * 40_000)


@contextmanager
def open_pty(link: Path) -> Iterator[int]:
    fd = os.open(link, os.O_RDWR | os.O_NOCTTY)
    tty.setraw(fd)
    try:
        yield fd
    finally:
        os.close(fd)


def read_exact(fd: int, n: int, timeout: float = 5.0) -> bytes:
    data = b""
    deadline = time.monotonic() + timeout
    while len(data) < n:
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            raise TimeoutError(f"got {len(data)} of {n} bytes")
        data += os.read(fd, n - len(data))
    return data


def silent(fd: int, seconds: float = 0.05) -> bool:
    ready, _, _ = select.select([fd], [], [], seconds)
    return not ready


def assert_all_gap_replies(data: bytes, count: int) -> None:
    assert len(data) == 9 * count
    for n in range(count):
        reply = decode_reply(data[9 * n:9 * n + 9])
        assert (reply.status, reply.value) == (100, 51200), n


# -- item 2: the 5 ms pause is measured on the line, not in our processing ---------------------


@pytest.mark.parametrize("loop", LOOPS)
def test_a_short_host_pause_never_tears_a_frame_while_the_server_is_busy_elsewhere(loop, tmp_path):
    """Another client's flood keeps the server busy far longer than 5 ms right between the two
    pieces of a frame a host sent 1 ms apart (TCP and pty): still one request, every time."""
    link = tmp_path / "tty"
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], pty=[str(link)], loop=loop) as sim, \
            open_pty(link) as port:
        ours, busy = RawClient(sim.tcp, timeout=10), RawClient(sim.tcp, timeout=10)
        try:
            for _ in range(3):
                ours.send_raw(GAP * 50 + GAP[:4])
                os.write(port, GAP * 50 + GAP[:4])
                busy.send_raw(JUNK)  # tens of milliseconds of work, arriving with our pieces
                time.sleep(0.001)  # the host's short pause
                ours.send_raw(GAP[4:])
                os.write(port, GAP[4:])
                assert_all_gap_replies(ours.recv_exact(9 * 51), 51)
                assert_all_gap_replies(read_exact(port, 9 * 51), 51)
        finally:
            ours.close()
            busy.close()


def test_a_burst_torn_at_its_end_on_the_pty_is_one_request_per_frame(tmp_path):
    """The issue's repro on the pty: 2,000 frames and 4 bytes in one write, 1 ms, the rest."""
    link = tmp_path / "tty"
    with SimulatorThread(clock="virtual", pty=[str(link)]), open_pty(link) as port:
        os.set_blocking(port, False)
        data = memoryview(GAP * 2000 + GAP[:4])
        replies = b""
        while data:  # the pty holds a few KB: write as the server reads, collect its replies
            readable, writable, _ = select.select([port], [port], [], 5.0)
            assert readable or writable
            if readable:
                replies += os.read(port, 65536)
            if writable:
                data = data[os.write(port, data):]
        time.sleep(0.001)
        os.write(port, GAP[4:])
        replies += read_exact(port, 9 * 2001 - len(replies))
        assert_all_gap_replies(replies, 2001)


@pytest.mark.parametrize("loop", LOOPS)
def test_a_real_pause_on_an_idle_server_drops_the_fragment(loop, tmp_path):
    """The other direction: more than 5 ms of silence after 4 bytes, on TCP and on the pty, and
    the next whole frame is a request of its own (one reply, nothing for the fragment)."""
    link = tmp_path / "tty"
    with SimulatorThread(clock="virtual", tcp=["127.0.0.1:0"], pty=[str(link)], loop=loop) as sim, \
            open_pty(link) as port:
        client = RawClient(sim.tcp)
        try:
            for pause in (0.008, 0.02):
                client.send_raw(bytes([1, Opcode.SAP, 4, 0]))
                os.write(port, bytes([1, Opcode.SAP, 4, 0]))
                time.sleep(pause)  # the pause the rule is about
                client.send_raw(GAP)
                os.write(port, GAP)
                assert_all_gap_replies(client.recv_exact(9), 1)
                assert_all_gap_replies(read_exact(port, 9), 1)
                client.expect_silence(0.03)
                assert silent(port, 0.03)
        finally:
            client.close()
