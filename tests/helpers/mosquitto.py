"""A throwaway mosquitto broker on a free loopback port, for tests and benchmarks.

    broker = Broker(tmp_dir)        # started; broker.url == "mqtt://127.0.0.1:<port>"
    broker.stop(); broker.start()   # a restart keeps sessions (persistence is on)
"""

from __future__ import annotations

import getpass
import shutil
import socket
import subprocess
import time
from pathlib import Path

MOSQUITTO = shutil.which("mosquitto") or ("/usr/sbin/mosquitto"
                                          if Path("/usr/sbin/mosquitto").exists() else None)


def missing_reason() -> str | None:
    """Why MQTT tests cannot run here (None: they can); see tests/helpers/requirements.py."""
    if MOSQUITTO is None:
        return "mosquitto is not installed (apt-get install mosquitto; scripts/test.py says so)"
    return None


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Broker:
    def __init__(self, directory: Path, port: int | None = None) -> None:
        assert MOSQUITTO is not None
        self.port = port or free_port()
        self.directory = directory
        self.config = directory / "mosquitto.conf"
        self.config.write_text(
            f"listener {self.port} 127.0.0.1\n"
            "allow_anonymous true\n"
            "persistence true\n"
            f"persistence_location {directory}/\n"
            "autosave_interval 0\n"
            "set_tcp_nodelay true\n"
            "log_dest none\n"
            # started as root, mosquitto would drop to user "mosquitto" and then could not
            # write its database into our temporary directory
            f"user {getpass.getuser()}\n")
        self.proc: subprocess.Popen | None = None
        self.start()

    @property
    def url(self) -> str:
        return f"mqtt://127.0.0.1:{self.port}"

    def start(self) -> None:
        self.proc = subprocess.Popen([MOSQUITTO, "-c", str(self.config)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 10
        while True:  # readiness: poll the port with a deadline
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return
            except OSError as exc:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"mosquitto did not start: {self.proc.stderr.read()}") from exc
                time.sleep(0.02)

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(10)
        self.proc = None
