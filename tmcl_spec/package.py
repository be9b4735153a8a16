"""The installed distribution's identity, for every tool's ``--version``.

Looked up only when asked: importlib.metadata costs start-up time nobody needs otherwise.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

DISTRIBUTION = "tmcl-sim"


def package_version() -> str:
    """The version pip installed (pyproject.toml's), or "unknown" when run from a bare checkout."""
    from importlib import metadata

    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


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
