"""A TMCL client that sends requests but never reads the replies costs the server bounded
memory, loses no reply, and does not slow the other clients (found with issue 11 item 8)."""

from __future__ import annotations

import select
import socket
import time
from collections.abc import Callable

from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_reply
from tmcl_server.transports.tcp import MAX_WRITE_BUFFER
from tmcl_spec.commands import Opcode

WAIT_S = 5.0  # a fail-safe for a reply that is due, never a pause to hope in
#: asyncio reads at most this much at once: the replies to one read may overshoot the cap.
READ_SIZE = 256 * 1024


def test_a_client_that_never_reads_is_back_pressured(
        tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    sim = tmcl_sim_factory()
    endpoint = sim.endpoints["tcp"][0]
    host, port = endpoint.rsplit(":", 1)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8192)  # before connect: small window
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8192)
    sock.connect((host, int(port)))
    sock.setblocking(False)
    frame = Request(1, Opcode.GAP, 4, 0, 0).encode()
    burst = frame * 8192
    limit = 64 * 1024 * 1024  # far past the cap and the kernel's buffers
    sent = 0
    stalled_since: float | None = None
    while sent < limit:
        try:
            sent += sock.send(burst[sent % len(burst):])
            stalled_since = None
        except BlockingIOError:  # the server takes no more: wait until it stays that way
            now = time.monotonic()
            stalled_since = stalled_since or now
            if now - stalled_since > 1.0:
                break
            select.select([], [sock], [], 0.05)
    assert sim.server is not None
    (transport,) = [t for t in sim.server.transports if t.kind == "tcp"]
    buffered = sim.call(lambda: max(c.transport.get_write_buffer_size()  # type: ignore[attr-defined]
                                    for c in transport.connections if c.transport))  # type: ignore[attr-defined]
    assert sent < limit, "the server read everything: no back-pressure"
    assert buffered <= MAX_WRITE_BUFFER + READ_SIZE, buffered
    other = RawClient(endpoint)  # served meanwhile
    assert other.request(1, Opcode.GAP, 4, 0).status == 100
    other.close()
    # the flooder reads at last: the queued replies come first, whole and in order
    sock.setblocking(True)
    sock.settimeout(WAIT_S)
    data = b""
    while len(data) < MAX_WRITE_BUFFER:
        chunk = sock.recv(1 << 20)
        assert chunk, "closed"
        data += chunk
    replies = {data[i:i + len(frame)] for i in range(0, MAX_WRITE_BUFFER // 9 * 9, len(frame))}
    assert len(replies) == 1 and decode_reply(replies.pop()).status == 100
    sock.close()
