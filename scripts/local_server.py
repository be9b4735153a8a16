"""What the benchmarks and long runs share to start a ``tmcl-server`` process and speak to it:
waiting for its ready file, a raw 9-byte TCP host, and its resident memory.

The host is the ``tmcl`` client's own :class:`tmcl_server.upload.StreamClient` (nine bytes
out, nine back, Nagle off), so the scripts measure the server with the client users run
rather than with copies of it.  A script imports this file from its own folder (Python puts
``scripts/`` first on the path), and this file puts the checkout beside it on the path.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from tmcl_server.protocol import Reply, Request, decode_reply  # noqa: E402
from tmcl_server.upload import StreamClient, UploadError  # noqa: E402

__all__ = ["ROOT", "StreamClient", "UploadError", "request", "rss_kb", "tcp_host", "wait_for_ready"]


def wait_for_ready(proc: subprocess.Popen[Any], ready: Path, *, seconds: float = 30.0,
                   what: str = "tmcl-server", poll_s: float = 0.01,
                   details: Callable[[], str] | None = None) -> dict[str, list[str]]:
    """The endpoints a server wrote to its ``--ready-file`` (written atomically), once it is
    there; RuntimeError (the process killed) when it exits first or takes over ``seconds``.
    ``details`` says more in that error (e.g. the server's stderr)."""
    deadline = time.monotonic() + seconds
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            more = f": {details()}" if details is not None else ""
            raise RuntimeError(f"{what} did not start{more}")
        time.sleep(poll_s)
    endpoints: dict[str, list[str]] = json.loads(ready.read_text())
    return endpoints


def tcp_host(endpoint: str | tuple[str, int], timeout: float | None = 5.0) -> StreamClient:
    """A raw TMCL host on ``HOST:PORT`` (module address 1; ``timeout`` None blocks)."""
    if isinstance(endpoint, tuple):
        endpoint = f"{endpoint[0]}:{endpoint[1]}"
    return StreamClient.tcp(endpoint, 1, timeout)


def request(host: StreamClient, address: int, opcode: int, type_: int = 0, motor: int = 0,
            value: int = 0) -> Reply:
    """One request to any module address on the line, its reply checked and decoded."""
    return decode_reply(host.exchange(Request(address, opcode, type_, motor, value).encode()))


def rss_kb(pid: int) -> int:
    """A live process's resident memory in KiB (``VmRSS`` in /proc/PID/status; 0 if the
    kernel does not say)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0
