"""The behaviour snapshots: each module type and chip core runs one fixed script of host
commands, and its transcript must be the one stored in ``tests/snapshots/`` (see
tests/helpers/snapshot.py).  A change of behaviour is a diff of those files, made on purpose
with ``.venv/bin/python scripts/update_snapshots.py`` and explained in its commit."""

from __future__ import annotations

import difflib

import pytest

from tests.helpers.snapshot import COMBINATIONS, run_script, snapshot_path


@pytest.mark.parametrize(("kind", "core"), COMBINATIONS, ids=[f"{k}-{c}" for k, c in COMBINATIONS])
def test_the_transcript_is_the_stored_one(kind: str, core: str) -> None:
    path = snapshot_path(kind, core)
    stored = path.read_text() if path.exists() else ""
    now = run_script(kind, core)
    if now != stored:
        diff = "".join(list(difflib.unified_diff(
            stored.splitlines(keepends=True), now.splitlines(keepends=True),
            f"stored {path.name}", "now", n=1))[:80])
        pytest.fail(f"the behaviour of {kind} on {core} changed (if on purpose: "
                    f".venv/bin/python scripts/update_snapshots.py --only {kind}-{core}, and "
                    f"say why in the commit):\n{diff}")


def test_every_stored_transcript_belongs_to_a_combination() -> None:
    names = {snapshot_path(kind, core).name for kind, core in COMBINATIONS}
    stored = {path.name for path in snapshot_path(*COMBINATIONS[0]).parent.glob("*.txt")}
    assert stored == names
