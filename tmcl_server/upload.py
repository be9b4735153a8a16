"""Download a TMCL program into a module (simulated or real) and run it: the clients and the
sequence behind ``tmcl program upload`` (and its alias ``tmcl-upload``, tmcl_server/tool/).

    tmcl-upload prog.tmc --tcp 127.0.0.1:2323 --verify --run
    tmcl-upload prog.bin --serial /tmp/ttyTMCL0:115200
    tmcl-upload prog.tmc --connection "--interface serial_tmcl --port COM4 --data-rate 9600"

``--tcp`` and ``--serial`` speak raw 9-byte TMCL themselves (the simulator's TCP port, a pty
or any serial line); ``--connection`` hands its argument to pytrinamic's ConnectionManager,
which reaches real modules over USB, RS-485 or CAN.  The sequence is the TMCL-IDE's: 132
(download from an address), every command (each answered with status 101), 133; then
optionally 134 read-back and 131/129.
"""

from __future__ import annotations

import socket
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from interpreter.assembler import assemble_file
from interpreter.isa import PROGRAM_MEMORY_SIZE, RECORD_LENGTH, Instruction, decode_program
from tmcl_server.endpoints import parse_host_port, parse_serial_spec
from tmcl_server.protocol import FRAME_LENGTH, Request, decode_reply
from tmcl_spec.commands import OPERANDS, CodeProtection, Opcode, Status
from tmcl_spec.numbers import to_int32
from tmcl_spec.parameters import GP

#: (byte 1, byte 2, byte 3, value) of a reply: module, status, opcode, value normally;
#: opcode, type, motor, value for command 134.
ReplyFields = tuple[int, int, int, int]


class UploadError(RuntimeError):
    pass


class Client(Protocol):
    def send(self, opcode: int, type_: int, motor: int, value: int) -> ReplyFields: ...

    def close(self) -> None: ...


class StreamClient:
    """Raw TMCL over a byte stream: write 9 bytes, read 9 bytes (also the scripts' TCP host)."""

    def __init__(self, write: Callable[[bytes], Any], read: Callable[[int], bytes],
                 close: Callable[[], None], address: int) -> None:
        self._write, self._read, self._close = write, read, close
        self.address = address

    @classmethod
    def tcp(cls, endpoint: str, address: int, timeout: float | None) -> StreamClient:
        """``HOST:PORT`` with Nagle off; ``timeout`` None blocks (the benchmarks' lockstep)."""
        sock = socket.create_connection(parse_host_port(endpoint), timeout=timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

        def read(n: int) -> bytes:
            data = b""
            while len(data) < n:
                chunk = sock.recv(n - len(data))
                if not chunk:
                    raise UploadError("connection closed by the module")
                data += chunk
            return data

        return cls(sock.sendall, read, sock.close, address)

    @classmethod
    def serial(cls, argument: str, address: int, timeout: float) -> StreamClient:
        import serial  # pyserial

        device, baud = parse_serial_spec(argument)
        port = serial.Serial(device, baud or 9600, timeout=timeout)

        def read(n: int) -> bytes:
            data = port.read(n)
            if len(data) != n:
                raise UploadError(f"no reply from module {address} on {device}")
            return bytes(data)

        return cls(port.write, read, port.close, address)

    def exchange(self, frame: bytes) -> bytes:
        """Write one frame, return the 9 bytes that answer it as they came (unchecked: the
        136 version string has no checksum, a host under test may judge a bad one itself)."""
        self._write(frame)
        return self._read(FRAME_LENGTH)

    def send(self, opcode: int, type_: int, motor: int, value: int) -> ReplyFields:
        frame = self.exchange(Request(self.address, opcode, type_, motor, value).encode())
        reply = decode_reply(frame)  # checks the checksum (also right for the 134 layout)
        return reply.module, reply.status, reply.opcode, reply.value

    def close(self) -> None:
        self._close()


class PytrinamicClient:
    """Any interface pytrinamic's ConnectionManager can open (USB, serial, CAN, TCP)."""

    def __init__(self, arguments: str, address: int) -> None:
        try:
            from pytrinamic.connections import ConnectionManager
        except ImportError as exc:
            raise UploadError("--connection needs pytrinamic (pip install pytrinamic)") from exc
        self._interface = ConnectionManager(arguments).connect()
        self.address = address

    @property
    def interface(self) -> Any:
        """pytrinamic's interface object (``tmcl proxy`` sends raw frames through it)."""
        return self._interface

    def send(self, opcode: int, type_: int, motor: int, value: int) -> ReplyFields:
        from pytrinamic.tmcl import TMCLReplyStatusError

        try:
            reply = self._interface.send(opcode, type_, motor, value, module_id=self.address)
        except TMCLReplyStatusError as exc:
            reply = exc.reply
        return reply.module_address, reply.status, reply.command, to_int32(reply.value)  # it is unsigned

    def close(self) -> None:
        self._interface.close()


def _expect(fields: ReplyFields, status: int, what: str) -> None:
    if fields[1] != status:
        try:
            name = Status(fields[1]).name
        except ValueError:
            name = "unknown"
        raise UploadError(f"{what}: module answered status {fields[1]} ({name})")


def upload(client: Client, instructions: Sequence[Instruction], start: int = 0,
           verify: bool = False, run: bool = False) -> None:
    """Download ``instructions`` from address ``start``; optionally read back and start.

    The code protection (GP 81) is named when it is in the way: write protection refuses the
    download, read protection makes a read-back impossible (the memory reads as empty), so
    ``verify`` is refused before anything is sent.
    """
    if verify:
        _, status, _, protection = client.send(Opcode.GGP, GP.CODE_PROTECTION, 0, 0)
        if status == Status.OK and protection & CodeProtection.READ:
            raise UploadError(f"cannot verify: the module's program memory is read-protected "
                              f"(GP 81 = {protection}), it reads back as empty; upload without "
                              "--verify, or clear GP 81 (which erases the stored program)")
    entered = client.send(Opcode.ENTER_DOWNLOAD_MODE, 0, 0, start)
    if entered[1] == Status.WRITE_PROTECTED:
        raise UploadError("enter download mode: module answered status 8 (WRITE_PROTECTED): its "
                          "program memory is write-protected (GP 81 bit 1)")
    _expect(entered, Status.OK, "enter download mode")
    try:
        for address, ins in enumerate(instructions, start):
            fields = client.send(ins.opcode, ins.type, ins.motor, ins.value)
            _expect(fields, Status.LOADED, f"command at address {address}")
    finally:
        _expect(client.send(Opcode.EXIT_DOWNLOAD_MODE, 0, 0, 0), Status.OK, "exit download mode")
    if verify:
        for address, ins in enumerate(instructions, start):
            opcode, type_, motor, value = client.send(Opcode.READ_PROGRAM_MEMORY, 0, 0, address)
            if (opcode, type_, motor, value) != tuple(ins):
                raise UploadError(f"verify: address {address} holds "
                                  f"{(opcode, type_, motor, value)}, expected {tuple(ins)}")
    if run:
        _expect(client.send(Opcode.RESET_APPLICATION, 0, 0, 0), Status.OK, "reset application")
        _expect(client.send(Opcode.RUN_APPLICATION, 1, 0, start), Status.OK, "run application")


#: What a program may hold: the TMCL commands (opcodes 1..71 with mnemonics).  A record with
#: another opcode would not be stored in download mode but executed (137: a factory reset).
STORABLE_OPCODES = frozenset(int(opcode) for opcode in OPERANDS)


def load_program(path: Path, include: Sequence[Path] = ()) -> list[Instruction]:
    """A ``.bin`` file as is (every record a program command), anything else assembled as
    TMCL source."""
    if path.suffix.lower() == ".bin":
        with path.open("rb") as stream:  # at most a full program memory and one record more
            data = stream.read((PROGRAM_MEMORY_SIZE + 1) * RECORD_LENGTH)
        if len(data) > PROGRAM_MEMORY_SIZE * RECORD_LENGTH:
            raise ValueError(f"longer than a program memory ({PROGRAM_MEMORY_SIZE} records)")
        instructions = decode_program(data)
        check_storable(instructions)
        return instructions
    return assemble_file(path, include).instructions


def check_storable(instructions: Sequence[Instruction]) -> None:
    """ValueError naming the first record that is not a program command."""
    for index, ins in enumerate(instructions):
        if ins.opcode not in STORABLE_OPCODES:
            try:
                name = f" ({Opcode(ins.opcode).name})"
            except ValueError:
                name = ""
            raise ValueError(f"record {index} (bytes {index * RECORD_LENGTH}..{index * RECORD_LENGTH + 7}) "
                             f"holds command {ins.opcode}{name}, not a program command: nothing uploaded")
