"""The virtual SLCAN adapter: pytrinamic's ``slcan_tmcl`` and python-can on the pty, and the
Lawicel conversation itself byte by byte."""

from __future__ import annotations

import os
import select
import socket
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest
from hypothesis import given
from hypothesis import strategies as st
from pytrinamic.connections import ConnectionManager
from pytrinamic.modules import TMCM6212 as PytrinamicTMCM6212

from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_can_reply
from tmcl_server.transports.can.slcan import decode_slcan_transmit, encode_slcan_frame
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import GP
from tmcl_spec.tmcm6212 import TMCM_6212

WAIT_S = 5.0  # a fail-safe for an answer that is due, never a pause to hope in


@pytest.fixture(scope="module")
def shared_sim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SimulatorThread]:
    """One simulator for the pytrinamic tests: its slcan_tmcl waits 2 s after opening a port."""
    link = tmp_path_factory.mktemp("slcan") / "ttySLCAN0"
    with SimulatorThread(clock="virtual", addresses=[1, 3], slcan=[str(link)]) as sim:
        yield sim


@pytest.fixture(scope="module")
def pytrinamic_iface(shared_sim: SimulatorThread) -> Iterator[object]:
    port = shared_sim.endpoints["slcan"][0]
    with ConnectionManager(f"--interface slcan_tmcl --port {port} --data-rate 1000000").connect() as iface:
        yield iface


def test_pytrinamic_reads_the_version_string(pytrinamic_iface: object) -> None:
    assert pytrinamic_iface.get_version_string() == TMCM_6212.version_string.decode()  # type: ignore[attr-defined]


def test_pytrinamic_sets_and_gets_parameters(pytrinamic_iface: object) -> None:
    module = PytrinamicTMCM6212(pytrinamic_iface)
    motor = module.motors[2]
    motor.linear_ramp.max_velocity = 12345
    motor.linear_ramp.max_acceleration = 5000
    assert motor.linear_ramp.max_velocity == 12345
    assert motor.linear_ramp.max_acceleration == 5000
    assert pytrinamic_iface.get_global_parameter(GP.CAN_ID, 0) == 1  # type: ignore[attr-defined]
    other = PytrinamicTMCM6212(pytrinamic_iface, module_id=3)
    assert other.motors[2].linear_ramp.max_velocity != 12345  # module 3 is another module


def test_pytrinamic_moves_to_a_position_polled_to_completion(shared_sim: SimulatorThread,
                                                             pytrinamic_iface: object) -> None:
    module = PytrinamicTMCM6212(pytrinamic_iface)
    motor = module.motors[0]
    motor.linear_ramp.max_velocity = 2000
    motor.linear_ramp.max_acceleration = 4000
    module.move_to(0, 5000)
    assert not motor.get_position_reached()
    polls = 0
    while not motor.get_position_reached():
        polls += 1
        assert polls < 200, "the move never completed"
        shared_sim.advance(0.1)
    assert motor.get_actual_position() == 5000
    assert polls > 5  # it took a while of simulated time, and the polls saw it move


class SlcanPort:
    """A host on the adapter's pty, by hand: Lawicel lines in and out."""

    def __init__(self, path: str) -> None:
        self.fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        self._buffer = b""

    def write(self, text: bytes) -> None:
        os.write(self.fd, text)

    def answer(self) -> bytes:
        """The next CR- or BEL-terminated answer."""
        while not any(end in self._buffer for end in (b"\r", b"\a")):
            readable, _, _ = select.select([self.fd], [], [], WAIT_S)
            assert readable, f"no answer (have {self._buffer!r})"
            self._buffer += os.read(self.fd, 4096)
        cut = min(i for i in (self._buffer.find(b"\r"), self._buffer.find(b"\a")) if i >= 0) + 1
        answer, self._buffer = self._buffer[:cut], self._buffer[cut:]
        return answer

    def ask(self, line: bytes) -> bytes:
        self.write(line + b"\r")
        return self.answer()

    def close(self) -> None:
        os.close(self.fd)


@pytest.fixture
def sim(tmcl_sim_factory: Callable[..., SimulatorThread], tmp_path: Path) -> SimulatorThread:
    return tmcl_sim_factory(addresses=[1, 3], slcan=[str(tmp_path / "ttySLCAN0")],
                            socketcand=["127.0.0.1:0"])


@pytest.fixture
def port(sim: SimulatorThread) -> Iterator[SlcanPort]:
    handle = SlcanPort(sim.endpoints["slcan"][0])
    yield handle
    handle.close()


def tmcl_line(can_id: int, opcode: int, type_: int = 0, motor: int = 0, value: int = 0,
              length: int = 7) -> bytes:
    data = Request(can_id, opcode, type_, motor, value).encode_can()
    return f"t{can_id:03X}{length}".encode() + (data + bytes(length - 7)).hex().upper().encode()


def test_lawicel_conversation(port: SlcanPort) -> None:
    assert port.ask(b"V") == b"V1013\r"
    assert port.ask(b"N") == b"NTMCL\r"
    assert port.ask(tmcl_line(1, Opcode.GGP, GP.CAN_ID)) == b"\a"  # channel not open yet
    assert port.ask(b"S6") == b"\r"
    assert port.ask(b"O") == b"\r"
    assert port.ask(b"S8") == b"\a"  # no bit rate change while open
    assert port.ask(b"O") == b"\a"
    assert port.ask(b"F") == b"F00\r"
    assert port.ask(tmcl_line(3, Opcode.GGP, GP.CAN_ID)) == b"z\r"
    reply = decode_slcan_transmit(port.answer().rstrip(b"\r"))
    assert reply is not None and reply.arbitration_id == 2 and reply.dlc == 7
    assert decode_can_reply(reply.data).value == 3
    assert port.ask(b"C") == b"\r"
    assert port.ask(tmcl_line(3, Opcode.GGP, GP.CAN_ID)) == b"\a"


def test_eight_byte_request_and_time_stamps(port: SlcanPort) -> None:
    assert port.ask(b"Z1") == b"\r"
    assert port.ask(b"O") == b"\r"
    assert port.ask(tmcl_line(1, Opcode.GET_FIRMWARE_VERSION, length=8)) == b"z\r"
    line = port.answer()
    assert line.startswith(b"t0028" + TMCM_6212.version_string.hex().upper().encode())
    assert len(line) == len(b"t0028") + 16 + 4 + 1  # four hex digits of milliseconds, CR


def test_listen_only_hears_but_does_not_send(sim: SimulatorThread, port: SlcanPort) -> None:
    assert port.ask(b"L") == b"\r"
    assert port.ask(tmcl_line(1, Opcode.GGP, GP.CAN_ID)) == b"\a"
    host, tcp_port = sim.endpoints["socketcand"][0].rsplit(":", 1)
    with can.Bus(interface="socketcand", host=host, port=int(tcp_port), channel="can0") as other:
        data = Request(1, Opcode.GGP, GP.CAN_ID, 0, 0).encode_can()
        other.send(can.Message(arbitration_id=1, is_extended_id=False, data=data))
        assert port.answer() == tmcl_line(1, Opcode.GGP, GP.CAN_ID) + b"\r"  # another host's
        assert port.answer().startswith(b"t0027")                           # and the reply


def test_bad_lines_are_refused_and_remote_and_extended_frames_ignored(
        sim: SimulatorThread, port: SlcanPort) -> None:
    assert port.ask(b"O") == b"\r"
    for bad in (b"t00", b"t0017001122", b"t8001" + b"00", b"tXYZ0", b"t0019" + b"00" * 9,
                b"d0011" + b"00", b"Q9", b"\xff\xfe", b"x" * 200):
        assert port.ask(bad) == b"\a", bad
    assert port.ask(b"r0017") == b"z\r"
    assert port.ask(b"T00000001" + b"7" + b"06010000000000") == b"Z\r"
    assert port.ask(b"t0013060100") == b"z\r"  # DLC 3 to a module
    assert port.ask(tmcl_line(1, Opcode.GGP, GP.CAN_ID)) == b"z\r"
    assert decode_slcan_transmit(port.answer().rstrip(b"\r")) is not None
    stats = sim.call(lambda: dict(sim.server.can_bus().modules.stats))
    assert (stats["remote"], stats["extended"], stats["bad_length"], stats["requests"]) == (1, 1, 1, 1)


def test_odd_data_digits_get_a_bel_and_the_next_line_of_the_same_write_still_counts(
        port: SlcanPort) -> None:
    assert port.ask(b"O") == b"\r"
    port.write(b"t00170601000\r" + tmcl_line(1, Opcode.GGP, GP.CAN_ID) + b"\r")  # 13 digits
    assert port.answer() == b"\a"
    assert port.answer() == b"z\r"
    reply = decode_slcan_transmit(port.answer().rstrip(b"\r"))
    assert reply is not None and decode_can_reply(reply.data).value == 1


def test_the_ack_and_the_reply_leave_in_one_write(port: SlcanPort) -> None:
    assert port.ask(b"O") == b"\r"
    port.write(tmcl_line(1, Opcode.GGP, GP.CAN_ID) + b"\r")
    readable, _, _ = select.select([port.fd], [], [], WAIT_S)
    assert readable
    data = os.read(port.fd, 4096)
    assert data.startswith(b"z\r") and data.endswith(b"\r") and data.count(b"\r") == 2


def test_stale_frames_of_a_vanished_host_are_dropped_by_close(sim: SimulatorThread,
                                                              port: SlcanPort) -> None:
    assert port.ask(b"O") == b"\r"
    port.write(tmcl_line(1, Opcode.GGP, GP.CAN_ID) + b"\r")  # the host dies before reading
    assert port.answer() == b"z\r"  # (the request went out; its reply is left unread)
    assert sim.endpoints["slcan"] and sim.server is not None
    (adapter,) = [t for t in sim.server.transports if t.kind == "slcan"]
    session = adapter.session  # type: ignore[attr-defined]
    successor = SlcanPort(sim.endpoints["slcan"][0])
    try:
        successor.write(b"C\r")
        deadline = time.monotonic() + WAIT_S
        while sim.call(lambda: session.open):  # until the adapter has taken the C
            assert time.monotonic() < deadline, "C never handled"
        assert successor.answer() == b"\r"  # the stale reply is gone, only C's answer is left
        assert successor.ask(b"O") == b"\r"
        assert successor.ask(b"F") == b"F00\r"
    finally:
        successor.close()


def test_python_can_slcan_host_and_socketcand_host_share_the_wire(sim: SimulatorThread) -> None:
    host, tcp_port = sim.endpoints["socketcand"][0].rsplit(":", 1)
    with (can.Bus(interface="slcan", channel=sim.endpoints["slcan"][0], bitrate=1_000_000,
                  sleep_after_open=0) as usb,
          can.Bus(interface="socketcand", host=host, port=int(tcp_port), channel="can0") as lan):
        request = Request(3, Opcode.GAP, 4, 0, 0).encode_can() + b"\x00"
        usb.send(can.Message(arbitration_id=3, is_extended_id=False, data=request))
        reply = usb.recv(WAIT_S)
        assert reply is not None and reply.arbitration_id == 2 and reply.dlc == 8
        heard = [lan.recv(WAIT_S), lan.recv(WAIT_S)]
        assert [(f.arbitration_id, bytes(f.data)) for f in heard if f is not None] == [
            (3, request), (2, bytes(reply.data))]


@given(can_id=st.integers(0, 0x7FF), data=st.binary(max_size=8), extended=st.booleans(),
       remote=st.booleans())
def test_slcan_lines_round_trip(can_id: int, data: bytes, extended: bool, remote: bool) -> None:
    frame = can.Message(arbitration_id=can_id << (18 if extended else 0), is_extended_id=extended,
                        is_remote_frame=remote, data=b"" if remote else data,
                        dlc=len(data))
    line = encode_slcan_frame(frame)
    assert line is not None and line.endswith(b"\r")
    decoded = decode_slcan_transmit(line[:-1])
    assert decoded is not None and decoded.equals(frame, timestamp_delta=None)


# == issue 11 item 5: every malformed line gets one BEL and nothing after it is lost =========

MALFORMED_LINES = [
    b"t00170601000",                   # odd number of data digits
    b"t0017060100000",                 # DLC 7, six data bytes
    b"t00170601000000000000",          # DLC 7, nine data bytes
    b"t001706010000000G",              # bad hex digit
    b"t0G17060100000000",              # bad hex in the id
    b"t0019" + b"00" * 9,              # DLC 9
    b"t00" ,                           # cut short
    b"T1FFFFFFF" + b"7",               # extended id, DLC 7, no data
    b"T2000000007" + b"00" * 7,        # extended id above 29 bits
    b"r0017AA",                        # remote frame with data
    b"d0011" + b"00",                  # unknown command letter
    b"S9", b"S", b"s12", b"Z2", b"M123", b"Q",  # control commands with bad arguments
    b"V1", b"\xff\xfe\x80", b"\x00",   # junk bytes
    b"t" * 64, b"x" * 65,              # at and over the line length limit
]


def test_every_malformed_line_in_one_write_gets_one_bel_then_the_valid_line_counts(
        port: SlcanPort) -> None:
    assert port.ask(b"O") == b"\r"
    port.write(b"".join(line + b"\r" for line in MALFORMED_LINES)
               + tmcl_line(1, Opcode.GGP, GP.CAN_ID) + b"\r")
    answers = [port.answer() for _ in MALFORMED_LINES]
    assert answers == [b"\a"] * len(MALFORMED_LINES)
    assert port.answer() == b"z\r"
    reply = decode_slcan_transmit(port.answer().rstrip(b"\r"))
    assert reply is not None and decode_can_reply(reply.data).value == 1


def test_a_line_without_cr_is_bounded_in_memory(sim: SimulatorThread, port: SlcanPort) -> None:
    from tmcl_server.transports.can.slcan import MAX_LINE, SlcanPtyTransport

    assert port.ask(b"O") == b"\r"
    chunk = b"t0017" + b"0" * 4091
    for _ in range(256):  # 1 MiB without a CR, as fast as the pty takes it
        view = memoryview(chunk)
        while view:
            try:
                view = view[os.write(port.fd, view):]
            except BlockingIOError:
                select.select([], [port.fd], [], WAIT_S)
    transport = next(t for t in sim.server.transports if isinstance(t, SlcanPtyTransport))
    # the adapter keeps at most one line's worth of it (asked on the server's loop)
    assert sim.call(lambda: len(transport.session._line)) <= MAX_LINE
    assert port.ask(b"") == b"\a"  # the end of the overlong line: one BEL
    assert port.ask(tmcl_line(1, Opcode.GGP, GP.CAN_ID)) == b"z\r"  # and on it goes
    reply = decode_slcan_transmit(port.answer().rstrip(b"\r"))
    assert reply is not None and decode_can_reply(reply.data).value == 1


def test_a_host_that_does_not_read_loses_whole_lines_never_parts(sim: SimulatorThread,
                                                                  port: SlcanPort) -> None:
    """Frames for a host that stops reading are dropped (the F overrun flag says so), but
    never cut: every line it reads afterwards is a whole frame."""
    assert port.ask(b"O") == b"\r"
    host, tcp_port = sim.endpoints["socketcand"][0].rsplit(":", 1)
    count = 20_000  # ~ 530 KB of SLCAN lines: far more than a pty buffers
    with socket.create_connection((host, int(tcp_port)), timeout=WAIT_S) as lan:
        lan.recv(64)
        lan.sendall(b"< open can0 >" + b"".join(
            f"< send 7{n % 256:02X} 8 {' '.join(['%02X' % (n % 256)] * 8)} >".encode()
            for n in range(count)))
        deadline = time.monotonic() + 30
        sent = lambda: sim.call(lambda: _socketcand(sim).stats["sent"])  # noqa: E731
        while sent() < count:  # until the bus has carried every frame
            assert time.monotonic() < deadline, "frames not all sent"
            time.sleep(0.05)
    data = b""
    while True:
        readable, _, _ = select.select([port.fd], [], [], 0.5)
        if not readable:
            break
        data += os.read(port.fd, 65536)
    lines = data.split(b"\r")
    assert lines[-1] == b""
    bad = [line for line in lines[:-1] if decode_slcan_transmit(line) is None]
    assert not bad, bad[:3]
    assert 0 < len(lines) - 1 < count  # some arrived, the rest were dropped whole
    assert port.ask(b"F") == b"F08\r"  # data overrun


def _socketcand(sim: SimulatorThread) -> object:
    assert sim.server is not None
    (transport,) = [t for t in sim.server.transports if t.kind == "socketcand"]
    return transport
