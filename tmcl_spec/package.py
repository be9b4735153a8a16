"""The installed distribution's identity, for every tool's ``--version``.

Looked up only when asked: importlib.metadata costs start-up time nobody needs otherwise.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

DISTRIBUTION = "tmcl-sim"


def package_version() -> str:
    """The version pip installed (pyproject.toml's), or "unknown" when run from a bare checkout."""
    from importlib import metadata

    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


#: Characters the tools print that legacy consoles (Windows' cp1252, cp437) cannot show, and
#: what they print instead; anything else they cannot show becomes "?".
CONSOLE_FALLBACKS = {
    "\u2192": "->", "\u2190": "<-", "\u2194": "<->",  # arrows
    "\u2265": ">=", "\u2264": "<=", "\u2260": "!=", "\u00b1": "+/-", "\u00d7": "x",
    "\u2026": "...", "\u2014": "-", "\u2013": "-",  # ellipsis, em and en dash
    "\u00b5": "u", "\u0394": "d", "\u2713": "ok", "\u2717": "x",  # micro, delta, ticks
}
_CONSOLE_ERRORS = "tmcl-console"


def _console_fallback(error: UnicodeError) -> tuple[str, int]:
    if not isinstance(error, UnicodeEncodeError):
        raise error
    text = error.object[error.start:error.end]
    return "".join(CONSOLE_FALLBACKS.get(c, "?") for c in text), error.end


def safe_console() -> None:
    """Standard output and error never fail on a character their encoding lacks: a cp1252
    console (Windows, PYTHONIOENCODING=cp1252) gets "->" for "→" instead of a
    UnicodeEncodeError.  UTF-8 streams are left as they are."""
    import codecs
    import io
    import sys

    try:
        codecs.lookup_error(_CONSOLE_ERRORS)
    except LookupError:
        codecs.register_error(_CONSOLE_ERRORS, _console_fallback)
    for stream in (sys.stdout, sys.stderr):
        if not isinstance(stream, io.TextIOWrapper) or stream.errors not in ("strict", "backslashreplace"):
            continue
        try:
            "→µ±…".encode(stream.encoding)
        except (UnicodeEncodeError, LookupError):
            stream.reconfigure(errors=_CONSOLE_ERRORS)


def docs_location() -> Path:
    """The documentation's folder: the wheel carries the checkout's docs/ as tmcl_spec/docs
    (setup.py), so ``--help`` and error messages name files an installed copy has."""
    here = Path(__file__).resolve().parent
    for candidate in (here / "docs", here.parent / "docs"):
        if candidate.is_dir():
            return candidate
    return here / "docs"


def doc(name: str) -> str:
    """The path of one page of the documentation, e.g. ``doc("can.md")``, for a help text."""
    return str(docs_location() / name)


def version_text(program: str, detail: str = "") -> str:
    """What ``PROGRAM --version`` prints: ``tmcl-server 0.1.0 (...)``."""
    return f"{program} {package_version()}" + (f" ({detail})" if detail else "")


def add_version_option(parser: argparse.ArgumentParser, detail: str = "") -> None:
    """``--version``: print :func:`version_text` and exit (the version is looked up then)."""

    class _Version(argparse.Action):
        def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                     values: str | Sequence[Any] | None, option_string: str | None = None) -> None:
            print(version_text(parser.prog, detail))  # on stdout, as argparse's own action does
            parser.exit()

    parser.add_argument("--version", nargs=0, action=_Version,
                        help="show the program's version and exit")
