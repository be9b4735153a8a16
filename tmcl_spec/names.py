"""Compact parameter names (``MaxPositioningSpeed``), derived from the manual's table names.

The tables (:mod:`tmcl_spec.tmcm6212`) keep the manual's wording ("Maximum positioning
speed"); traces, the ``tmcl`` tool and dumps need one word per parameter that a shell and a
JSON key can carry.  There is no second table of names: every compact name is computed from
the row's name by :func:`compact_name`, so a new module type's tables name themselves.

Rules: a parenthesised aside is dropped ("Chopper off time (TOff)"), only the first of
alternatives separated by `` / `` is kept ("Chopper hysteresis end / fast decay time"),
"Maximum"/"Minimum" shorten to "Max"/"Min", and the words are joined with their first letter
capitalised and the rest as written (``coolStep`` -> ``CoolStep``, ``VSTART`` stays).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from typing import TYPE_CHECKING

from tmcl_spec.parameters import ParamSpec

if TYPE_CHECKING:
    from tmcl_spec.modules import ModuleType

_ABBREVIATIONS = {"maximum": "Max", "minimum": "Min"}
_ASIDE = re.compile(r"\([^)]*\)")
_WORD = re.compile(r"[A-Za-z0-9]+")


def compact_name(text: str) -> str:
    """``"Maximum positioning speed"`` -> ``"MaxPositioningSpeed"``."""
    text = _ASIDE.sub(" ", text).split(" / ")[0]
    words = []
    for word in _WORD.findall(text):
        short = _ABBREVIATIONS.get(word.lower())
        words.append(short if short else word[0].upper() + word[1:])
    return "".join(words)


class ParameterNames:
    """Both directions for one table: number -> compact name, and any spelling -> number.

    ``aliases`` (number -> names: pytrinamic's, :mod:`tmcl_spec.pytrinamic_names`) are read
    too, for the numbers the table has; the table's own names win where a spelling is both,
    and names are only ever printed in the table's spelling."""

    __slots__ = ("_lookup", "by_number")

    def __init__(self, table: Mapping[int, ParamSpec],
                 aliases: Mapping[int, tuple[str, ...]] | None = None) -> None:
        self.by_number: dict[int, str] = {n: compact_name(s.name) for n, s in table.items()}
        self._lookup: dict[str, int] = {}
        for number, names in (aliases or {}).items():
            if number in table:
                self._lookup.update(dict.fromkeys((name.lower() for name in names), number))
        for number, spec in table.items():
            self._lookup[self.by_number[number].lower()] = number
            self._lookup[spec.name.lower()] = number

    def name(self, number: int) -> str | None:
        return self.by_number.get(number)

    def number(self, text: str) -> int | None:
        """The number a compact name, the manual's name or a decimal number stands for."""
        text = text.strip()
        if re.fullmatch(r"\d+", text):
            return int(text)
        return self._lookup.get(text.lower())

    def __iter__(self) -> Iterator[tuple[int, str]]:
        return iter(self.by_number.items())


_CACHE: dict[tuple[int, int], tuple[Mapping[int, ParamSpec], object, ParameterNames]] = {}


def names_of(table: Mapping[int, ParamSpec],
             aliases: Mapping[int, tuple[str, ...]] | None = None) -> ParameterNames:
    """The (cached) names of a table, with ``aliases``; tables and alias tables are
    module-level constants, so cache by identity."""
    key = (id(table), id(aliases))
    cached = _CACHE.get(key)
    if cached is None or cached[0] is not table or cached[1] is not aliases:
        cached = _CACHE[key] = (table, aliases, ParameterNames(table, aliases))
    return cached[2]


def module_names(kind: ModuleType) -> tuple[ParameterNames, dict[int, ParameterNames]]:
    """What a module type's parameters are called: its axis parameters, and its global ones by
    bank; pytrinamic's names are read too (``MaxVelocity`` for ``MaxPositioningSpeed``)."""
    from tmcl_spec.pytrinamic_names import pytrinamic_names

    theirs = pytrinamic_names(kind.key)
    return (names_of(kind.axis_parameters, theirs.axis),
            {bank: names_of(table, theirs.banks.get(bank))
             for bank, table in kind.global_parameters.items()})
