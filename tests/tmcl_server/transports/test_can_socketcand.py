"""python-can hosts on the simulated CAN bus through the socketcand server, end to end."""

from __future__ import annotations

import select
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator

import can
import pytest

from tests.conftest import RawClient as TcpClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Reply, Request, decode_can_reply
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.parameters import AP, GP

WAIT_S = 5.0  # a fail-safe for a reply that is due, never a pause to hope in


class CanHost:
    """A TMCL host on socketcand, listening to one reply id (as pytrinamic's filter does)."""

    def __init__(self, sim: SimulatorThread, reply_id: int | None = 2, channel: str = "can0") -> None:
        host, port = sim.endpoints["socketcand"][0].rsplit(":", 1)
        filters = None if reply_id is None else [{"can_id": reply_id, "can_mask": 0x7FF,
                                                  "extended": False}]
        self.bus = can.Bus(interface="socketcand", host=host, port=int(port), channel=channel,
                           can_filters=filters)

    def send(self, can_id: int, opcode: int, type_: int = 0, motor: int = 0, value: int = 0,
             length: int = 8) -> None:
        data = Request(can_id, opcode, type_, motor, value).encode_can()
        self.bus.send(can.Message(arbitration_id=can_id, is_extended_id=False,
                                  data=data + bytes(length - len(data))))

    def receive(self) -> can.Message:
        frame = self.bus.recv(timeout=WAIT_S)
        assert frame is not None, "no reply"
        return frame

    def command(self, can_id: int, opcode: int, type_: int = 0, motor: int = 0, value: int = 0,
                length: int = 8) -> Reply:
        self.send(can_id, opcode, type_, motor, value, length)
        reply = decode_can_reply(self.receive().data)
        assert reply.opcode == opcode
        return reply

    def close(self) -> None:
        self.bus.shutdown()


@pytest.fixture
def sim(tmcl_sim_factory: Callable[..., SimulatorThread]) -> SimulatorThread:
    return tmcl_sim_factory(addresses=[1, 3, 5], socketcand=["127.0.0.1:0"])


@pytest.fixture
def make_host(sim: SimulatorThread) -> Iterator[Callable[..., CanHost]]:
    hosts: list[CanHost] = []

    def make(**kwargs: object) -> CanHost:
        hosts.append(CanHost(sim, **kwargs))  # type: ignore[arg-type]
        return hosts[-1]

    yield make
    for host in hosts:
        host.close()


def node_stats(sim: SimulatorThread) -> Counter[str]:
    return sim.call(lambda: Counter(sim.server.can_bus().modules.stats))


def server_stats(sim: SimulatorThread) -> Counter[str]:
    assert sim.server is not None
    (transport,) = [t for t in sim.server.transports if t.kind == "socketcand"]
    return sim.call(lambda: Counter(transport.stats))  # type: ignore[attr-defined]


class RawClient:
    """A socketcand client by hand, for what python-can never sends."""

    def __init__(self, sim: SimulatorThread, open_bus: str | None = "can0",
                 small_buffers: bool = False) -> None:
        host, port = sim.endpoints["socketcand"][0].rsplit(":", 1)
        self.sock = socket.socket()
        if small_buffers:  # before connect, so the window is small from the start
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8192)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8192)
        self.sock.settimeout(WAIT_S)
        self.sock.connect((host, int(port)))
        self._buffer = b""
        assert self.element() == "< hi >"
        if open_bus is not None:
            self.sock.sendall(f"< open {open_bus} >".encode())

    def element(self) -> str:
        while b">" not in self._buffer:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise ConnectionError("closed by the server")
            self._buffer += chunk
        element, _, self._buffer = self._buffer.partition(b">")
        return element.decode().strip() + " >"


def test_three_modules_two_hosts_each_talking_to_its_own(sim: SimulatorThread,
                                                         make_host: Callable[..., CanHost]) -> None:
    sniffer = make_host(reply_id=None)
    alice = make_host(reply_id=2)
    bob = make_host(reply_id=6)
    assert bob.command(5, Opcode.SGP, GP.CAN_REPLY_ID, 0, 6).status == Status.OK  # comes on 6
    rounds = 30
    failures: list[str] = []

    def run(host: CanHost, modules: tuple[int, ...]) -> None:
        try:
            for i in range(rounds):
                module, motor, value = modules[i % len(modules)], i % 6, 1000 + i * 7 + modules[0]
                host.command(module, Opcode.SAP, AP.MAX_SPEED, motor, value)
                reply = host.command(module, Opcode.GAP, AP.MAX_SPEED, motor)
                if (reply.module, reply.value) != (module, value):
                    failures.append(f"{module}/{motor}: {reply}")
        except AssertionError as exc:
            failures.append(str(exc))

    threads = [threading.Thread(target=run, args=(alice, (1, 3))),
               threading.Thread(target=run, args=(bob, (5,)))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
    assert failures == []
    # The sniffer heard the whole wire: both hosts' requests and every reply.
    heard = Counter(sniffer.receive().arbitration_id for _ in range(2 + 4 * 2 * rounds))
    assert heard == {1: rounds, 3: rounds, 2: 2 * rounds, 5: 2 * rounds + 1, 6: 2 * rounds + 1}


def test_duplicate_id_produces_two_replies(make_host: Callable[..., CanHost]) -> None:
    host = make_host()
    host.command(5, Opcode.SGP, GP.CAN_SECONDARY_ID, 0, 1)
    host.send(1, Opcode.GGP, GP.CAN_ID, 0)
    replies = sorted((decode_can_reply(host.receive().data) for _ in range(2)),
                     key=lambda r: r.module)
    assert [(r.module, r.value) for r in replies] == [(1, 1), (5, 5)]


def test_foreign_ids_get_silence(sim: SimulatorThread, make_host: Callable[..., CanHost]) -> None:
    host = make_host()
    for can_id in (4, 7, 0x7FF):
        host.send(can_id, Opcode.GGP, GP.CAN_ID, 0)
    # Replies keep their order on the wire: a reply to a foreign id would come first.
    reply = host.command(3, Opcode.GGP, GP.CAN_ID, 0)
    assert (reply.module, reply.value) == (3, 3)
    assert node_stats(sim)["foreign"] == 3


@pytest.mark.parametrize("length", [7, 8])
def test_reply_length_mirrors_the_request(make_host: Callable[..., CanHost], length: int) -> None:
    host = make_host()
    host.send(1, Opcode.GAP, AP.MAX_SPEED, 0, length=length)
    frame = host.receive()
    assert frame.dlc == length and frame.arbitration_id == 2
    assert decode_can_reply(frame.data).status == Status.OK


def test_can_heartbeat_stops_a_moving_axis(sim: SimulatorThread,
                                           make_host: Callable[..., CanHost]) -> None:
    host = make_host()
    host.command(1, Opcode.SGP, GP.CAN_HEARTBEAT, 0, 100)
    host.command(1, Opcode.ROR, 0, 2, 3000)
    sim.advance(0.05)
    assert host.command(1, Opcode.GAP, AP.ACTUAL_SPEED, 2).value > 0
    sim.advance(0.5)  # no command for 500 ms: the heartbeat trips after 100
    assert host.command(1, Opcode.GAP, AP.ACTUAL_SPEED, 2).value == 0


def test_a_reconnecting_host_finds_the_state_intact(sim: SimulatorThread,
                                                    make_host: Callable[..., CanHost]) -> None:
    first = make_host()
    first.command(3, Opcode.SAP, AP.MAX_SPEED, 4, 4321)
    first.command(3, Opcode.ROR, 0, 1, 800)
    first.close()
    sim.advance(1.0)
    second = make_host()
    assert second.command(3, Opcode.GAP, AP.MAX_SPEED, 4).value == 4321
    assert second.command(3, Opcode.GAP, AP.ACTUAL_SPEED, 1).value > 0


def test_bad_frames_junk_and_a_flood_leave_the_bus_serving(
        sim: SimulatorThread, make_host: Callable[..., CanHost]) -> None:
    host = make_host()
    vandal = RawClient(sim)
    assert vandal.element() == "< ok >"
    vandal.sock.sendall(b"< rawmode >")
    assert vandal.element() == "< ok >"
    bad_frames = (b"< send 001 3 6 1 0 >"                      # wrong length
                  b"< sendrtr 001 7 >"                         # remote
                  b"< send 00000001 7 6 1 0 0 0 0 0 >")        # extended id
    junk = (b"\x00\xff garbage <<< >>> < send zz 9 > < send 001 9 1 2 3 4 5 6 7 8 9 > "
            b"< frobnicate > < send 001 2 100 1 >\r\n")
    vandal.sock.sendall((bad_frames + junk) * 300 + b"< " + b"x" * 5000)
    for i in range(20):  # the bus keeps serving, in order, while the flood is handled
        assert host.command(5, Opcode.SAP, AP.MAX_SPEED, 0, 100 + i).status == Status.OK
    assert host.command(5, Opcode.GAP, AP.MAX_SPEED, 0).value == 119
    vandal.sock.sendall(b"< echo >")  # the vandal's own connection still works too
    while (element := vandal.element()) != "< echo >":
        assert element.startswith("< error unknown command") or element.startswith("< frame")
    stats, node = server_stats(sim), node_stats(sim)
    assert (node["bad_length"], node["remote"], node["extended"]) == (300, 300, 300)
    assert stats["bad_commands"] == 3 * 300  # zz, 9 bytes, 100: ignored, as socketcand does
    assert stats["unknown_commands"] == 2 * 300  # "< >" (from <<< >>>) and frobnicate
    assert stats["junk_bytes"] > 5000


def test_a_client_vanishing_mid_element_harms_nobody(sim: SimulatorThread,
                                                      make_host: Callable[..., CanHost]) -> None:
    host = make_host()
    for _ in range(5):
        quitter = RawClient(sim)
        quitter.sock.sendall(b"< rawmode >< send 001 8 6 ")
        quitter.sock.close()
    assert host.command(1, Opcode.GGP, GP.CAN_ID, 0).value == 1


def test_an_unknown_bus_is_refused(sim: SimulatorThread) -> None:
    client = RawClient(sim, open_bus="vcan9")
    assert client.element() == "< error could not open bus >"
    assert client.sock.recv(1) == b""  # and the connection is closed, as socketcand does
    with pytest.raises(can.CanError):
        CanHost(sim, channel="vcan9")


def _socketcand(sim: SimulatorThread) -> object:
    assert sim.server is not None
    (transport,) = [t for t in sim.server.transports if t.kind == "socketcand"]
    return transport


def test_echo_to_a_client_that_never_reads_stays_bounded_and_loses_nothing(
        sim: SimulatorThread, make_host: Callable[..., CanHost]) -> None:
    """Issue 11 item 8: ``< echo >`` answers pile up for a client that never reads; the server
    keeps at most MAX_WRITE_BUFFER of them and stops reading that client's commands meanwhile."""
    from tmcl_server.transports.can.socketcand import MAX_WRITE_BUFFER

    flooder = RawClient(sim, small_buffers=True)  # the kernel holds little on our side
    assert flooder.element() == "< ok >"
    sock = flooder.sock
    sock.setblocking(False)
    burst = b"< echo >" * 8192
    limit = 64 * 1024 * 1024  # far past the cap and any kernel buffers: only back-pressure
    sent = 0                  # stops the flood before this
    stalled_since: float | None = None
    while sent < limit:
        try:
            sent += sock.send(burst[sent % len(burst):])
            stalled_since = None
        except BlockingIOError:  # the server took no more: wait until it stays that way
            now = time.monotonic()
            stalled_since = stalled_since or now
            if now - stalled_since > 1.0:
                break
            select.select([], [sock], [], 0.05)
    transport = _socketcand(sim)
    buffered = sim.call(lambda: max(c.transport.get_write_buffer_size()  # type: ignore[attr-defined]
                                    for c in transport.clients if c.transport))  # type: ignore[attr-defined]
    assert sent < limit, "the server read everything: no back-pressure"
    assert buffered <= MAX_WRITE_BUFFER + 64 * 1024, buffered
    # another client is served meanwhile
    other = make_host()
    assert other.command(1, Opcode.GAP, AP.MAX_SPEED, 0).status == Status.OK
    # the flooder starts reading: every echo it sent arrives, none lost
    sock.setblocking(True)
    sock.settimeout(WAIT_S)
    rest = len(b"< echo >") - sent % len(b"< echo >")
    if rest != len(b"< echo >"):  # finish the element cut by the full socket
        threading.Thread(target=sock.sendall, args=(b"< echo >"[-rest:],), daemon=True).start()
        sent += rest
    expected = sent // len(b"< echo >") * len(b"< echo >")
    received = len(flooder._buffer)
    while received < expected:
        chunk = sock.recv(1 << 20)
        assert chunk, "closed"
        received += len(chunk)
    assert received == expected
    sock.close()


def test_a_connection_flood_is_refused_past_the_limit_and_the_hosts_keep_working(
        tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    """Issue 36, N2: socketcand had no connection limit (1,100 connections took every
    descriptor and a TCP host's GAP got no reply).  Now ``--max-connections`` bounds it too:
    a host that opened the bus keeps its slot, the newcomers past the limit are closed at once
    without a greeting, counted, and the TCP host is served throughout."""
    limit = 8
    sim = tmcl_sim_factory(socketcand=["127.0.0.1:0"], tcp=["127.0.0.1:0"], max_connections=limit)
    host = CanHost(sim)
    tcp = TcpClient(sim.tcp)
    flood: list[socket.socket] = []
    try:
        assert host.command(1, Opcode.GAP, AP.MAX_SPEED, 0).status == Status.OK
        address, port = sim.endpoints["socketcand"][0].rsplit(":", 1)
        greeted = refused = 0
        for _ in range(3 * limit):
            sock = socket.create_connection((address, int(port)), timeout=WAIT_S)
            flood.append(sock)
            sock.sendall(b"< hi")  # junk, never a valid command
            try:
                data = sock.recv(16)
            except ConnectionResetError:
                data = b""
            greeted += data == b"< hi >"
            refused += data == b""
        assert (greeted, refused) == (limit - 1, 2 * limit + 1)
        assert host.command(1, Opcode.GAP, AP.MAX_SPEED, 0).status == Status.OK
        assert tcp.request(1, Opcode.GAP, AP.MAX_SPEED, 0).status == Status.OK
        transport = _socketcand(sim)
        assert sim.call(lambda: transport.connections.refused) == 2 * limit + 1  # type: ignore[attr-defined]
    finally:
        for sock in flood:
            sock.close()
        tcp.close()
        host.close()
