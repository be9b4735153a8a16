"""Persistent state: what survives a restart, a crash, a factory reset and a corrupt file."""

from __future__ import annotations

import json
import logging
import os

import pytest

from tests.conftest import Bench
from tmcl_server.eeprom import FILE_NAME, FORMAT_VERSION, Eeprom
from tmcl_server.module import TMCM6212
from tmcl_spec.commands import Opcode
from tmcl_spec.parameters import GP


def restart(tmp_path) -> Bench:
    return Bench(TMCM6212(1, Eeprom(tmp_path)))


def test_user_variables_survive_restart_only_when_stored(tmp_path):
    b = restart(tmp_path)
    b.ok(Opcode.SGP, 0, 2, 11)
    b.ok(Opcode.SGP, 55, 2, -55)
    b.ok(Opcode.SGP, 54, 2, 54)
    b.ok(Opcode.STGP, 0, 2)
    b.ok(Opcode.STGP, 55, 2)
    again = restart(tmp_path)
    assert [again.ok(Opcode.GGP, n, 2) for n in (0, 54, 55)] == [11, 0, -55]


def test_gp85_stops_automatic_restore(tmp_path):
    b = restart(tmp_path)
    b.ok(Opcode.SGP, 3, 2, 33)
    b.ok(Opcode.STGP, 3, 2)
    b.ok(Opcode.SGP, GP.DO_NOT_RESTORE_USER_VARIABLES, 0, 1)
    again = restart(tmp_path)
    assert again.ok(Opcode.GGP, 3, 2) == 0
    again.ok(Opcode.RSGP, 3, 2)  # still restorable by hand
    assert again.ok(Opcode.GGP, 3, 2) == 33


def test_bank0_parameters_are_stored_when_set(tmp_path):
    b = restart(tmp_path)
    b.ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 7)
    b.ok(Opcode.SGP, GP.TELEGRAM_PAUSE, 0, 3)
    b.send(Opcode.SGP, GP.SERIAL_ADDRESS, 0, 9)
    again = Bench(TMCM6212(1, Eeprom(tmp_path)))
    assert again.module.address == 9
    assert again.ok(Opcode.GGP, GP.HOST_ADDRESS, 0) == 7
    assert again.ok(Opcode.GGP, GP.TELEGRAM_PAUSE, 0) == 3


def test_suppress_reply_and_tick_timer_are_never_stored(tmp_path):
    b = restart(tmp_path)
    b.send(Opcode.SGP, GP.SUPPRESS_REPLY, 0, 1)
    again = restart(tmp_path)
    assert again.ok(Opcode.GGP, GP.SUPPRESS_REPLY, 0) == 0


def test_axis_parameters_stap_rsap(tmp_path):
    b = restart(tmp_path)
    b.ok(Opcode.SAP, 4, 2, 20000)
    b.ok(Opcode.STAP, 4, 2)
    b.ok(Opcode.SAP, 4, 2, 30000)
    b.ok(Opcode.RSAP, 4, 2)
    assert b.ok(Opcode.GAP, 4, 2) == 20000
    b.ok(Opcode.SAP, 4, 2, 30000)
    assert restart(tmp_path).ok(Opcode.GAP, 4, 2) == 20000
    assert b.status(Opcode.STAP, 3, 2) == 3  # read-only parameters cannot be stored


def test_factory_reset_erases_the_file_contents(tmp_path):
    b = restart(tmp_path)
    b.ok(Opcode.SGP, 1, 2, 5)
    b.ok(Opcode.STGP, 1, 2)
    b.send(137, 0, 0, 1234)
    assert restart(tmp_path).ok(Opcode.GGP, 1, 2) == 0


def test_file_has_format_and_version(tmp_path):
    restart(tmp_path).ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 3)
    document = json.loads((tmp_path / FILE_NAME).read_text())
    assert document["format"] == "tmcl-sim-eeprom"
    assert document["version"] == FORMAT_VERSION
    assert document["globals"] == {"76": 3}


@pytest.mark.parametrize("content", [b"{not json", b"\x00\xff" * 10, b'{"format": "other"}',
                                     b'{"format": "tmcl-sim-eeprom", "version": 99}',
                                     b'{"format": "tmcl-sim-eeprom", "version": 1, "globals": 5}'])
def test_corrupt_file_is_reported_and_left_untouched(tmp_path, caplog, content):
    path = tmp_path / FILE_NAME
    path.write_bytes(content)
    b = restart(tmp_path)
    assert b.module.eeprom.problem is not None
    assert str(path) in b.module.eeprom.problem
    assert "EEPROM file" in caplog.text
    assert b.ok(Opcode.GGP, GP.HOST_ADDRESS, 0) == 2  # factory defaults
    b.ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 5)
    b.ok(Opcode.STGP, 0, 2)
    assert path.read_bytes() == content  # never overwritten


def test_crash_during_save_keeps_the_previous_state(tmp_path, monkeypatch):
    ee = Eeprom(tmp_path)
    ee.put("globals", 76, 3)
    before = (tmp_path / FILE_NAME).read_bytes()

    def crash(*args, **kwargs):
        raise OSError("power failure")

    monkeypatch.setattr(os, "replace", crash)
    with pytest.raises(OSError):
        ee.put("globals", 76, 4)
    monkeypatch.undo()
    assert (tmp_path / FILE_NAME).read_bytes() == before
    assert Eeprom(tmp_path).get("globals", 76) == 3
    assert [p.name for p in tmp_path.iterdir()] == [FILE_NAME]  # no temp file left behind


def test_memory_only_eeprom_writes_nothing(tmp_path):
    ee = Eeprom()
    ee.put("globals", 1, 2)
    assert ee.get("globals", 1) == 2
    assert not ee.persistent


def test_the_journals_replay_in_sequence_order_and_skip_torn_lines(tmp_path, caplog):
    """What a server leaves after a crash (docs/eeprom.md, "On a server: a journal"): a
    snapshot, and stores in two journal files whose lines are replayed by their sequence
    numbers, whichever file holds them; a store a snapshot already holds changes nothing
    when replayed again; a torn line (a store cut by a crash or a full disk, never answered
    OK) is skipped with one warning, also when a later store follows it."""
    from tmcl_server.eeprom import JOURNAL_NAMES

    (tmp_path / FILE_NAME).write_text(json.dumps(
        {"format": "tmcl-sim-eeprom", "version": FORMAT_VERSION, "user_variables": {"1": 5, "2": 6}}))
    older, newer = (tmp_path / name for name in JOURNAL_NAMES)
    newer.write_bytes(b'{"n":3,"op":"put","s":"user_variables","v":{"1":5}}\n'  # in the snapshot
                      b'{"n":4,"op":"erase"}\n'
                      b'{"n":5,"op":"put","s":"user_variables","v":{"3":8}}\n')
    older.write_bytes(b'{"n":6,"op":"put","s":"user_variables","v":{"4":9}}\n'
                      b'{"n":7,"op":"put","s":"user_vari\n'  # torn, then a later store
                      b'{"n":8,"op":"replace","s":"coordinates","v":{"0":{"1":100}}}\n'
                      b'{"n":9,"op":"put","s":"globals","v":{"7')  # torn at the end
    with caplog.at_level(logging.WARNING):
        eeprom = Eeprom(tmp_path)
    assert eeprom.problem is None and eeprom.replayed == 5
    assert dict(eeprom.items("user_variables")) == {"3": 8, "4": 9}
    assert eeprom.get("coordinates", 0) == {"1": 100}
    assert [r.getMessage() for r in caplog.records if "torn" in r.getMessage()] == [
        f"EEPROM journal in {tmp_path}: 2 torn or malformed line(s) skipped (a store cut by a "
        "crash or a full disk, never answered OK)"]
    eeprom.start_journal(lambda delay, callback: None)  # a server starts: one snapshot ...
    assert all((tmp_path / name).stat().st_size == 0 for name in JOURNAL_NAMES)  # ... empties them
    assert json.loads((tmp_path / FILE_NAME).read_text())["user_variables"] == {"3": 8, "4": 9}
    eeprom.flush()
    assert sorted(p.name for p in tmp_path.iterdir()) == [FILE_NAME]


def test_a_planted_symlink_for_a_journal_is_not_followed(tmp_path):
    """Issue 36, N5: a journal name that is a symbolic link (planted in a shared state
    directory) is not written through: the store answers status 5, the link's target is
    untouched."""
    from tmcl_server.eeprom import JOURNAL_NAMES, EepromWriteError

    victim = tmp_path / "victim"
    victim.write_text("precious")
    state = tmp_path / "state"
    state.mkdir()
    eeprom = Eeprom(state)
    (state / JOURNAL_NAMES[0]).symlink_to(victim)  # planted after the server read the state
    eeprom.start_journal(lambda delay, callback: None)
    with pytest.raises(EepromWriteError):
        eeprom.put("user_variables", 1, 1)
    assert victim.read_text() == "precious"
    eeprom.flush()
