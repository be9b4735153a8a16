"""Which asyncio event loop the server runs on: uvloop when it is installed, else asyncio's.

uvloop (the ``fast`` extra) serves the wire with less overhead per request; everything works
on the standard loop too.  Imported only by the command line and the embedding API.
"""

from __future__ import annotations

import asyncio

from tmcl_server.platform import standard_event_loop

LOOPS = ("auto", "asyncio", "uvloop")


def uvloop_available() -> bool:
    """Whether uvloop can be imported (never on Windows, which it does not support)."""
    import importlib.util

    try:
        return importlib.util.find_spec("uvloop") is not None
    except (ImportError, ValueError):  # a finder that refuses it, or a stub in sys.modules
        return False


def new_event_loop(kind: str = "auto") -> asyncio.AbstractEventLoop:
    """A new loop: ``uvloop``, ``asyncio``, or ``auto`` (uvloop if installed)."""
    if kind not in LOOPS:
        raise ValueError(f"unknown event loop {kind!r} (one of {', '.join(LOOPS)})")
    if kind == "uvloop" or (kind == "auto" and uvloop_available()):
        try:
            import uvloop  # the fast extra
        except ImportError as exc:
            if kind == "uvloop":
                raise ValueError(f"uvloop cannot be used here ({exc}); it is the fast extra, "
                                 "pip install 'tmcl-sim[fast]' (not on Windows)") from None
        else:
            return uvloop.new_event_loop()
    return standard_event_loop()
