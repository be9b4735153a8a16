"""Integer conventions shared by every layer: the signed 32-bit value field and time units."""

from __future__ import annotations

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
UINT32_MAX = 2**32 - 1

#: Simulated time is an integer count of nanoseconds.
NS_PER_S = 1_000_000_000
NS_PER_MS = 1_000_000


def to_int32(value: int) -> int:
    """Wrap any integer to the signed 32-bit range (the wire's value field, the firmware's int)."""
    value &= UINT32_MAX
    return value - 0x1_0000_0000 if value & 0x8000_0000 else value


def to_signed(value: int, bits: int) -> int:
    """Wrap any integer to a signed ``bits``-bit range (a 24-bit position register read as a
    whole AP 1, for example)."""
    half = 1 << (bits - 1)
    return ((value + half) & ((half << 1) - 1)) - half


def seconds_to_ns(seconds: float) -> int:
    return round(seconds * NS_PER_S)
