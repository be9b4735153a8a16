"""A real serial port through pyserial: a USB-RS485 adapter, or one end of a socat/com0com
pair so that a TMCL-IDE on another machine or OS can reach the simulator."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
from typing import TYPE_CHECKING

import serial

from tmcl_server.endpoints import parse_serial_spec
from tmcl_server.platform import can_watch_descriptors
from tmcl_server.simulation import Simulation
from tmcl_server.transports.base import (
    LinkMode,
    StreamSession,
    Transport,
    TransportHost,
    link_mode,
    split_endpoint_options,
)
from tmcl_spec.parameters import GP

if TYPE_CHECKING:
    from tmcl_server.transports.wire import WireTiming

log = logging.getLogger(__name__)


class SerialPortTransport(Transport):
    kind = "serial"

    def __init__(self, simulation: Simulation, spec: str, mode: LinkMode = LinkMode.RS485,
                 wire: WireTiming | None = None) -> None:
        self.simulation = simulation
        self.mode = mode
        #: ``--wire-timing``: bytes paced at the port's baud rate (transports/wire.py).
        self.wire = wire
        self.device, baud = parse_serial_spec(spec)
        if baud is None:  # the module's own GP 65 setting decides, as on the real part
            module = simulation.modules[0] if simulation.modules else None
            baud = module.type.baud_rates.get(module.globals[0][GP.BAUD_RATE], 9600) if module else 9600
        self.baudrate = baud
        self._port: serial.SerialBase | None = None
        self._session: StreamSession | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._reader_fd: int | None = None

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> SerialPortTransport:
        """``DEVICE[:BAUD][,mode=usb|rs485]``; without a mode: USB for one module, RS-485 for
        several (docs/protocol.md)."""
        from tmcl_server.transports.wire import WireTiming

        spec, options = split_endpoint_options(argument)
        return cls(host.simulation, spec, link_mode(host.simulation, options, f"--serial {spec}"),
                   WireTiming.of(host))

    async def start(self) -> list[str]:
        loop = asyncio.get_running_loop()
        self._port = serial.serial_for_url(self.device, baudrate=self.baudrate, timeout=0)
        if self.wire is not None:
            from tmcl_server.transports.wire import LineRate, PacedStreamSession

            self._session = PacedStreamSession(
                self.simulation, self._port.write, loop, self.mode, f"serial {self.device}",
                baud=LineRate.uart(None, self.baudrate), timing=self.wire)
        else:
            port = self._port
            self._session = StreamSession(self.simulation, port.write, loop, self.mode,
                                          f"serial {self.device}", lambda: port.in_waiting)
        try:
            fd = self._port.fileno()
        except (AttributeError, NotImplementedError, OSError, ValueError):
            fd = None
        if isinstance(fd, int) and can_watch_descriptors():
            # a loop that watches sockets only refuses: the thread below reads instead
            with contextlib.suppress(NotImplementedError, OSError, ValueError):
                loop.add_reader(fd, self._on_readable)
                self._reader_fd = fd
        if self._reader_fd is None:  # Windows' COM ports, URL handlers: a small reader thread
            self._port.timeout = 0.01
            self._thread = threading.Thread(target=self._read_loop, args=(loop,), daemon=True)
            self._thread.start()
        return [f"{self.device}@{self.baudrate}"]

    def _on_readable(self) -> None:
        assert self._port is not None and self._session is not None
        try:
            data = self._port.read(max(1, self._port.in_waiting))
        except (OSError, serial.SerialException) as exc:
            log.warning("serial %s read failed: %s", self.device, exc)
            return
        if data:
            self._session.feed(data)

    def _read_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        assert self._port is not None and self._session is not None
        while not self._stop.is_set():
            try:
                data = self._port.read(256)
            except (OSError, serial.SerialException):
                break
            if data:
                loop.call_soon_threadsafe(self._session.feed, data)

    async def close(self) -> None:
        self._stop.set()
        if self._session is not None:
            self._session.close()
        if self._reader_fd is not None:
            asyncio.get_running_loop().remove_reader(self._reader_fd)
            self._reader_fd = None
        if self._thread is not None:
            await asyncio.to_thread(self._thread.join, 1.0)
        if self._port is not None:
            with contextlib.suppress(Exception):
                self._port.close()
            self._port = None
