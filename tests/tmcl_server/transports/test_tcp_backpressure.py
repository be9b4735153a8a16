"""A TMCL client that sends requests but never reads the replies costs the server bounded
memory, loses no reply, and does not slow the other clients (found with issue 11 item 8)."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable

from tests.conftest import RawClient
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_reply
from tmcl_server.transports.tcp import MAX_WRITE_BUFFER
from tmcl_spec.commands import Opcode

WAIT_S = 60.0  # a fail-safe for what is due, never a pause to hope in
#: asyncio reads at most this much at once: the replies to one read may overshoot the cap.
READ_SIZE = 256 * 1024


def test_a_client_that_never_reads_is_back_pressured(
        tmcl_sim_factory: Callable[..., SimulatorThread]) -> None:
    """The flooder writes from a thread of its own with blocking sends: the kernel passes
    each frame on whole as the server reads, so no pause of the test's (a loaded machine)
    tears a frame, which the server would rightly drop after 5 ms.  Back-pressure is the
    server's own word: it stops reading once its replies fill the cap."""
    sim = tmcl_sim_factory()
    endpoint = sim.endpoints["tcp"][0]
    host, port = endpoint.rsplit(":", 1)
    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8192)  # before connect: small window
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 8192)
    sock.connect((host, int(port)))
    frame = Request(1, Opcode.GAP, 4, 0, 0).encode()
    burst = frame * 8192
    limit = 64 * 1024 * 1024  # far past the cap and the kernel's buffers
    finished = threading.Event()

    def flood() -> None:
        with contextlib.suppress(OSError):  # the test shuts the socket down at the end
            for _ in range(limit // len(burst)):
                sock.sendall(burst)
            finished.set()

    flooder = threading.Thread(target=flood, name="flooder", daemon=True)
    flooder.start()
    assert sim.server is not None
    (transport,) = [t for t in sim.server.transports if t.kind == "tcp"]
    paused = lambda: any(not c.transport.is_reading()  # type: ignore[attr-defined]  # noqa: E731
                         for c in transport.connections if c.transport)  # type: ignore[attr-defined]
    deadline = time.monotonic() + WAIT_S
    while not sim.call(paused):
        assert not finished.is_set(), "the server read everything: no back-pressure"
        assert time.monotonic() < deadline, "the server neither reads everything nor pauses"
        time.sleep(0.02)
    buffered = sim.call(lambda: max(c.transport.get_write_buffer_size()  # type: ignore[attr-defined]
                                    for c in transport.connections if c.transport))  # type: ignore[attr-defined]
    # paused: past the cap once, and not yet drained to the low mark (a quarter of it)
    assert MAX_WRITE_BUFFER // 4 < buffered <= MAX_WRITE_BUFFER + READ_SIZE, buffered
    other = RawClient(endpoint)  # served meanwhile
    assert other.request(1, Opcode.GAP, 4, 0).status == 100
    other.close()
    # the flooder reads at last: the queued replies come first, whole and in order
    sock.settimeout(WAIT_S)
    data = b""
    try:
        while len(data) < MAX_WRITE_BUFFER:
            chunk = sock.recv(1 << 20)
            assert chunk, "closed"
            data += chunk
    finally:
        with contextlib.suppress(OSError):
            sock.shutdown(socket.SHUT_RDWR)  # ends the flooder's send
        flooder.join(WAIT_S)
        sock.close()
    replies = {data[i:i + len(frame)] for i in range(0, MAX_WRITE_BUFFER // 9 * 9, len(frame))}
    assert len(replies) == 1 and decode_reply(replies.pop()).status == 100
