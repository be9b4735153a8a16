"""What a command handler is given and what it may answer (shared by module and standalone mode).

A handler takes the request, the sink for later replies and the kind of bus it came from; it
returns the reply value (``None`` echoes the request's value), a :class:`RawReply` with a
special layout, or :data:`NO_REPLY`, or raises :class:`CommandError` with a status code.
"""

from __future__ import annotations

from collections.abc import Callable
from enum import Enum
from typing import Any, Protocol

from tmcl_server.protocol import Reply, Request
from tmcl_spec.commands import Status


class Interface(Enum):
    """Which kind of bus a request came from: it decides addressing and heartbeat."""

    SERIAL = "serial"  # RS-485 / USB: TCP, pty and real serial ports in the simulator
    CAN = "can"

    __hash__ = object.__hash__  # Enum hashes by name in Python code; this is on the hot path


class ReplySink(Protocol):
    """Where a module can push replies nobody asked for right now (command 138 events)."""

    def send_unsolicited(self, reply: Reply) -> None: ...


class CommandError(Exception):
    """A handler refuses a command; the reply carries ``status`` (Table 4) and ``value``
    (None: the request's value, as every TMCL firmware answers a refused command)."""

    def __init__(self, status: Status, value: int | None = None) -> None:
        super().__init__(status.name)
        self.status = int(status)
        self.value = value


#: Handler result: send nothing at all (command 137 restarts the module).
NO_REPLY = object()

Handler = Callable[[Request, ReplySink | None, Interface], Any]
