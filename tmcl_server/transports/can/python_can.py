"""``--can INTERFACE:CHANNEL[:BITRATE]``: join the simulated bus to any python-can bus.

``socketcan:can0`` (a real adapter or a vcan), ``pcan:PCAN_USBBUS1``, ``slcan:/dev/ttyACM0``,
``virtual:NAME`` (python-can's in-process bus) ... Frames from that bus reach the modules and
every gateway; frames the modules and gateways send go out on it.  Options beyond channel and
bit rate come from python-can's own configuration (``~/can.ini``, ``CAN_*`` variables).
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
from collections import Counter
from typing import Any

import can

from tmcl_server.transports.base import Transport, TransportHost
from tmcl_server.transports.can.bus import SimulatedCanBus

log = logging.getLogger(__name__)

#: How long the python-can reader thread blocks per read; bounds the time close() takes.
READ_TIMEOUT_S = 0.05


def parse_can_spec(text: str) -> tuple[str, str, int | None]:
    """``INTERFACE:CHANNEL[:BITRATE]``; the channel may itself contain colons."""
    interface, sep, rest = text.partition(":")
    if not sep or not interface or not rest:
        raise ValueError(f"expected INTERFACE:CHANNEL[:BITRATE], got {text!r}")
    channel, sep, tail = rest.rpartition(":")
    if sep and channel and tail.isdigit():
        return interface, channel, int(tail)
    return interface, rest, None


#: What to do when SocketCAN is missing: the ways onto the simulated bus that need no kernel.
_WITHOUT_KERNEL_CAN = "--can virtual:NAME, --socketcand or --slcan-pty need none (docs/can.md)"


class CanUnavailableError(OSError):
    """A python-can bus that cannot be opened here, said in one line: for SocketCAN, whether
    the system has none (Errno 97: no CAN sockets, or not Linux) or lacks the interface."""

    def __init__(self, interface: str, channel: str, cause: Exception) -> None:
        number = cause.errno if isinstance(cause, OSError) else None
        super().__init__(number, str(cause))
        self.text = self._explain(interface, channel, number, cause)

    @staticmethod
    def _explain(interface: str, channel: str, number: int | None, cause: Exception) -> str:
        if interface == "socketcan":
            if number in (errno.EAFNOSUPPORT, errno.EPROTONOSUPPORT) or isinstance(
                    cause, can.CanInterfaceNotImplementedError):
                return ("this system has no SocketCAN (the kernel's CAN sockets: Linux with the "
                        f"can and can_raw modules); {_WITHOUT_KERNEL_CAN}")
            if number == errno.ENODEV:
                return (f"no CAN interface {channel!r} here (`ip link` lists them; a virtual "
                        f"one: sudo ip link add dev {channel} type vcan && sudo ip link set "
                        f"{channel} up)")
        reason = getattr(cause, "strerror", None) or str(cause) or type(cause).__name__
        return f"python-can cannot open {interface} channel {channel!r}: {reason}"

    def __str__(self) -> str:
        return self.text


class PythonCanTransport(Transport):
    kind = "can"

    def __init__(self, bus: SimulatedCanBus, spec: str) -> None:
        self.spec = spec
        self.interface, self.channel, self.bitrate = parse_can_spec(spec)
        self.bus = bus
        self.stats: Counter[str] = Counter()
        self._can: can.BusABC | None = None
        self._notifier: can.Notifier | None = None

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> PythonCanTransport:
        return cls(host.can_bus(), argument)

    async def start(self) -> list[str]:
        options: dict[str, Any] = {} if self.bitrate is None else {"bitrate": self.bitrate}
        try:
            self._can = bus = await asyncio.to_thread(
                can.Bus, interface=self.interface, channel=self.channel, **options)
        except (OSError, can.CanError) as exc:
            raise CanUnavailableError(self.interface, self.channel, exc) from exc
        self._notifier = can.Notifier(bus, [self._from_outside], timeout=READ_TIMEOUT_S,
                                      loop=asyncio.get_running_loop())
        self.bus.attach(self)
        return [self.spec]

    def _from_outside(self, frame: can.Message) -> None:
        self.stats["received"] += 1
        self.bus.send(frame, self)

    def on_frame(self, frame: can.Message) -> None:
        if self._can is None:
            return
        try:
            self._can.send(frame)
            self.stats["sent"] += 1
        except can.CanError as exc:  # bus off, transmit buffer full: the frame is lost
            self.stats["send_errors"] += 1
            log.warning("%s: frame %s not sent: %s", self.spec, frame, exc)

    async def close(self) -> None:
        self.bus.detach(self)
        if self._notifier is not None:
            self._notifier.stop(1.0)  # its reader thread ends within READ_TIMEOUT_S
            self._notifier = None
        if self._can is not None:
            with contextlib.suppress(Exception):
                self._can.shutdown()
            self._can = None
