"""Every module type on every chip core the command line offers either runs (the behaviour
snapshots cover each such combination: tests/helpers/snapshot.py) or is refused at start with
one line naming the cores it runs on (issue 34, item 10: ``--module-type tmcm-6110 --axis-core
tmc4361a`` raised ``KeyError(17)`` at the first MVP)."""

from __future__ import annotations

import pytest

from axes.cores import CHIP_CORES
from tests.helpers.snapshot import COMBINATIONS
from tmcl_server.cli import main
from tmcl_server.module import TMCLModule
from tmcl_server.module.core import chip_core_problem
from tmcl_spec.modules import MODULE_TYPES, module_type

EVERY = [(kind, core) for kind in sorted(MODULE_TYPES) for core in sorted(CHIP_CORES)]
REFUSED = [pair for pair in EVERY if pair not in COMBINATIONS]


def test_the_combinations_that_run_are_the_snapshots_ones() -> None:
    runs = [(kind, core) for kind, core in EVERY
            if chip_core_problem(module_type(kind), core) is None]
    assert sorted(runs) == sorted(COMBINATIONS)


@pytest.mark.parametrize(("kind", "core"), REFUSED, ids=[f"{k}-{c}" for k, c in REFUSED])
def test_a_combination_that_cannot_work_is_refused_at_start_in_one_line(
        kind: str, core: str, capsys: pytest.CaptureFixture[str]) -> None:
    status = main(["--module-type", kind, "--axis-core", core, "--no-tcp", "--pty", "/x/y"])
    err = capsys.readouterr().err.splitlines()
    assert status == 2 and len(err) == 1, err
    assert err[0].startswith(f"tmcl-server: error: argument --axis-core: the "
                             f"{module_type(kind).name} does not run on the {core} core ("), err
    fits = sorted(c for k, c in COMBINATIONS if k == kind)
    assert err[0].endswith(f"; it runs on {', '.join(fits)}"), err
    with pytest.raises(ValueError, match=f"does not run on the {core} core"):
        TMCLModule(kind=kind, chip_core=core)  # the embedding API refuses it alike
