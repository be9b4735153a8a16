"""Which asyncio event loop the server runs on: uvloop when it is installed, else asyncio's.

uvloop (the ``fast`` extra) serves the wire with less overhead per request; everything works
on the standard loop too.  Imported only by the command line and the embedding API.
"""

from __future__ import annotations

import asyncio

LOOPS = ("auto", "asyncio", "uvloop")


def uvloop_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("uvloop") is not None


def new_event_loop(kind: str = "auto") -> asyncio.AbstractEventLoop:
    """A new loop: ``uvloop``, ``asyncio``, or ``auto`` (uvloop if installed)."""
    if kind not in LOOPS:
        raise ValueError(f"unknown event loop {kind!r} (one of {', '.join(LOOPS)})")
    if kind == "uvloop" and not uvloop_available():
        raise ValueError("uvloop is not installed (pip install 'tmcl-sim[fast]')")
    if kind == "uvloop" or (kind == "auto" and uvloop_available()):
        import uvloop  # the fast extra

        return uvloop.new_event_loop()
    return asyncio.new_event_loop()
