"""Byte-level behaviour on real sockets and ports: framing, addressing, bad input, events."""

from __future__ import annotations

import os
import random
import select
import threading
import time
import tty

import pytest

from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_reply
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import GP


@pytest.fixture
def sim():
    with SimulatorThread(clock="virtual", modules=2, tcp=["127.0.0.1:0"]) as sim:
        yield sim


def test_torn_frame_completed_without_pause_is_one_request(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    frame = Request(1, Opcode.GAP, 4, 0, 0).encode()
    client.send_raw(frame[:3])
    client.send_raw(frame[3:7])
    client.send_raw(frame[7:])
    reply = decode_reply(client.recv_exact(9))
    assert (reply.status, reply.opcode, reply.value) == (100, Opcode.GAP, 51200)


def test_partial_frame_is_dropped_after_a_pause_of_more_than_5ms(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    client.send_raw(bytes([1, Opcode.SAP, 4, 0]))  # torn: the host gave up on this one
    time.sleep(0.02)  # creates the >5 ms gap the rule is about; the result does not depend on it
    reply = client.request(1, Opcode.GAP, 4, 0)
    assert (reply.status, reply.value) == (100, 51200)
    client.expect_silence(0.05)


def test_our_own_processing_time_is_no_pause_on_the_line(sim, raw_client_factory):
    """A burst takes the server longer than 5 ms to work through; a frame torn at its end and
    completed 1 ms later (while the server was still busy) is one request, not garbage."""
    client = raw_client_factory(sim.tcp)
    request = Request(1, Opcode.GAP, 4, 0, 0).encode()
    burst = 5000
    client.send_raw(request * burst + request[:4])
    time.sleep(0.001)  # a short pause of the host, well under 5 ms
    client.send_raw(request[4:])
    replies = client.recv_exact(9 * (burst + 1))
    for n in range(burst + 1):
        reply = decode_reply(replies[9 * n:9 * n + 9])
        assert (reply.status, reply.value) == (100, 51200), n


def test_garbage_then_pause_resynchronises(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    rng = random.Random(7)
    junk = bytes(rng.choice(range(3, 256)) for _ in range(40))  # never addresses modules 1/2
    client.send_raw(junk)
    time.sleep(0.02)
    assert client.request(2, Opcode.GGP, GP.SERIAL_ADDRESS, 0).value == 2


def test_wrong_checksum_gets_status_1_and_nothing_runs(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    frame = bytearray(Request(1, Opcode.SAP, 4, 0, 777).encode())
    frame[8] ^= 0x55
    client.send_raw(bytes(frame))
    reply = decode_reply(client.recv_exact(9))
    assert (reply.host, reply.module, reply.status, reply.opcode, reply.value) == (2, 1, 1, 0, 0)
    assert client.request(1, Opcode.GAP, 4, 0).value == 51200


def test_address_filtering(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    client.send_raw(Request(3, Opcode.GAP, 1, 0, 0).encode())
    client.expect_silence()
    assert client.request(2, Opcode.GAP, 1, 0).module == 2
    client.request(2, Opcode.SGP, GP.HOST_ADDRESS, 0, 9)
    assert client.request(2, Opcode.GAP, 1, 0).host == 9


def test_client_vanishing_mid_frame_harms_nobody(sim, raw_client_factory):
    steady = raw_client_factory(sim.tcp)
    for _ in range(20):
        leaver = RawClient(sim.tcp)
        leaver.send_raw(Request(1, Opcode.SAP, 4, 0, 1).encode()[:5])
        leaver.close()
        assert steady.request(1, Opcode.GAP, 4, 0).value == 51200


def test_flood_of_junk_does_not_starve_other_clients(sim, raw_client_factory):
    steady = raw_client_factory(sim.tcp)
    flooder = raw_client_factory(sim.tcp)
    stop = threading.Event()

    def flood():
        junk = bytes([0xEE]) * 4096  # address 0xEE: nobody answers, nothing comes back
        while not stop.is_set():
            try:
                flooder.send_raw(junk)
            except OSError:
                return

    thread = threading.Thread(target=flood, daemon=True)
    thread.start()
    try:
        for n in range(200):
            assert steady.request(1, Opcode.GGP, 5, 2).value == 0, n
    finally:
        stop.set()
        thread.join(5)


def test_many_clients_in_parallel_each_get_their_own_replies(sim):
    errors: list[str] = []

    def worker(index: int) -> None:
        client = RawClient(sim.tcp)
        try:
            for n in range(100):
                value = index * 1000 + n
                client.request(1, Opcode.SGP, 100 + index, 2, value)
                got = client.request(1, Opcode.GGP, 100 + index, 2).value
                if got != value:
                    errors.append(f"client {index}: {got} != {value}")
        finally:
            client.close()

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert errors == []


def test_target_reached_event_reply_goes_to_the_asking_client(sim, raw_client_factory):
    asker = raw_client_factory(sim.tcp)
    other = raw_client_factory(sim.tcp)
    first = asker.request(1, 138, 1, 0, 0b11)
    assert (first.status, first.opcode, first.value) == (100, 138, 0b11)
    asker.request(1, Opcode.MVP, 0, 1, 5000)
    asker.request(1, Opcode.MVP, 0, 4, 5000)  # motor 4 is not in the mask
    sim.advance(3)
    event = decode_reply(asker.recv_exact(9))
    assert (event.host, event.module, event.status, event.opcode, event.value) == (
        2, 1, 128, 138, 0b10)
    asker.expect_silence(0.05)
    other.expect_silence(0.05)


def test_suppressed_replies(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    client.send_raw(Request(1, Opcode.SGP, GP.SUPPRESS_REPLY, 0, 1).encode())
    client.send_raw(Request(1, Opcode.SAP, 4, 0, 1000).encode())
    assert client.request(1, Opcode.GAP, 4, 0).value == 1000  # GAP is always answered


def test_telegram_pause_delays_the_reply(sim, raw_client_factory):
    client = raw_client_factory(sim.tcp)
    client.request(1, Opcode.SGP, GP.TELEGRAM_PAUSE, 0, 60)
    start = time.monotonic()
    client.request(1, Opcode.GAP, 1, 0)
    assert time.monotonic() - start >= 0.060


def read_exact(fd: int, n: int, timeout: float = 2.0) -> bytes:
    data = b""
    deadline = time.monotonic() + timeout
    while len(data) < n:
        ready, _, _ = select.select([fd], [], [], max(0.0, deadline - time.monotonic()))
        if not ready:
            raise TimeoutError(f"got {data.hex(' ')} only")
        data += os.read(fd, n - len(data))
    return data


def test_real_serial_port_through_pyserial():
    """--serial: the host sits on the other end of a pty pair, as on a USB-RS485 adapter."""
    master, slave = os.openpty()
    tty.setraw(master)
    port_name = os.ttyname(slave)
    try:
        with SimulatorThread(clock="virtual", serial=[f"{port_name}:115200"]) as sim:
            assert sim.endpoints["serial"] == [f"{port_name}@115200"]
            os.write(master, Request(1, Opcode.GGP, GP.SERIAL_ADDRESS, 0, 0).encode())
            assert decode_reply(read_exact(master, 9)).value == 1
            os.write(master, bytes([1, 136, 0, 0, 0, 0, 0, 0, 137]))
            assert read_exact(master, 9) == b"\x026212V105"
    finally:
        os.close(master)
        os.close(slave)
