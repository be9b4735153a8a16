"""Standalone mode over the wire: tmcl-upload and pytrinamic (unchanged) against the server."""

from __future__ import annotations

from pathlib import Path

import pytest
from pytrinamic.connections import ConnectionManager
from pytrinamic.tmcl import TMCLCommand

from interpreter.assembler import assemble_file
from interpreter.disassembler import disassemble
from interpreter.isa import Instruction
from interpreter.machine import wrap32
from tmcl_server.embed import SimulatorThread
from tmcl_server.tool import upload_alias as tmcl_upload

PROGRAM = """\
#include TMCLParam.tmc
#include Interrupts.inc
Counter = 7
    SAP APMaxPositioningSpeed, Motor0, 51200
    VECT TI_TIMER0, Tick
    SGP TI_TIMER0, 3, 100
    EI TI_TIMER0
    EI TI_GLOBAL
Loop:
    MVP ABS, Motor0, 25600
    WAIT POS, Motor0, 0
    MVP REL, Motor0, -25600
    WAIT POS, Motor0, 0
    JA Loop
Tick:
    GGP Counter, 2
    CALC ADD, 1
    AGP Counter, 2
    RETI
"""


def read_back(iface: object, count: int) -> list[Instruction]:
    """What pytrinamic's LoadTMCLBinaryFromModule does: legacy 134, fields from the reply."""
    program = []
    for address in range(count):
        reply = iface.send(TMCLCommand.READ_TMCL_MEMORY, 0, 0, address)  # type: ignore[attr-defined]
        program.append(Instruction(reply.module_address, reply.status, reply.command,
                                   wrap32(reply.value)))  # pytrinamic reads the value unsigned
    return program


@pytest.fixture
def source(tmp_path: Path) -> Path:
    path = tmp_path / "shuttle.tmc"
    path.write_text(PROGRAM)
    return path


def test_upload_read_back_and_disassemble_round_trip(tmcl_sim: SimulatorThread, source: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assembled = assemble_file(source)
    assert tmcl_upload([str(source), "--tcp", tmcl_sim.tcp, "--verify"]) == 0
    assert "14 commands at 0, verified" in capsys.readouterr().out
    with ConnectionManager(f"--interface socket_serial_tmcl --port {tmcl_sim.tcp}").connect() as iface:
        program = read_back(iface, len(assembled.instructions) + 1)
    assert program[-1].opcode == 0  # the end of the stored program
    assert program[:-1] == assembled.instructions
    assert disassemble(program[:-1]) == disassemble(assembled.instructions)


def test_program_runs_while_pytrinamic_talks_direct_mode(tmcl_sim: SimulatorThread, source: Path) -> None:
    assert tmcl_upload([str(source), "--tcp", tmcl_sim.tcp, "--run"]) == 0
    with ConnectionManager(f"--interface socket_serial_tmcl --port {tmcl_sim.tcp}").connect() as iface:
        positions = []
        for _ in range(10):
            tmcl_sim.advance(0.25)
            positions.append(iface.send(TMCLCommand.GAP, 1, 0, 0).value)
            assert iface.send(TMCLCommand.GET_APPLICATION_STATUS, 1, 0, 0).value >> 24 == 1  # running
        # Out to 25600 (a 1.41 s triangle ramp), then back: sampled every 250 ms.
        assert positions[:5] == sorted(positions[:5]) and 25000 < max(positions) <= 25600
        assert positions[-1] < 10000
        ticks = iface.send(TMCLCommand.GGP, 7, 2, 0).value
        # Timer 0 every 100 ms, counted by the handler; the SGP that starts it runs 20 us
        # into the program, so the 25th tick falls just after the 2.5 s simulated here.
        assert ticks == 24
        iface.send(TMCLCommand.STOP_APPLICATION, 0, 0, 0)
        assert iface.send(TMCLCommand.GGP, 128, 0, 0).value == 0


def test_upload_reports_a_refusing_module(tmcl_sim: SimulatorThread, source: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    tmcl_sim.call(lambda: tmcl_sim.simulation.module(1).write_global(81, 0, 2))
    assert tmcl_upload([str(source), "--tcp", tmcl_sim.tcp]) == 1
    assert "status 8 (WRITE_PROTECTED)" in capsys.readouterr().err


def test_upload_over_a_pty_with_the_serial_client(tmcl_sim_factory: object, tmp_path: Path,
                                                  source: Path) -> None:
    link = tmp_path / "ttyTMCL"
    sim = tmcl_sim_factory(pty=[str(link)])  # type: ignore[operator]
    assert tmcl_upload([str(source), "--serial", f"{link}:115200", "--verify"]) == 0
    stored = sim.call(lambda: sim.simulation.module(1).program.interpreter.program())
    assert stored == assemble_file(source).instructions


def test_upload_through_pytrinamic_connection_manager(tmcl_sim: SimulatorThread, source: Path) -> None:
    connection = f"--interface socket_serial_tmcl --port {tmcl_sim.tcp}"
    assert tmcl_upload([str(source), "--connection", connection, "--verify", "--run"]) == 0
    tmcl_sim.advance(0.5)
    status = tmcl_sim.call(lambda: tmcl_sim.simulation.module(1).read_global(128, 0))
    assert status == 1
