"""Tables of things chosen by name (module types, chip cores, transports), imported on demand.

Like python-can's ``BACKENDS``: a table maps a name to ``"module:attribute"``, so choosing one
thing imports only what it needs.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from typing import Any


def resolve(table: Mapping[str, str], name: str, what: str) -> Any:
    """The object ``table`` names ``name`` (in any case); ValueError with the closest known
    name and the list if none."""
    try:
        where = table[name.lower()]
    except KeyError:
        import difflib

        close = difflib.get_close_matches(name.lower(), list(table), n=1)
        hint = f"did you mean {close[0]}? " if close else ""
        raise ValueError(f"unknown {what} {name!r} ({hint}known: {', '.join(table)})") from None
    module_name, _, attribute = where.partition(":")
    return getattr(importlib.import_module(module_name), attribute)
