#!/usr/bin/env python3
"""Set up the simulator from the project's own files and start it, on any system:

    python3 scripts/serve.py [tmcl-server arguments]      (Windows: py scripts/serve.py ...)

Default: TCP 127.0.0.1:2323 and, where there are pseudo-terminals, the virtual serial port
/tmp/ttyTMCL0 (left out when the arguments name a ``--pty`` or ``--serial`` of their own).
The arguments go to ``tmcl-server`` as they came (nothing split at commas), and it runs in
the caller's directory, so relative paths (``--world my.toml``) are the caller's.  The first
start creates ``.venv`` and installs tmcl-sim with what the README's examples use; later
starts reuse it (scripts/bootstrap.py).  ``PYTHON=...`` picks the Python.
"""

from __future__ import annotations

import sys
from pathlib import Path

import bootstrap

#: examples: pytrinamic (scripts/example_pytrinamic.py, the README's snippets); fast: uvloop;
#: plot: matplotlib (tmcl plot); http: aiohttp (--http, the dashboard); tools: pytrinamic for
#: tmcl --connection (real modules)
SERVE_EXTRAS = "examples,fast,plot,http,tools"
DEFAULT_PTY = "/tmp/ttyTMCL0"
WHO = "serve.py"


def names_a_port(arguments: list[str]) -> bool:
    """Whether the arguments name a --pty or --serial of their own."""
    return any(a in ("--pty", "--serial") or a.startswith(("--pty=", "--serial="))
               for a in arguments)


def server_arguments(arguments: list[str]) -> list[str]:
    if bootstrap.windows() or names_a_port(arguments):
        return list(arguments)
    return ["--pty", DEFAULT_PTY, *arguments]


def main() -> int:
    arguments = sys.argv[1:]
    bootstrap.ensure_venv(WHO, SERVE_EXTRAS)
    if bootstrap.windows() and not names_a_port(arguments):
        bootstrap.say(WHO, "for the TMCL-IDE: py scripts/serve.py --serial COM11 (one end of a "
                           "com0com pair; docs/windows.md)")
    tools = bootstrap.venv_program("tmcl")
    if Path.cwd().resolve() == bootstrap.ROOT:
        tools = tools.relative_to(bootstrap.ROOT)
    bootstrap.say(WHO, f"the tools (tmcl, tmcl-asm, tmcl-upload) are in {tools.parent}: {tools}, "
                       f"or {bootstrap.activate_hint(tools.parent)}")
    return bootstrap.hand_over(bootstrap.venv_program("tmcl-server"), server_arguments(arguments))


if __name__ == "__main__":
    sys.exit(bootstrap.main_guard(WHO, main))
