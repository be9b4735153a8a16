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


# -- the command-line tools' shared conventions ------------------------------------------------

#: Exit codes of the client tools (``tmcl``, ``tmcl-upload``, ``tmcl-asm``), one meaning each,
#: for scripts: the same kind of error ends each tool with the same code.
EXIT_OK = 0
EXIT_REFUSED = 1
EXIT_USAGE = 2
EXIT_NO_REPLY = 3
EXIT_BAD_INPUT = 4
EXIT_GAVE_UP = 5
EXIT_INTERRUPTED = 130
EXIT_CODES = (
    (EXIT_OK, "success"),
    (EXIT_REFUSED, "the module refused the command (error status) or a verify found a difference"),
    (EXIT_USAGE, "usage: bad arguments, unknown mnemonic or parameter name"),
    (EXIT_NO_REPLY, "no connection, or no reply in time"),
    (EXIT_BAD_INPUT, "a file cannot be read, written, assembled or decoded"),
    (EXIT_GAVE_UP, "a --wait gave up before its condition held"),
    (EXIT_INTERRUPTED, "interrupted (Ctrl-C)"),
)


def _option_strings(parser: argparse.ArgumentParser) -> list[str]:
    """Every long option of a parser and of its subcommands' parsers."""
    found: list[str] = []
    for action in parser._actions:
        found += [o for o in action.option_strings if o.startswith("--")]
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found += _option_strings(sub)
    return sorted(set(found))


def with_suggestion(parser: argparse.ArgumentParser, message: str) -> str:
    """An argparse error with a did-you-mean for a misspelt option, command or choice, and a
    word for an argument PowerShell split at an unquoted comma (``mode=rs485`` alone)."""
    import difflib
    import re

    unknown = re.fullmatch(r"unrecognized arguments: (.*)", message)
    if unknown:
        options = _option_strings(parser)
        hints = []
        for word in unknown.group(1).split():
            name = word.split("=", 1)[0]
            close = difflib.get_close_matches(name, options, n=1) if word.startswith("--") else []
            if close:
                hints.append(f"did you mean {close[0]} for {name}?")
            elif re.fullmatch(r"[a-z_]+=\S*", word):
                hints.append(f"{word} looks like part of an argument split at a comma: PowerShell "
                             "splits unquoted commas, quote the argument (--serial "
                             "'COM11,mode=rs485'; docs/windows.md)")
        return message + "".join(f"; {hint}" for hint in hints)
    choice = re.fullmatch(r"(argument .*?: )?invalid choice: '?(.*?)'? \(choose from (.*)\)", message)
    if choice:
        choices = [c.strip(" '\"") for c in choice.group(3).split(",")]
        close = difflib.get_close_matches(choice.group(2).lower(), [c.lower() for c in choices], n=1)
        if close:
            return f"{message}; did you mean {choices[[c.lower() for c in choices].index(close[0])]}?"
    return message
