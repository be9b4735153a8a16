"""The contract every module type keeps, checked on each entry of MODULE_TYPES: its identity
(command 136), GAP and SAP on every parameter its table lists, a move, and every fault kind
applied or refused with a clear message.  A new module type is covered by its line in
MODULE_TYPES alone (the chip cores have their own contract test: tests/axes/test_contracts.py).
"""

from __future__ import annotations

import pytest

from tmcl_server.clock import VirtualClock
from tmcl_server.dispatch import Interface
from tmcl_server.fault_language import KINDS, FaultSpecError
from tmcl_server.faults import FaultInjector
from tmcl_server.module import TMCLModule
from tmcl_server.protocol import RawReply, Reply, Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode, Status
from tmcl_spec.modules import MODULE_TYPES, module_type
from tmcl_spec.parameters import AP

KINDS_OF_MODULE = sorted(MODULE_TYPES)
S = 1_000_000_000


class Rig:
    def __init__(self, key: str) -> None:
        self.module = TMCLModule(kind=key)
        self.sim = Simulation([self.module], VirtualClock())

    def cmd(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> Reply | RawReply:
        replies = self.sim.execute_on([self.module], Request(1, opcode, type_, motor, value),
                                      Interface.SERIAL)
        assert len(replies) == 1
        return replies[0][1]

    def ok(self, opcode: int, type_: int = 0, motor: int = 0, value: int = 0) -> int:
        reply = self.cmd(opcode, type_, motor, value)
        assert isinstance(reply, Reply) and reply.status == Status.OK, (opcode, type_, motor, reply)
        return reply.value


@pytest.mark.parametrize("key", KINDS_OF_MODULE)
def test_every_module_type_tells_who_it_is(key: str) -> None:
    rig, kind = Rig(key), module_type(key)
    version = rig.cmd(Opcode.GET_FIRMWARE_VERSION, 0)
    assert isinstance(version, RawReply) and version.data[1:9] == kind.version_string
    assert rig.ok(Opcode.GET_FIRMWARE_VERSION, 1) & 0xFFFF_FFFF == kind.version_number


@pytest.mark.parametrize("key", KINDS_OF_MODULE)
def test_gap_and_sap_answer_on_every_listed_parameter(key: str) -> None:
    rig, kind = Rig(key), module_type(key)
    for motor in range(kind.number_of_axes):
        for number, spec in sorted(kind.axis_parameters.items()):
            reply = rig.cmd(Opcode.GAP, number, motor)
            assert isinstance(reply, Reply)
            if spec.readable:
                assert reply.status == Status.OK, (key, motor, number, reply)
            else:
                assert reply.status != Status.OK, (key, motor, number, reply)
            if spec.writable and number not in (AP.TARGET_POSITION, AP.TARGET_SPEED):
                value = spec.default if spec.accepts(spec.default) else spec.minimum
                written = rig.cmd(Opcode.SAP, number, motor, value)
                assert isinstance(written, Reply) and written.status == Status.OK, (
                    key, motor, number, value, written)


@pytest.mark.parametrize("key", KINDS_OF_MODULE)
def test_every_axis_of_every_module_type_reaches_a_target(key: str) -> None:
    rig, kind = Rig(key), module_type(key)
    for motor in range(kind.number_of_axes):
        rig.ok(Opcode.MVP, 0, motor, 2000)
    rig.sim.advance(20.0)
    for motor in range(kind.number_of_axes):
        assert rig.ok(Opcode.GAP, AP.ACTUAL_POSITION, motor) == 2000, (key, motor)


@pytest.mark.parametrize("kind_name", sorted(KINDS))
@pytest.mark.parametrize("key", KINDS_OF_MODULE)
def test_every_fault_kind_is_applied_or_refused_with_a_clear_message(key: str, kind_name: str) -> None:
    rig = Rig(key)
    injector = FaultInjector.of(rig.sim)
    try:
        fault = injector.add(kind_name)
    except FaultSpecError as exc:  # refused: one line naming the fault
        assert kind_name in str(exc) and "\n" not in str(exc)
        return
    assert fault.id in injector.faults or fault.spec.kind.name == "reset"  # a reset acts at once
    # the module keeps answering (or not, as the fault says) without raising
    for _ in range(3):
        rig.sim.execute_on([rig.module], Request(1, Opcode.GAP, AP.ACTUAL_POSITION, 0, 0),
                           Interface.SERIAL)
    rig.sim.advance(0.5)
    injector.clear()
