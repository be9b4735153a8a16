"""``tmcl-server`` (or ``tmcl proxy``) as a real process, for the tests that need one: started,
waited for through its ready file, stopped with a signal."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def wait_for_ready_file(proc: subprocess.Popen[Any], ready: Path, seconds: float = 20.0,
                        what: str = "server") -> dict[str, list[str]]:
    """The endpoints in ``ready`` (written atomically) once it exists: readiness, not a
    result, so a poll with a deadline.  AssertionError with the process's output when it
    exits first or takes longer than ``seconds`` (then it is killed)."""
    deadline = time.monotonic() + seconds
    while not ready.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            proc.kill()
            out, err = proc.communicate(timeout=10)
            raise AssertionError(f"{what} did not start: {out}\n{err}")
        time.sleep(0.01)
    endpoints: dict[str, list[str]] = json.loads(ready.read_text())
    return endpoints


class ServerProcess:
    """``python -m tmcl_server ARGS --ready-file ...`` with text pipes; ``endpoints`` is what
    it listens on.  ``preexec_fn`` runs in the child before the server (e.g. a file limit)."""

    def __init__(self, tmp_path: Path, *args: str,
                 preexec_fn: Callable[[], None] | None = None) -> None:
        self.ready_file = tmp_path / f"ready-{time.monotonic_ns()}.json"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "tmcl_server", "--ready-file", str(self.ready_file), *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=preexec_fn)
        self.endpoints = wait_for_ready_file(self.proc, self.ready_file)

    def stop(self, sig: int = signal.SIGTERM) -> tuple[int, str, str]:
        self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=20)
        return self.proc.returncode, out, err
