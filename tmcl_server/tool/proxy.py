"""``tmcl proxy``: sit between hosts and a module, forward every frame unchanged, capture them.

    tmcl --serial /dev/ttyACM0 proxy --listen-tcp 127.0.0.1:2323 --capture session.jsonl
    tmcl --connection "--interface socketcan_tmcl --port can0" proxy --listen-pty /tmp/ttyPROXY

The module side is the tool's usual connection (``--tcp``, ``--serial``, ``--connection`` for
pytrinamic's interfaces, CAN among them); the host side is any number of ``--listen-tcp`` and
``--listen-pty`` endpoints.  Hosts take turns on the wire as on a real bus: one request goes
to the module, and the next (from any host) waits until its reply came back or ``--timeout``
passed.  A frame the module sends unasked (a 138 event) goes to the host that spoke last.

One thread, one ``selectors`` loop: a request is forwarded before anything is written to the
capture, so the capture costs the host no latency (scripts/bench_proxy.py measures what the
proxy adds).  The capture format: tmcl_server/capture.py, docs/capture.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import queue
import select
import selectors
import signal
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from tmcl_server.capture import NO_REPLY, REPLY, REQUEST, UNSOLICITED, CaptureWriter
from tmcl_server.decode import module_type_by_number
from tmcl_server.endpoints import parse_host_port, parse_serial_spec
from tmcl_server.platform import (
    PlatformUnsupported,
    bytes_waiting,
    can_watch_descriptors,
    open_raw_pty,
    require_pseudo_terminals,
)
from tmcl_server.protocol import FRAME_LENGTH, RESYNC_GAP_NS, FrameAssembler, Request, decode_reply
from tmcl_server.ptylink import LinkLock, remove_link, replace_symlink
from tmcl_server.tool.connection import BadInput, NoReply, UsageError, Where
from tmcl_server.upload import PytrinamicClient, UploadError
from tmcl_spec.commands import FACTORY_RESET_KEY, Opcode

#: Bytes read at once from a host or the module.
READ_SIZE = 4096


class LinkClosed(Exception):
    """The module side went away (the message says how)."""


# -- the module side --------------------------------------------------------------------------

class ModuleLink:
    """Frames to the module, bytes back; :meth:`fileno` is what the loop watches."""

    description = ""

    def fileno(self) -> int:
        raise NotImplementedError

    def send(self, frame: bytes) -> None:
        raise NotImplementedError

    def receive(self) -> bytes:
        """What arrived (the loop saw the link readable); LinkClosed at the end."""
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class _SocketLink(ModuleLink):
    """Raw TMCL over TCP (the simulator, an Ethernet-to-serial converter)."""

    def __init__(self, endpoint: str) -> None:
        self.description = f"tcp {endpoint}"
        self._socket = socket.create_connection(parse_host_port(endpoint), timeout=5)
        self._socket.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._socket.setblocking(False)

    def fileno(self) -> int:
        return self._socket.fileno()

    def send(self, frame: bytes) -> None:
        try:
            sent = self._socket.send(frame)  # nine bytes: the kernel takes them at once ...
        except BlockingIOError:
            sent = 0
        if sent < len(frame):  # ... unless the module stopped reading: then wait for it
            self._socket.setblocking(True)
            try:
                self._socket.sendall(frame[sent:])
            finally:
                self._socket.setblocking(False)

    def receive(self) -> bytes:
        try:
            data = self._socket.recv(READ_SIZE)
        except BlockingIOError:
            return b""
        except OSError as exc:
            raise LinkClosed(f"the module link {self.description} failed: {exc}") from None
        if not data:
            raise LinkClosed(f"the module closed the link ({self.description})")
        return data

    def close(self) -> None:
        self._socket.close()


class _PumpedLink(ModuleLink):
    """A module reached through blocking calls (pyserial where the loop cannot watch a port,
    pytrinamic's interfaces): a worker thread does them and hands what comes back to the
    loop through a socket pair."""

    #: Why the worker stopped (said when the loop finds the link closed).
    failure = "closed"

    def __init__(self) -> None:
        self._wake, self._feed = socket.socketpair()
        self._wake.setblocking(False)
        self._frames: queue.Queue[bytes | None] = queue.Queue()
        self._closed = False
        self._worker = threading.Thread(target=self._run, name="tmcl-proxy-link", daemon=True)
        self._worker.start()

    def fileno(self) -> int:
        return self._wake.fileno()

    def send(self, frame: bytes) -> None:
        self._frames.put(frame)

    def receive(self) -> bytes:
        try:
            data = self._wake.recv(READ_SIZE)
        except BlockingIOError:
            return b""
        if not data:
            raise LinkClosed(f"the module link {self.description} failed: {self.failure}")
        return data

    def _run(self) -> None:
        try:
            self.work()
        except Exception as exc:  # the link broke: the loop hears of it as an end of data
            self.failure = f"{type(exc).__name__}: {exc}"
        with contextlib.suppress(OSError):
            self._feed.shutdown(socket.SHUT_WR)

    def work(self) -> None:
        raise NotImplementedError

    def deliver(self, data: bytes) -> None:
        if data:
            self._feed.sendall(data)

    def close(self) -> None:
        self._closed = True
        self._frames.put(None)
        self._worker.join(timeout=5)
        self._wake.close()
        self._feed.close()


def _open_serial(argument: str, poll_s: float) -> Any:
    import serial  # pyserial

    device, baud = parse_serial_spec(argument)
    return serial.Serial(device, baud or 9600, timeout=poll_s)


class _SerialLink(ModuleLink):
    """A serial port through pyserial, watched by the loop (POSIX)."""

    def __init__(self, argument: str) -> None:
        self._port = _open_serial(argument, 0)
        self.description = f"serial {self._port.port}"

    def fileno(self) -> int:
        return int(self._port.fileno())

    def send(self, frame: bytes) -> None:
        self._port.write(frame)

    def receive(self) -> bytes:
        try:
            return bytes(self._port.read(self._port.in_waiting or 1))
        except Exception as exc:  # pyserial's SerialException: the adapter was unplugged
            raise LinkClosed(f"the module link {self.description} failed: {exc}") from None

    def close(self) -> None:
        self._port.close()


class _ThreadSerialLink(_PumpedLink):
    """A serial port where the loop cannot watch it (Windows): read by the worker thread."""

    def __init__(self, argument: str) -> None:
        self._port = _open_serial(argument, 0.05)
        self.description = f"serial {self._port.port}"
        super().__init__()

    def send(self, frame: bytes) -> None:
        self._port.write(frame)

    def work(self) -> None:
        while not self._closed:
            self.deliver(bytes(self._port.read(self._port.in_waiting or 1)))

    def close(self) -> None:
        super().close()
        self._port.close()


class _PytrinamicLink(_PumpedLink):
    """A pytrinamic interface (USB, serial, CAN adapters): each frame goes out through its
    ``_send`` and the reply comes back through its ``_recv``, the two calls every pytrinamic
    interface implements (TmclInterface's documented contract).  Request and reply only: a
    138 event the module sends later is not read."""

    def __init__(self, arguments: str, address: int) -> None:
        client = PytrinamicClient(arguments, address)
        self.description = f"pytrinamic {arguments!r}"
        self._interface: Any = client.interface
        super().__init__()

    def work(self) -> None:
        interface = self._interface
        while (frame := self._frames.get()) is not None:
            interface._send(interface._host_id, frame[0], frame)
            if frame[1] == Opcode.RESTORE_FACTORY_SETTINGS and \
                    int.from_bytes(frame[4:8], "big") == FACTORY_RESET_KEY:
                continue  # the module restarts without a reply
            try:
                reply = interface._recv(interface._host_id, frame[0])
            except Exception:  # pytrinamic's timeouts: no reply (the loop's timeout says so)
                continue
            self.deliver(bytes(reply))

    def close(self) -> None:
        super().close()
        with contextlib.suppress(Exception):
            self._interface.close()


def open_module_link(where: Where) -> ModuleLink:
    try:
        if where.connection:
            return _PytrinamicLink(where.connection, where.address)
        if where.serial:
            return _SerialLink(where.serial) if can_watch_descriptors() else _ThreadSerialLink(where.serial)
        assert where.tcp is not None  # Where.from_args chose the default
        return _SocketLink(where.tcp)
    except UploadError as exc:
        raise NoReply(str(exc)) from None
    except Exception as exc:  # OSError, pyserial's and pytrinamic's own kinds
        raise NoReply(f"cannot reach the module ({where.describe()}): {exc}") from None


def identify(link: ModuleLink, address: int, timeout: float) -> dict[str, Any]:
    """Command 136 (types 0 and 1), once, before any host is let in."""
    version = _ask(link, Request(address, Opcode.GET_FIRMWARE_VERSION, 0, 0, 0), timeout)
    number = decode_reply(_ask(link, Request(address, Opcode.GET_FIRMWARE_VERSION, 1, 0, 0),
                               timeout)).value & 0xFFFF_FFFF
    kind = module_type_by_number(number >> 16)
    return {"version": version[1:FRAME_LENGTH].decode("ascii", "replace"),
            "module_number": number >> 16, "firmware": f"{number >> 8 & 0xFF}.{number & 0xFF:02d}",
            "type": kind.name if kind is not None else None}


def _ask(link: ModuleLink, request: Request, timeout: float) -> bytes:
    link.send(request.encode())
    data = b""
    deadline = time.monotonic() + timeout
    with selectors.DefaultSelector() as watch:
        watch.register(link.fileno(), selectors.EVENT_READ)
        while len(data) < FRAME_LENGTH:
            left = deadline - time.monotonic()
            if left <= 0 or not watch.select(left):
                raise NoReply(f"no reply from module {request.address} ({link.description}) "
                              f"within {timeout:g} s to command 136 (identify): is the link right? "
                              "(--no-identify skips it)")
            try:
                data += link.receive()
            except LinkClosed as exc:
                raise NoReply(str(exc)) from None
    return data[:FRAME_LENGTH]


# -- the host side ----------------------------------------------------------------------------

@dataclass(eq=False)
class Host:
    """One host: a TCP client, or whoever has a pty open."""

    endpoint: str
    write: Callable[[bytes], None]
    #: What the loop reads it from (asked whether bytes wait unread).
    fd: int
    frames: FrameAssembler = field(default_factory=FrameAssembler)
    connected: bool = True
    #: When the last bytes of a partial frame came (None: no partial frame held).
    partial_since: int | None = None


@dataclass
class _Waiting:
    host: Host
    address: int
    deadline_ns: int


class Proxy:
    """The forwarding loop: ``run()`` serves until interrupted (Ctrl-C, SIGTERM), or raises
    LinkClosed when the module side goes away."""

    def __init__(self, link: ModuleLink, capture: CaptureWriter | None, timeout_s: float) -> None:
        self.link = link
        self.capture = capture
        self.timeout_ns = int(timeout_s * 1e9)
        self.selector = selectors.DefaultSelector()
        self.selector.register(link.fileno(), selectors.EVENT_READ, self._from_module)
        self._replies = FrameAssembler()
        self._queue: deque[tuple[Host, bytes]] = deque()
        self._waiting: _Waiting | None = None
        self._last_host: Host | None = None
        #: Hosts holding a partial frame (see _resync).
        self._partial: set[Host] = set()
        #: Ctrl-C or SIGTERM came while a frame was being handled: stop after it.
        self._stopping = False
        self._in_select = False
        self._cleanup: list[Callable[[], None]] = []
        #: Requests forwarded so far (the closing line says it).
        self.forwarded = 0

    # -- endpoints ------------------------------------------------------------------------------

    def listen_tcp(self, endpoint: str) -> str:
        host, port = parse_host_port(endpoint)
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        server = socket.socket(family, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind((host, port))
        server.listen(16)
        server.setblocking(False)
        self.selector.register(server, selectors.EVENT_READ, lambda: self._accept(server))
        self._cleanup.append(server.close)
        bound = server.getsockname()
        return f"[{bound[0]}]:{bound[1]}" if family == socket.AF_INET6 else f"{bound[0]}:{bound[1]}"

    def _accept(self, server: socket.socket) -> None:
        try:
            client, peer = server.accept()
        except OSError:
            return
        client.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        client.setblocking(False)
        host = Host(f"tcp {peer[0]}:{peer[1]}", client.sendall, client.fileno())
        self.selector.register(client, selectors.EVENT_READ, lambda: self._from_tcp_host(client, host))

    def _from_tcp_host(self, client: socket.socket, host: Host) -> None:
        try:
            data = client.recv(READ_SIZE)
        except BlockingIOError:
            return
        except OSError:
            data = b""
        if not data:
            host.connected = False
            self.selector.unregister(client)
            client.close()
            return
        self._from_host(host, data)

    def listen_pty(self, path: str) -> str:
        """A pseudo-terminal with ``path`` linked to it (whoever opens it is one host)."""
        require_pseudo_terminals()
        link = Path(path)
        lock = LinkLock(link, "tmcl-server or tmcl proxy")
        lock.acquire(link)
        self._cleanup.append(lock.release)
        master, slave, device = open_raw_pty()  # our own slave stays open: no hang-up between hosts
        self._cleanup += [lambda: os.close(slave), lambda: os.close(master)]
        replace_symlink(device, link)
        self._cleanup.insert(0, lambda: remove_link(link, device))
        host = Host(f"pty {path}", _PtyWriter(master), master)
        self.selector.register(master, selectors.EVENT_READ, lambda: self._from_pty(master, host))
        return str(link)

    def _from_pty(self, master: int, host: Host) -> None:
        try:
            data = os.read(master, READ_SIZE)
        except (BlockingIOError, OSError):
            return
        self._from_host(host, data)

    # -- forwarding -----------------------------------------------------------------------------

    def _from_host(self, host: Host, data: bytes) -> None:
        frames = host.frames
        for frame in frames.feed(data):
            self._queue.append((host, frame))
        if frames.buffer:  # a partial frame: dropped if the host then stays silent (_resync)
            host.partial_since = time.monotonic_ns()
            self._partial.add(host)
        elif host.partial_since is not None:
            host.partial_since = None
            self._partial.discard(host)
        if self._waiting is None:
            self._next()

    def _resync(self, now: int) -> None:
        """A partial frame followed by more than 5 ms of silence is dropped, as the module
        drops it (docs/protocol.md).  Silence on the line, not time the proxy spent elsewhere:
        only when no bytes wait unread (the server's pty and TCP do the same)."""
        for host in list(self._partial):
            since = host.partial_since
            if since is None or not host.connected:
                self._partial.discard(host)
            elif now - since > RESYNC_GAP_NS and bytes_waiting(host.fd) == 0:
                host.frames.drop()
                host.partial_since = None
                self._partial.discard(host)

    def _next(self) -> None:
        """Forward the next queued request: the wire is free."""
        while self._waiting is None and self._queue:
            host, frame = self._queue.popleft()
            if not host.connected:
                continue
            if self._replies.buffer:
                self._replies.drop()  # a torn reply from before: stale now
            t = time.monotonic_ns()
            self.link.send(frame)
            self._waiting = _Waiting(host, frame[0], t + self.timeout_ns)
            self._last_host = host
            self.forwarded += 1
            if self.capture is not None:
                self.capture.frame(t, REQUEST, host.endpoint, frame[0], frame)

    def _from_module(self) -> None:
        data = self.link.receive()
        t = time.monotonic_ns()
        for frame in self._replies.feed(data):
            waiting = self._waiting
            if waiting is not None:
                self._waiting = None
                self._deliver(waiting.host, frame)
                if self.capture is not None:
                    self.capture.frame(t, REPLY, waiting.host.endpoint, waiting.address, frame)
                self._next()
            else:
                host = self._last_host
                if host is not None:
                    self._deliver(host, frame)
                if self.capture is not None:
                    self.capture.frame(t, UNSOLICITED, host.endpoint if host else "", None, frame)

    def _deliver(self, host: Host, frame: bytes) -> None:
        if host.connected:
            with contextlib.suppress(OSError):  # a host gone: the capture still has the reply
                host.write(frame)

    def _expire(self) -> None:
        waiting = self._waiting
        if waiting is not None and time.monotonic_ns() >= waiting.deadline_ns:
            self._waiting = None
            if self.capture is not None:
                self.capture.frame(time.monotonic_ns(), NO_REPLY, waiting.host.endpoint,
                                   waiting.address)
            self._next()

    # -- the loop -------------------------------------------------------------------------------

    def run(self) -> None:
        """Serve until Ctrl-C or SIGTERM (:meth:`interrupt`)."""
        select = self.selector.select
        while not self._stopping:
            waiting = self._waiting
            deadline = None if waiting is None else waiting.deadline_ns
            for host in self._partial:
                if host.partial_since is not None:
                    due = host.partial_since + RESYNC_GAP_NS + 1
                    deadline = due if deadline is None else min(deadline, due)
            timeout = None if deadline is None else max(0.0, (deadline - time.monotonic_ns()) / 1e9)
            self._in_select = True
            try:
                ready = select(timeout)
            finally:
                self._in_select = False
            for key, _ in ready:
                key.data()
            if self._partial:
                self._resync(time.monotonic_ns())
            if self._waiting is not None:
                self._expire()

    def interrupt(self, *_: object) -> None:
        """The signal handler: out of a blocking wait at once; while a frame is handled, after
        it (so its forwarding and its capture line go together)."""
        if self._in_select:
            raise KeyboardInterrupt
        self._stopping = True

    def close(self) -> None:
        for step in self._cleanup:
            with contextlib.suppress(OSError):
                step()
        self._cleanup.clear()
        self.selector.close()
        self.link.close()
        if self.capture is not None:
            self.capture.close()


#: How long a frame waits for room in a pty whose host does not read before it is dropped
#: (the capture has it; the proxy must go on serving the others).
PTY_WRITE_PATIENCE_S = 0.2


class _PtyWriter:
    """Whole frames to a pty: a host that reads slowly gets them late, one that reads nothing
    loses them whole (as the server's pty does); once one was lost, the next ones are dropped
    at once until the host reads again."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.stalled = False

    def __call__(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + (0 if self.stalled else PTY_WRITE_PATIENCE_S)
        while view:
            try:
                view = view[os.write(self.fd, view):]
            except BlockingIOError:
                left = deadline - time.monotonic()
                if left <= 0 and len(view) == len(data):
                    self.stalled = True  # nothing of it went out: dropped whole
                    return
                if left <= -1.0:
                    self.stalled = True  # it stopped reading inside a frame: the rest is lost
                    return  # (the 5 ms rule resynchronises the host)
                select.select([], [self.fd], [], max(left, 0.01))
        self.stalled = False


def cmd_proxy(args: argparse.Namespace) -> int:
    where = _check_proxy_args(args)
    link = open_module_link(where)
    try:
        identity = None if args.no_identify else identify(link, where.address, where.timeout)
        capture = _open_capture(args.capture, link, identity)
    except BaseException:
        link.close()
        raise
    proxy = Proxy(link, capture, where.timeout)
    try:
        endpoints = _open_endpoints(proxy, args)
        _announce(link, identity, where.address, endpoints)
        if args.ready_file:
            _write_ready_file(args.ready_file, endpoints)
        _serve(proxy)
        saved = f", capture {args.capture}" if args.capture else ""
        _say(f"tmcl proxy: stopped after {proxy.forwarded} requests{saved}")
        return 0
    finally:
        proxy.close()
        if args.ready_file:
            with contextlib.suppress(OSError):
                Path(args.ready_file).unlink()


def _check_proxy_args(args: argparse.Namespace) -> Where:
    """Somewhere for the hosts, a capture's directory that exists, one way to the module,
    pseudo-terminals if asked for: all before the module is reached."""
    if not args.listen_tcp and not args.listen_pty:
        raise UsageError("give at least one --listen-tcp HOST:PORT or --listen-pty PATH for the hosts")
    if args.capture is not None and not Path(args.capture).absolute().parent.is_dir():
        raise BadInput(f"--capture {args.capture}: directory {Path(args.capture).absolute().parent} "
                       "does not exist")
    where = Where.from_args(args)
    if args.listen_pty:
        try:
            require_pseudo_terminals()
        except PlatformUnsupported as exc:
            raise UsageError(f"--listen-pty: {exc}") from None
    return where


def _open_capture(path: str | None, link: ModuleLink, identity: dict[str, Any] | None
                  ) -> CaptureWriter | None:
    if path is None:
        return None
    try:
        return CaptureWriter.create(path, link.description, identity)
    except OSError as exc:
        raise BadInput(f"--capture {path}: {exc.strerror or exc}") from None


def _announce(link: ModuleLink, identity: dict[str, Any] | None, address: int,
              endpoints: dict[str, list[str]]) -> None:
    """Which module, over what, and every endpoint the hosts may use: one line each."""
    who = (f"{identity['type'] or 'module ' + str(identity['module_number'])} "
           f"({identity['version']})") if identity else f"module {address}"
    _say(f"tmcl proxy: {who} over {link.description}")
    for kind, names in endpoints.items():
        for name in names:
            _say(f"{kind} {name}")


def _serve(proxy: Proxy) -> None:
    """Forward until Ctrl-C or SIGTERM (every frame so far is then on disk); a module link
    that closes is NoReply."""
    main = threading.current_thread() is threading.main_thread()
    previous = [(sig, signal.signal(sig, proxy.interrupt)) for sig in
                (signal.SIGINT, signal.SIGTERM)] if main else []
    try:
        proxy.run()
    except KeyboardInterrupt:
        pass
    except LinkClosed as exc:
        raise NoReply(str(exc)) from None
    finally:
        for sig, handler in previous:
            signal.signal(sig, handler)


def _open_endpoints(proxy: Proxy, args: argparse.Namespace) -> dict[str, list[str]]:
    endpoints: dict[str, list[str]] = {}
    for option, kind, opener in (("--listen-tcp", "tcp", proxy.listen_tcp),
                                 ("--listen-pty", "pty", proxy.listen_pty)):
        for value in getattr(args, option[2:].replace("-", "_")) or ():
            try:
                endpoints.setdefault(kind, []).append(opener(value))
            except (OSError, ValueError) as exc:
                reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else exc
                raise UsageError(f"{option} {value}: {reason}") from None
    return endpoints


def _write_ready_file(path: str, endpoints: dict[str, list[str]]) -> None:
    target = Path(path)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(endpoints), encoding="utf-8")
    os.replace(tmp, target)


def _say(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()
