"""Issue 11 item 4: a malformed ``eeprom.json`` never stops the module from starting.

Every file here must leave the module answering on factory defaults, the file byte for byte
as it was, and one warning that names the file and the field at fault.
"""

from __future__ import annotations

import json
import logging
import os

import pytest

from tests.conftest import Bench, RawClient
from tests.helpers.processes import ServerProcess
from tmcl_server.eeprom import FILE_NAME, Eeprom
from tmcl_server.module import TMCM6212, TMCLModule
from tmcl_spec.commands import Opcode
from tmcl_spec.modules import MODULE_TYPES
from tmcl_spec.parameters import GP


def _doc(**sections: object) -> bytes:
    return json.dumps({"format": "tmcl-sim-eeprom", "version": 1, **sections}).encode()


#: (file content, the field the warning must name)
MALFORMED = {
    # the files
    "axis-row-not-object": (_doc(axis_parameters={"0": 5}), "axis_parameters.0"),
    "program-address-out-of-memory": (_doc(program={"99999": [22, 0, 0, 0]}), "program.99999"),
    "global-key-not-a-number": (_doc(globals={"abc": 1}), "globals.abc"),
    "address-a-string": (_doc(globals={"66": "abc"}), "globals.66"),
    "host-address-a-string": (_doc(globals={"76": "x"}), "globals.76"),
    "address-zero": (_doc(globals={"66": 0}), "globals.66"),
    "address-256": (_doc(globals={"66": 256}), "globals.66"),
    # more of the same kind
    "truncated": (_doc(globals={"76": 3})[:-7], "unreadable"),
    "empty-file": (b"", "unreadable"),
    "top-level-list": (b"[1, 2, 3]", "not a tmcl-sim-eeprom file"),
    "top-level-null": (b"null", "not a tmcl-sim-eeprom file"),
    "not-utf8": (b"\xff\xfe\x00junk", "unreadable"),
    "deeply-nested": (b'{"format": "tmcl-sim-eeprom", "version": 1, "program": '
                      + b"[" * 100_000 + b"]" * 100_000 + b"}", "unreadable"),
    "huge-integer": (_doc(user_variables={"0": 10**40}), "user_variables.0"),
    "huge-integer-digits": (b'{"format": "tmcl-sim-eeprom", "version": 1, "user_variables": '
                            b'{"0": ' + b"9" * 5000 + b"}}", "unreadable"),
    "infinity": (b'{"format": "tmcl-sim-eeprom", "version": 1, "globals": {"76": Infinity}}',
                 "globals.76"),
    "nan": (b'{"format": "tmcl-sim-eeprom", "version": 1, "globals": {"76": NaN}}', "globals.76"),
    "float-value": (_doc(globals={"76": 3.5}), "globals.76"),
    "bool-value": (_doc(globals={"76": True}), "globals.76"),
    "unknown-global": (_doc(globals={"250": 1}), "globals.250"),
    "read-only-global": (_doc(globals={"128": 1}), "globals.128"),
    "negative-key": (_doc(globals={"-1": 1}), "globals.-1"),
    "nested-junk-in-globals": (_doc(globals={"76": {"a": [1, {"b": None}]}}), "globals.76"),
    "section-a-list": (_doc(globals=[1, 2]), "globals"),
    "unknown-top-level-field": (_doc(extra={"1": 2}), "extra"),
    "user-variable-not-storable": (_doc(user_variables={"200": 1}), "user_variables.200"),
    "user-variable-too-big": (_doc(user_variables={"3": 2**31}), "user_variables.3"),
    "axis-out-of-range": (_doc(axis_parameters={"6": {"4": 100}}), "axis_parameters.6"),
    "axis-parameter-not-storable": (_doc(axis_parameters={"0": {"1": 100}}), "axis_parameters.0.1"),
    "axis-parameter-out-of-range": (_doc(axis_parameters={"0": {"6": 100000}}),
                                    "axis_parameters.0.6"),
    "axis-parameter-null": (_doc(axis_parameters={"0": {"4": None}}), "axis_parameters.0.4"),
    "coordinate-axis-junk": (_doc(coordinates={"x": {"1": 1}}), "coordinates.x"),
    "coordinate-zero": (_doc(coordinates={"0": {"0": 1}}), "coordinates.0.0"),
    "coordinate-string": (_doc(coordinates={"0": {"1": "1"}}), "coordinates.0.1"),
    "program-not-a-list": (_doc(program={"0": "MVP"}), "program.0"),
    "program-short": (_doc(program={"0": [4, 0, 0]}), "program.0"),
    "program-opcode-zero": (_doc(program={"0": [0, 0, 0, 0]}), "program.0"),
    "program-opcode-256": (_doc(program={"0": [256, 0, 0, 0]}), "program.0"),
    "program-motor-negative": (_doc(program={"0": [4, 0, -1, 0]}), "program.0"),
    "program-value-huge": (_doc(program={"0": [4, 0, 0, 2**32]}), "program.0"),
    "program-negative-address": (_doc(program={"-3": [4, 0, 0, 0]}), "program.-3"),
}


@pytest.mark.parametrize("content, field", MALFORMED.values(), ids=MALFORMED.keys())
def test_malformed_file_starts_on_factory_defaults(tmp_path, caplog, content, field):
    path = tmp_path / FILE_NAME
    path.write_bytes(content)
    with caplog.at_level(logging.WARNING, logger="tmcl_server.eeprom"):
        b = Bench(TMCM6212(1, Eeprom(tmp_path)))
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1, warnings
    assert str(path) in warnings[0] and field in warnings[0], warnings[0]
    assert b.module.address == 1
    assert b.ok(Opcode.GAP, 4, 0) == TMCM6212(1).axis(0).get_parameter(4)  # factory default
    assert b.ok(Opcode.GGP, GP.HOST_ADDRESS, 0) == 2
    b.ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 5)  # auto-stored: would write the file
    b.ok(Opcode.STGP, 0, 2)
    assert path.read_bytes() == content  # kept for inspection, never overwritten
    assert [p.name for p in tmp_path.iterdir()] == [FILE_NAME]


def test_a_file_this_simulator_wrote_is_accepted(tmp_path):
    b = Bench(TMCM6212(1, Eeprom(tmp_path)))
    b.ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 7)
    b.ok(Opcode.SAP, 4, 2, 20000)
    b.ok(Opcode.STAP, 4, 2)
    b.ok(Opcode.SGP, 55, 2, -55)
    b.ok(Opcode.STGP, 55, 2)
    b.ok(Opcode.SGP, GP.COORDINATE_STORAGE, 0, 1)
    b.ok(Opcode.SCO, 20, 5, -2**31)
    again = TMCM6212(1, Eeprom(tmp_path))
    assert again.eeprom.problem is None and again.eeprom.persistent


def test_every_module_type_accepts_an_empty_file(tmp_path):
    for kind in MODULE_TYPES:
        (tmp_path / kind).mkdir()
        (tmp_path / kind / FILE_NAME).write_bytes(_doc())
        assert TMCLModule(1, Eeprom(tmp_path / kind), kind=kind).eeprom.problem is None


@pytest.mark.parametrize("name", ["address-a-string", "program-address-out-of-memory",
                                  "axis-row-not-object", "deeply-nested"])
def test_server_process_starts_and_names_file_and_field(tmp_path, name):
    content, field = MALFORMED[name]
    state = tmp_path / "state"
    path = state / "module-1" / FILE_NAME
    path.parent.mkdir(parents=True)
    path.write_bytes(content)
    server = ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state))
    try:
        client = RawClient(server.endpoints["tcp"][0])
        assert client.request(1, Opcode.GAP, 4, 0).status == 100
        client.close()
    finally:
        code, _, err = server.stop()
    assert code == 0
    named = [line for line in err.splitlines() if str(path) in line]
    assert len(named) == 1 and field in named[0] and named[0].startswith("WARNING"), err
    assert "Traceback" not in err
    assert path.read_bytes() == content


# == item 7: a store that cannot be written ===================================================


def _file_size_limit(limit: int):
    def apply() -> None:  # runs in the child: writes past `limit` bytes fail with EFBIG
        import resource
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


class LimitedServer(ServerProcess):
    """A server process whose files cannot grow past 40 bytes (the ready file fits; an
    EEPROM image does not, nor does one store's line in the journal): a write failure even
    root cannot get around."""

    def __init__(self, tmp_path, *args: str) -> None:
        super().__init__(tmp_path, *args, preexec_fn=_file_size_limit(40))


def _read_only_state(tmp_path):
    """A state directory the server cannot write in, and the server on it."""
    state = tmp_path / "state"
    (state / "module-1").mkdir(parents=True)
    (state / "module-1").chmod(0o555)
    if os.access(state / "module-1", os.W_OK):  # root: permissions do not stop it
        (state / "module-1").chmod(0o755)
        return LimitedServer(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state))
    return ServerProcess(tmp_path, "--tcp", "127.0.0.1:0", "--state-dir", str(state))


def test_failed_store_answers_status_5_and_keeps_the_connection(tmp_path):
    server = _read_only_state(tmp_path)
    try:
        client = RawClient(server.endpoints["tcp"][0])
        assert client.request(1, Opcode.SGP, 20, 2, 2020).status == 100
        for _ in range(3):  # each retry writes again (and fails again), none "succeeds"
            assert client.request(1, Opcode.STGP, 20, 2).status == 5
        assert client.request(1, Opcode.SAP, 4, 0, 1000).status == 100
        assert client.request(1, Opcode.STAP, 4, 0).status == 5
        reply = client.request(1, Opcode.SGP, GP.HOST_ADDRESS, 0, 3)
        assert reply.status == 5
        assert client.request(1, Opcode.GGP, 20, 2).value == 2020  # the connection is alive
        assert client.request(1, Opcode.GGP, GP.HOST_ADDRESS, 0).value == 3  # set in RAM
        other = RawClient(server.endpoints["tcp"][0])
        assert other.request(1, Opcode.GAP, 4, 0).value == 1000
        other.close()
        client.close()
    finally:
        (tmp_path / "state" / "module-1").chmod(0o755)
        code, _, err = server.stop()
    assert code == 0
    lines = [line for line in err.splitlines() if "cannot write" in line]
    assert len(lines) == 1, err  # one line for the run of failures
    assert "Traceback" not in err
    assert not list((tmp_path / "state" / "module-1").iterdir())  # no temporary file left


def test_failed_factory_reset_restarts_and_answers_status_5(tmp_path, monkeypatch):
    b = Bench(TMCM6212(1, Eeprom(tmp_path)))
    b.ok(Opcode.SGP, GP.HOST_ADDRESS, 0, 7)
    before = (tmp_path / FILE_NAME).read_bytes()

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "replace", refuse)  # the filesystem refuses, not our code
    assert b.status(Opcode.SGP, GP.TELEGRAM_PAUSE, 0, 4) == 5
    assert b.ok(Opcode.GGP, GP.TELEGRAM_PAUSE, 0) == 4
    assert b.status(137, 0, 0, 1234) == 5
    assert b.ok(Opcode.GGP, GP.HOST_ADDRESS, 0) == 2  # restarted on factory settings
    monkeypatch.undo()
    assert (tmp_path / FILE_NAME).read_bytes() == before
    b.ok(Opcode.SGP, 0, 2, 9)
    b.ok(Opcode.STGP, 0, 2)  # writable again: the next store writes the whole image,
    document = json.loads((tmp_path / FILE_NAME).read_text())  # the reset included
    assert document["globals"] == {} and document["user_variables"] == {"0": 9}
