"""How endpoints are written on command lines (``HOST:PORT``, ``DEVICE[:BAUD]``): parsed the
same way by the server's transports and by the clients (``tmcl``, ``tmcl-upload``), which must
not load a transport to read an address."""

from __future__ import annotations

import os


def parse_host_port(text: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """``HOST:PORT``, ``:PORT`` or ``PORT``; IPv6 hosts go in brackets."""
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = default_host, text
    host = host.strip("[]") or default_host
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"bad port in {text!r}") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"port out of range in {text!r}")
    return host, number


def parse_serial_spec(text: str) -> tuple[str, int | None]:
    """``DEVICE[:BAUD]``; a pyserial URL keeps its own ``host:port``."""
    head, sep, tail = text.rpartition(":")
    if sep and head and not tail.isdigit() and "://" not in text and not os.path.exists(text) \
            and os.path.exists(head):  # /dev/ttyUSB0:fast: a baud rate, not part of the path
        raise ValueError(f"baud rate {tail!r} in {text!r} is not a number")
    if not sep or not tail.isdigit() or not head:
        return text, None
    if "://" in head and ":" not in head.split("://", 1)[1]:
        return text, None  # socket://host:port has no baud suffix
    if int(tail) == 0:
        raise ValueError(f"baud rate 0 in {text!r}")
    return head, int(tail)
