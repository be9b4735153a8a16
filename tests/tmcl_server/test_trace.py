"""The telegram trace end to end: a real ``tmcl-server --trace`` and real clients.

pytrinamic over TCP and over the pty, a raw socket for what pytrinamic never sends (torn
frames, foreign addresses, wrong checksums, GP 255), python-can through socketcand for CAN
ids; then the trace file is read back.
"""

from __future__ import annotations

import asyncio
import io
import json
import time
from pathlib import Path

import aiomqtt
import can
from pytrinamic.connections import ConnectionManager

from tests.conftest import RawClient
from tests.helpers.mosquitto import Broker, missing_reason
from tests.helpers.requirements import needs
from tests.tmcl_server.test_cli import ServerProcess
from tmcl_server.embed import SimulatorThread
from tmcl_server.protocol import Request, decode_can_reply
from tmcl_server.server import ServerConfig
from tmcl_server.trace import Tracer
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.parameters import AP, GP

WAIT_S = 5.0  # fail-safe for a reply that is due


def _lines(path: Path, marker: str) -> list[str]:
    return [line for line in path.read_text().splitlines() if marker in line]


def _wait_for(trace: Path, text: str, timeout: float = 60.0) -> None:
    """Until the trace file (flushed within FLUSH_DELAY_S) has a line with ``text``."""
    deadline = time.monotonic() + timeout
    while not (trace.exists() and text in trace.read_text(encoding="utf-8")):
        assert time.monotonic() < deadline, f"no {text!r} in the trace"
        time.sleep(0.01)


def test_trace_of_pytrinamic_over_tcp_and_pty_and_of_frames_nobody_answers(tmp_path: Path) -> None:
    trace = tmp_path / "trace.txt"
    link = tmp_path / "ttyTMCL0"
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--pty", str(link), "--trace", str(trace))
    try:
        tcp = server.endpoints["tcp"][0]
        with ConnectionManager(f"--interface socket_serial_tmcl --port {tcp}").connect() as iface:
            iface.set_axis_parameter(AP.MAX_SPEED, 0, 51200)
            assert iface.get_axis_parameter(AP.MAX_SPEED, 0) == 51200
            assert iface.get_version_string() == "6212V105"
        pty = f"--interface serial_tmcl --port {link} --data-rate 115200"
        with ConnectionManager(pty).connect() as iface:
            assert iface.get_global_parameter(GP.SERIAL_ADDRESS, 0) == 1
        raw = RawClient(tcp)
        host_port = raw.sock.getsockname()[1]
        raw.send_raw(Request(7, Opcode.GAP, 1, 0, 0).encode())  # nobody has address 7
        raw.send_raw(Request(1, Opcode.GAP, 1, 0, 0).encode()[:5])  # half a frame ...
        time.sleep(0.02)  # ... a pause longer than 5 ms (the stimulus, not a wait for a result)
        # a loaded server may read the half frame only now; the next frame waits until it has
        # seen the pause, or it would continue the half frame (the 5 ms count from its read)
        _wait_for(trace, "torn frame: 5 of 9 bytes")
        assert raw.request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0).status == Status.OK
        bad = bytearray(Request(1, Opcode.GAP, 1, 0, 0).encode())
        bad[8] ^= 0xFF
        raw.send_raw(bytes(bad))
        assert raw.recv_exact(9)[2] == Status.WRONG_CHECKSUM  # a wrong checksum IS answered
        raw.send_raw(Request(1, Opcode.SGP, GP.SUPPRESS_REPLY, 0, 1).encode())  # answered by nothing
        assert raw.request(1, Opcode.GGP, GP.SUPPRESS_REPLY, 0).value == 1  # GGP always is
        raw.close()
    finally:
        code, _, err = server.stop()
    assert code == 0, err
    commands = _lines(trace, " cmd ")  # a request and its reply, on one line
    requests = _lines(trace, " req ")  # a request whose reply has a line of its own, or none
    replies = _lines(trace, " reply ")
    assert any(line.endswith("SAP 4 MaxPositioningSpeed m0 = 51200 → 100 OK") for line in commands)
    assert any(line.endswith("GAP 4 MaxPositioningSpeed m0 → 100 OK = 51200") for line in commands)
    assert any(line.endswith('GET_FIRMWARE_VERSION type 0 → "6212V105"') for line in commands)
    pty_lines = [line for line in commands if f"pty {link}" in line]
    assert any(line.endswith("GGP 66 SerialAddress b0 → 100 OK = 1") for line in pty_lines)
    tcp_lines = [line for line in commands if " tcp 127.0.0.1:" in line]
    assert tcp_lines and all(line.split()[0].count(":") == 2 for line in tcp_lines)  # wall time
    drops = _lines(trace, " drop ")
    assert drops and all(f" tcp 127.0.0.1:{host_port} " in line for line in drops)  # the host's end
    assert any("no module has address 7: no reply" in line for line in drops)
    assert any("torn frame: 5 of 9 bytes" in line and "dropped (01 06 01 00 00)" in line
               for line in drops)
    assert any("(wrong checksum) → 1 WRONG_CHECKSUM" in line for line in replies)
    assert any("SGP 255 SuppressReply b0 = 1: reply suppressed by GP 255" in line
               for line in _lines(trace, " noreply "))
    assert sum("SGP 255 SuppressReply b0 = 1" in line for line in requests) == 1  # once, not twice
    assert any(line.endswith("GGP 255 SuppressReply b0 → 100 OK = 1") for line in commands)


def test_trace_names_can_ids_and_reports_two_modules_on_one_id(tmp_path: Path) -> None:
    trace = tmp_path / "trace.jsonl"
    server = ServerProcess(tmp_path, "--no-tcp", "--modules", "2", "--socketcand", "127.0.0.1:0",
                           "--trace", str(trace), "--trace-format", "jsonl")
    try:
        host, port = server.endpoints["socketcand"][0].rsplit(":", 1)
        bus = can.Bus(interface="socketcand", host=host, port=int(port), channel="can0")
        try:
            def ask(can_id: int, request: Request) -> list[can.Message]:
                bus.send(can.Message(arbitration_id=can_id, is_extended_id=False,
                                     data=request.encode_can() + b"\0"))
                return [bus.recv(WAIT_S)]

            reply = decode_can_reply(ask(2, Request(2, Opcode.SGP, GP.CAN_SECONDARY_ID, 0, 1))[0].data)
            assert reply.status == Status.OK  # module 2 now also answers CAN id 1
            first = ask(1, Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0))
            second = bus.recv(WAIT_S)  # the other module's reply to the same request
            assert second is not None
            assert {decode_can_reply(m.data).module for m in (*first, second)} == {1, 2}
            bus.send(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\x06\x01\0\0\0\0\0"))
            ask(1, Request(1, Opcode.GGP, GP.CAN_ID, 0, 0))  # in order: the stray frame came first
            bus.recv(WAIT_S)
        finally:
            bus.shutdown()
    finally:
        code, _, err = server.stop()
    assert code == 0, err
    records = [json.loads(line) for line in trace.read_text().splitlines()]
    gap = [r for r in records if r["kind"] == "req" and r.get("opcode") == Opcode.GAP]
    assert gap and gap[0]["endpoint"] == "can can0 id 001" and gap[0]["parameter"] == "MaxPositioningSpeed"
    assert gap[0]["bytes"] == Request(1, Opcode.GAP, AP.MAX_SPEED, 0, 0).encode_can().hex()
    gap_replies = [r for r in records if r["kind"] == "reply" and r.get("opcode") == Opcode.GAP]
    assert {r["module"] for r in gap_replies} == {1, 2}
    assert {r["endpoint"] for r in gap_replies} == {"can can0 id 001 reply id 002"}
    assert all(r["status_name"] == "OK" and r["reply_value"] == 51200 for r in gap_replies)
    sgp = [r for r in records if r["kind"] == "cmd" and r["opcode"] == Opcode.SGP]  # one module: one line
    assert sgp and sgp[0]["endpoint"] == "can can0 id 002 reply id 002" and sgp[0]["status"] == 100
    assert sgp[0]["reply_bytes"] == "026409000000" + "01"  # the CAN payload: id, status, opcode, value
    warnings = [r for r in records if r["kind"] == "warn"]  # GAP and GGP, both to CAN id 1
    assert len(warnings) == 2 and all("2 modules answered CAN id 1" in w["text"] for w in warnings)
    stray, = [r for r in records if r["kind"] == "drop"]
    assert stray["can_id"] == 0x123 and stray["reason"] == "no module has this CAN id"
    assert all(isinstance(r["wall"], float) and isinstance(r["sim"], float) for r in records)


PROGRAM = [  # a timer interrupt every 50 ms counting in user variable 0, stopped after 3
    (Opcode.VECT, 0, 0, 6), (Opcode.SGP, 0, 3, 50), (Opcode.EI, 0, 0, 0), (Opcode.EI, 255, 0, 0),
    (Opcode.WAIT, 0, 0, 17), (Opcode.STOP, 0, 0, 0),
    (Opcode.GGP, 0, 2, 0), (Opcode.CALC, 0, 0, 1), (Opcode.AGP, 0, 2, 0), (Opcode.RETI, 0, 0, 0),
]


def test_trace_shows_program_start_stop_interrupts_and_138_events(tmcl_sim_factory) -> None:
    sim: SimulatorThread = tmcl_sim_factory()
    stream = io.StringIO()
    tracer = sim.call(lambda: Tracer(stream).attach(sim.simulation))
    client = RawClient(sim.tcp)
    try:
        client.request(1, Opcode.ENTER_DOWNLOAD_MODE)
        for opcode, type_, motor, value in PROGRAM:
            assert client.request(1, opcode, type_, motor, value).status == Status.LOADED
        client.request(1, Opcode.EXIT_DOWNLOAD_MODE)
        client.request(1, Opcode.RUN_APPLICATION, 1, 0, 0)
        client.request(1, Opcode.TARGET_REACHED_EVENT, 0, 0, 0b10)
        client.request(1, Opcode.MVP, 0, 1, 100)
        sim.advance(1.0)
        event = client.recv_exact(9)
        assert event[2] == Status.TARGET_REACHED_EVENT
    finally:
        client.close()
        sim.call(tracer.detach)
    lines = stream.getvalue().splitlines()
    events = [line.split(" event ", 1)[1].strip() for line in lines if " event " in line]
    assert "program_started pc 0" in events
    assert events.count("interrupt_taken vector 0 address 6") == 3  # 50, 100, 150 ms
    assert any(e.startswith("program_stopped") for e in events)
    assert "target_reached axis 1" in events
    assert any(e == "TARGET_REACHED_EVENT → 128 TARGET_REACHED_EVENT axes 1" for e in events)
    assert any(line.endswith("MVP ABS m1 100 → 100 OK") for line in lines)
    assert any(line.endswith("VECT 0 6 → 101 LOADED") for line in lines)  # stored while downloading


@needs(missing_reason())
def test_trace_names_the_mqtt_topic_a_request_came_on(tmp_path: Path) -> None:
    broker = Broker(tmp_path)
    trace = tmp_path / "trace.txt"
    sim = SimulatorThread(ServerConfig(clock="virtual", trace=str(trace),
                                       endpoints={"mqtt": [f"{broker.url}/rig"]})).start()
    try:
        async def ask() -> list[bytes]:
            async with aiomqtt.Client("127.0.0.1", broker.port) as client:
                await client.subscribe("rig/1/reply", qos=1)
                request = Request(1, Opcode.GAP, AP.MAX_SPEED, 2, 0).encode()
                await client.publish("rig/1/request", request, qos=1)
                await client.publish("rig/1/request", request[:8] + b"\0", qos=1)  # wrong checksum
                replies = []
                async for message in client.messages:
                    replies.append(bytes(message.payload))  # type: ignore[arg-type]
                    if len(replies) == 2:
                        return replies
            raise AssertionError("no reply")

        assert [reply[2] for reply in asyncio.run(asyncio.wait_for(ask(), WAIT_S))] == [100, 1]
    finally:
        sim.stop()
        broker.stop()
    replies = _lines(trace, " cmd ")
    assert any(" mqtt rig/1/request " in line
               and line.endswith("GAP 4 MaxPositioningSpeed m2 → 100 OK = 51200") for line in replies)
    assert any(" mqtt rig/1/request " in line and line.endswith("(wrong checksum) → 1 WRONG_CHECKSUM")
               for line in _lines(trace, " reply "))


def test_on_a_real_clock_each_exchange_carries_the_time_the_module_handled_it() -> None:
    """The module is brought up to the clock before the tracer notes the request, so the
    simulated-time column is the request's own time, not the previous request's."""
    from tests.helpers.clocks import ManualClock
    from tmcl_server.module import TMCM6212
    from tmcl_server.simulation import Simulation

    clock = ManualClock()
    simulation = Simulation([TMCM6212()], clock)
    stream = io.StringIO()
    Tracer(stream, "jsonl").attach(simulation)
    for t_ns in (1_000_000_000, 2_500_000_000, 2_750_000_000):
        clock.t = t_ns
        routed = simulation.handle_serial_frame(Request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0).encode())
        assert routed[0][1].status == Status.OK
    lines = [json.loads(line) for line in stream.getvalue().splitlines()]
    assert [line["sim"] for line in lines if line["kind"] == "cmd"] == [1.0, 2.5, 2.75]
    times = [line["sim"] for line in lines]  # events that fell due meanwhile come first
    assert times == sorted(times)
