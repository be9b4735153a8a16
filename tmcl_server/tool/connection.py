"""How the ``tmcl`` tool reaches a module, and the errors (with exit codes) scripts rely on.

The clients are tmcl-upload's (:mod:`tmcl_server.upload`): raw 9-byte TMCL over TCP or a
serial port / pty, or anything pytrinamic's ``ConnectionManager`` opens (imported only when
asked for).  This file adds what the tool needs beyond an upload: the 136 version string
(9 bytes with no checksum), and errors that name what went wrong.
"""

from __future__ import annotations

import argparse
import contextlib
from dataclasses import dataclass
from typing import Any

from tmcl_server.protocol import FRAME_LENGTH, Reply, Request, decode_reply
from tmcl_server.upload import PytrinamicClient, StreamClient, UploadError
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.numbers import to_int32
from tmcl_spec.package import (
    EXIT_BAD_INPUT,
    EXIT_GAVE_UP,
    EXIT_INTERRUPTED,
    EXIT_NO_REPLY,
    EXIT_REFUSED,
    EXIT_USAGE,
)

DEFAULT_TCP = "127.0.0.1:2323"


class ToolError(Exception):
    """A failure with the exit code the tool documents for it (tmcl_spec.package.EXIT_CODES)."""

    exit_code = EXIT_REFUSED


class Refused(ToolError):
    """The module answered with an error status (or did something else than asked)."""

    exit_code = EXIT_REFUSED


class UsageError(ToolError):
    """Arguments that make no sense (unknown mnemonic, parameter name, ...)."""

    exit_code = EXIT_USAGE


class NoReply(ToolError):
    """No connection, or no reply in time."""

    exit_code = EXIT_NO_REPLY


class BadInput(ToolError):
    """A file that cannot be read, assembled or decoded."""

    exit_code = EXIT_BAD_INPUT


class GaveUp(ToolError):
    """A wait (``--wait``) ended before its condition held."""

    exit_code = EXIT_GAVE_UP


class Interrupted(ToolError):
    """Ctrl-C: what was left running (or stopped) is in the message."""

    exit_code = EXIT_INTERRUPTED


class _RawStreamClient(StreamClient):
    """tmcl-upload's stream client, also able to read the 136 version string (no checksum)."""

    def exchange(self, request: Request) -> bytes:
        self._write(request.encode())
        return self._read(FRAME_LENGTH)

    def send_only(self, request: Request) -> None:
        self._write(request.encode())


class _PytrinamicClient(PytrinamicClient):
    def version_string(self) -> str:
        return str(self._interface.get_version_string(module_id=self.address))

    def send_only(self, request: Request) -> None:
        self._interface.send(request.opcode, request.type, request.motor, to_int32(request.value),
                             module_id=self.address, no_reply=True)


@dataclass
class Where:
    """Connection options as given (``--tcp``, ``--serial``, ``--connection``)."""

    tcp: str | None = None
    serial: str | None = None
    connection: str | None = None
    address: int = 1
    timeout: float = 2.0

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Where:
        chosen = [name for name in ("tcp", "serial", "connection") if getattr(args, name, None)]
        if len(chosen) > 1:
            raise UsageError(f"choose one of --tcp, --serial, --connection (got {', '.join(chosen)})")
        where = cls(getattr(args, "tcp", None), getattr(args, "serial", None),
                    getattr(args, "connection", None), getattr(args, "address", None) or 1,
                    getattr(args, "timeout", None) or 2.0)
        if not chosen:
            where.tcp = DEFAULT_TCP
        return where

    def describe(self) -> str:
        if self.connection:
            return f"pytrinamic {self.connection!r}"
        return f"serial {self.serial}" if self.serial else f"tcp {self.tcp}"


class Connection:
    """One module, reached one way; requests return :class:`Reply` or raise a ToolError."""

    def __init__(self, where: Where) -> None:
        self.where = where
        self.address = where.address
        try:
            if where.connection:
                self.client: Any = _PytrinamicClient(where.connection, where.address)
            elif where.serial:
                self.client = _RawStreamClient.serial(where.serial, where.address, where.timeout)
            else:
                self.client = _RawStreamClient.tcp(where.tcp or DEFAULT_TCP, where.address, where.timeout)
        except UploadError as exc:
            raise NoReply(str(exc)) from None
        except (OSError, ValueError) as exc:
            raise NoReply(f"cannot reach the module ({where.describe()}): {exc}") from None
        except Exception as exc:  # pytrinamic's own errors when it finds no port
            raise NoReply(f"cannot reach the module ({where.describe()}): {exc}") from None

    def __enter__(self) -> Connection:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        with contextlib.suppress(Exception):  # closing must not hide the real outcome
            self.client.close()

    def request(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> Reply:
        """Send one command and return the module's reply (any status)."""
        try:
            if isinstance(self.client, _RawStreamClient):
                return decode_reply(self.client.exchange(Request(self.address, opcode, type_, motor, value)))
            module, status, echoed, result = self.client.send(opcode, type_, motor, to_int32(value))
            return Reply(0, module, status, echoed, result)
        except TimeoutError as exc:
            raise NoReply(self._silence(opcode, exc)) from None
        except UploadError as exc:
            raise NoReply(self._silence(opcode, exc)) from None
        except OSError as exc:
            raise NoReply(f"connection failed ({self.where.describe()}): {exc}") from None
        except ValueError as exc:  # a reply with a wrong checksum
            raise NoReply(f"garbled reply: {exc}") from None
        except Exception as exc:  # pytrinamic raises its own kinds for timeouts and garbage
            raise NoReply(self._silence(opcode, exc)) from None

    def _silence(self, opcode: int, exc: object) -> str:
        return (f"no reply from module {self.address} ({self.where.describe()}) within "
                f"{self.where.timeout:g} s to command {opcode} ({exc}); is the address right, "
                "or does GP 255 suppress replies?")

    def send_no_reply(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> None:
        """A command the module does not answer (137 restarts it)."""
        try:
            self.client.send_only(Request(self.address, opcode, type_, motor, value))
        except Exception as exc:
            raise NoReply(f"connection failed ({self.where.describe()}): {exc}") from None

    def ok(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        """Send a command that must succeed; its reply value (Refused otherwise)."""
        reply = self.request(opcode, type_, motor, value)
        if reply.status not in (Status.OK, Status.LOADED):
            try:
                name = Status(reply.status).name
            except ValueError:
                name = "unknown status"
            raise Refused(f"module {self.address} refused command {opcode} type {type_} motor "
                          f"{motor} value {value}: status {reply.status} ({name})")
        return to_int32(reply.value)

    def version_string(self) -> str:
        """Command 136 type 0: e.g. ``6212V105``."""
        if isinstance(self.client, _RawStreamClient):
            try:
                data = self.client.exchange(Request(self.address, Opcode.GET_FIRMWARE_VERSION, 0, 0, 0))
            except (OSError, UploadError) as exc:
                raise NoReply(self._silence(Opcode.GET_FIRMWARE_VERSION, exc)) from None
            return data[1:FRAME_LENGTH].decode("ascii", "replace")
        try:
            return self.client.version_string()
        except Exception as exc:
            raise NoReply(self._silence(Opcode.GET_FIRMWARE_VERSION, exc)) from None
