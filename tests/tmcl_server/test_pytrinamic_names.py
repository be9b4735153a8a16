"""pytrinamic's parameter names (issue 37, item 5): every name the installed pytrinamic's
module classes give a parameter our tables have is read as that parameter, wherever a name is
accepted; the data lives once, in tmcl_spec/pytrinamic_names.py."""

from __future__ import annotations

import importlib
from collections.abc import Callable

import pytest

from tmcl_server.decode import Vocabulary
from tmcl_server.faults import parse_fault
from tmcl_server.tool import main as tmcl
from tmcl_spec.modules import MODULE_TYPES, module_type
from tmcl_spec.pytrinamic_names import PYTRINAMIC_NAMES

#: Module type -> (pytrinamic's class with the axis names, the class with the global ones, and
#: its attribute -> our bank).
CLASSES = {
    **{key: (f"pytrinamic.modules.TMCM{key[5:]}:TMCM{key[5:]}",) * 2 + ({"GP0": 0, "GP3": 3},)
       for key in ("tmcm-6212", "tmcm-1110", "tmcm-3110", "tmcm-6110", "tmcm-1140", "tmcm-1141",
                   "tmcm-1160", "tmcm-1161", "tmcm-1111")},
    "landungsbruecke-tmc4361a": ("pytrinamic.evalboards.TMC4361_eval:TMC4361_eval",
                                 "pytrinamic.modules.Landungsbruecke:Landungsbruecke", {"GP": 0}),
}


def _class(where: str) -> type:
    module, _, name = where.partition(":")
    return getattr(importlib.import_module(module), name)


def _names(cls: type) -> dict[str, int]:
    return {name: value for name, value in vars(cls).items()
            if not name.startswith("_") and isinstance(value, int)}


#: Where our table's own name wins over pytrinamic's number, and why.
OURS_WIN = {
    # pytrinamic/modules/TMCM1111.py (line 131) gives the high side AP 176 and names no low
    # side; the family's manuals and pytrinamic's TMCM1140.py (lines 93-94) have 175 high and
    # 176 low, as our TMCM-1111 table does (docs/modules.md): SlopeControlHighSide stays 175.
    ("tmcm-1111", "SlopeControlHighSide"),
}


def pytrinamic_parameters(key: str) -> list[tuple[str, str, int, Callable[[Vocabulary], object]]]:
    """(where, name, number, the vocabulary's names for it) of every name in the classes."""
    axis_class, global_class, banks = CLASSES[key]
    (motor,) = {m for m in vars(_class(axis_class)).values() if isinstance(m, type) and hasattr(m, "AP")}
    found: list[tuple[str, str, int, Callable[[Vocabulary], object]]] = [
        ("AP", name, number, lambda words: words.axis) for name, number in _names(motor.AP).items()]
    for attribute, bank in banks.items():
        found += [(attribute, name, number, lambda words, bank=bank: words.banks[bank])
                  for name, number in _names(getattr(_class(global_class), attribute)).items()]
    return found


def test_every_module_type_has_its_pytrinamic_class() -> None:
    assert set(CLASSES) == set(MODULE_TYPES) == set(PYTRINAMIC_NAMES)


@pytest.mark.parametrize("key", sorted(CLASSES))
def test_every_name_of_the_installed_pytrinamic_class_is_read_as_its_parameter(key: str) -> None:
    """Generated from the installed pytrinamic: a name for a number the module's table has is
    that number; a name for one it lacks (a newer firmware's) is no other parameter."""
    kind = module_type(key)
    words = Vocabulary(kind)
    tables = {"AP": kind.axis_parameters, "GP0": kind.global_parameters.get(0, {}),
              "GP": kind.global_parameters.get(0, {}), "GP3": kind.global_parameters.get(3, {})}
    checked = 0
    for where, name, number, names in pytrinamic_parameters(key):
        found = names(words).number(name)  # type: ignore[attr-defined]
        if (key, name) in OURS_WIN:
            assert found != number
        elif number in tables[where]:
            assert found == number, f"{key}: pytrinamic's {where}.{name} is {number}, read as {found}"
            checked += 1
        else:
            assert found is None, f"{key}: pytrinamic's {where}.{name} ({number}) read as {found}"
    assert checked >= 10


def test_the_newer_classes_run_current_is_ap_6() -> None:
    """pytrinamic's features (CurrentModule) and its newer classes call AP 6 RunCurrent."""
    assert Vocabulary(module_type("tmcm-6212")).axis.number("RunCurrent") == 6
    assert Vocabulary(module_type("tmcm-1140")).axis.number("runcurrent") == 6


def test_tmcl_send_and_watch_take_pytrinamic_names(tmcl_sim, capsys) -> None:
    assert tmcl(["--tcp", tmcl_sim.tcp, "send", "GAP", "MaxVelocity", "0"]) == 0
    assert capsys.readouterr().out == "GAP 4 MaxPositioningSpeed m0 → 100 OK = 51200\n"
    assert tmcl(["--tcp", tmcl_sim.tcp, "send", "SAP", "RunCurrent", "0", "100"]) == 0
    assert capsys.readouterr().out == "SAP 6 MaxCurrent m0 = 100 → 100 OK\n"
    assert tmcl(["--tcp", tmcl_sim.tcp, "send", "GGP", "SerialBaudRate", "0", "--value"]) == 0
    assert capsys.readouterr().out == "0\n"
    assert tmcl(["--tcp", tmcl_sim.tcp, "watch", "ActualVelocity", "ActualPosition", "--count", "1",
                 "--csv"]) == 0
    assert capsys.readouterr().out.splitlines()[0] == "t,0.ActualSpeed,0.ActualPosition"


def test_a_fault_filters_by_pytrinamic_names() -> None:
    assert parse_fault("noreply:opcode=GAP,type=MaxVelocity|ActualVelocity").keys["type"] == {4, 3}
