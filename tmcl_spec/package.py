"""The installed distribution's identity, for every tool's ``--version``."""

from __future__ import annotations

from importlib import metadata

DISTRIBUTION = "tmcl-sim"


def package_version() -> str:
    """The version pip installed (pyproject.toml's), or "unknown" when run from a bare checkout."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


def version_text(program: str, detail: str = "") -> str:
    """What ``PROGRAM --version`` prints: ``tmcl-server 0.1.0 (...)``."""
    return f"{program} {package_version()}" + (f" ({detail})" if detail else "")
