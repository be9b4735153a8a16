"""RFS STOP (13, type 1) ends a running reference search with a ramped stop, on every module
type and chip core (issue 34, item 1): the shape of Odemis' ``test_ref_cancel``, which starts a
referencing, cancels it 0.1 s later (RFS STOP) and expects the axis to stand, unreferenced."""

from __future__ import annotations

import pytest

from tests.helpers.snapshot import COMBINATIONS
from tmcl_server.clock import VirtualClock
from tmcl_server.dispatch import Interface
from tmcl_server.module import TMCLModule
from tmcl_server.protocol import Reply, Request
from tmcl_server.simulation import Simulation
from tmcl_spec.commands import Opcode, RfsType, Status
from tmcl_spec.parameters import AP

#: The TMCL modules (the evaluation board's firmware has no RFS).
WITH_RFS = [(kind, core) for kind, core in COMBINATIONS if core != "tmc4361a-eval"]


@pytest.mark.parametrize(("kind", "core"), WITH_RFS, ids=[f"{k}-{c}" for k, c in WITH_RFS])
def test_rfs_stop_stops_the_motor(kind: str, core: str) -> None:
    module = TMCLModule(kind=kind, chip_core=core)
    sim = Simulation([module], VirtualClock())

    def ok(opcode: int, type_: int = 0, value: int = 0) -> int:
        (_, reply), = sim.execute_on([module], Request(1, opcode, type_, 0, value),
                                     Interface.SERIAL)
        assert isinstance(reply, Reply) and reply.status == Status.OK, (opcode, type_, reply)
        return reply.value

    module.set_switch(0, "left", -10_000_000)  # far away: the search is still seeking at 0.1 s
    sim.notify_changed()
    ok(Opcode.SAP, AP.RFS_MODE, 1)
    ok(Opcode.RFS, RfsType.START)
    sim.advance(0.1)
    assert ok(Opcode.RFS, RfsType.STATUS) != 0
    assert ok(Opcode.GAP, AP.ACTUAL_SPEED) != 0
    ok(Opcode.RFS, RfsType.STOP)  # Odemis: f.cancel()
    assert ok(Opcode.RFS, RfsType.STATUS) == 0
    sim.advance(5.0)  # the ramped stop is over (at the default deceleration) long before
    assert ok(Opcode.GAP, AP.ACTUAL_SPEED) == 0
    stopped_at = ok(Opcode.GAP, AP.ACTUAL_POSITION)
    sim.advance(0.5)
    assert ok(Opcode.GAP, AP.ACTUAL_POSITION) == stopped_at != 0  # standing, not zeroed
    assert ok(Opcode.RFS, RfsType.STATUS) == 0
