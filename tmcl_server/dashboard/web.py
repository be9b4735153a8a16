"""The dashboard's web server (aiohttp, on the server's own event loop): ``--http [HOST:]PORT``.

Routes: ``/`` the page, ``/static/...`` its files (no CDN: it works offline), ``/ws`` one
WebSocket per open page, ``/api/hello`` and ``/api/frame?module=A`` the same JSON for scripts,
and the REST face ``/api/command``, ``/api/fault`` (:mod:`.api`).

Update protocol (docs/dashboard.md): the server sends ``hello`` once, then ``frame`` messages,
each after the page acknowledged the previous one (``{"op": "ack"}``, sent when the page has
drawn it), at most :data:`FRAME_PERIOD_S` apart: a slow browser gets fewer frames, never a
backlog.  Samples of the axes are taken every :data:`SAMPLE_PERIOD_S` (wall) on simulated time,
so a frame carries every sample since the page's last one.  The page's other messages
(``view``, ``command``, ``switch``, ``load``, ``input``, ``analog``, ``breakpoint``) are
carried out by :class:`~tmcl_server.dashboard.core.Dashboard`.

Every request first passes :class:`~tmcl_server.dashboard.guard.AccessPolicy` (Origin, Host,
token) and the port's limits (:mod:`.limits`: connections, request and frame rates, pages),
docs/dashboard.md "Security" and docs/robustness.md.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import socket
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aiohttp import WSMsgType, web
from aiohttp.http_exceptions import HttpProcessingError

from tmcl_server.dashboard.api import add_routes as add_rest_routes
from tmcl_server.dashboard.core import ActionError, Dashboard, Viewer
from tmcl_server.dashboard.guard import TOKEN_ENV, AccessPolicy
from tmcl_server.dashboard.limits import ConnectionGate, Pace
from tmcl_server.endpoints import parse_host_port
from tmcl_server.sidechannel import SideChannel
from tmcl_server.transports.admission import ESTABLISHED_IDLE_S
from tmcl_server.transports.base import Transport, TransportHost
from tmcl_server.transports.mqtt.payload import PayloadError, parse_json

if TYPE_CHECKING:
    from tmcl_server.simulation import Simulation

log = logging.getLogger(__name__)

STATIC = Path(__file__).resolve().parent / "static"
#: A page gets at most one frame per this many wall seconds (10 per second: smooth enough for
#: the plots, and a browser on the same small machine leaves the simulator its CPU) ...
FRAME_PERIOD_S = 0.1
#: ... and waits at most this long for its acknowledgement (a hidden tab draws nothing).
ACK_TIMEOUT_S = 1.0
#: The axes of every module a page shows are sampled this often (wall seconds).
SAMPLE_PERIOD_S = 0.02
#: Parameter values (a few hundred reads) go out at most this often, only to pages that
#: show the Parameters section.
PARAMETER_PERIOD_S = 0.5
#: Connections one ``--http`` port holds at once (pages, scripts, a browser's parallel
#: fetches); who gets a slot past it: transports/admission.py (docs/robustness.md).
MAX_CONNECTIONS = 32
#: Pages (WebSockets) open at once; past it a page silent a minute is closed, else the new one.
MAX_PAGES = 8
#: Plain HTTP requests (page, static files, /api/...) answered per second over the whole port,
#: and at once: more wait their turn with their connection's reading paused.
REQUEST_RATE, REQUEST_BURST = 30.0, 60
#: A request that would wait longer than this for its turn is answered 503 at once.
MAX_WAIT_S = 3.0
#: Frames sent per second to all pages together (each page at most 1 / FRAME_PERIOD_S).
FRAME_RATE = 40.0
#: Messages one page may send per second (acks come at most 10 a second).
MESSAGE_RATE, MESSAGE_BURST = 100.0, 100
#: The largest message a page may send (its messages are a few dozen bytes).
MAX_MESSAGE = 64 * 1024
#: An HTTP connection with no request for this long is closed (aiohttp's keep-alive timeout).
HTTP_IDLE_S = 30.0
#: A page is pinged this often and closed if it does not answer within half of it ...
HEARTBEAT_S = 20.0
#: ... and closed if it sent nothing for this long (an open page acknowledges frames, a
#: hidden one says "alive" every 30 s; it reconnects by itself when shown again).
PAGE_IDLE_S = 120.0


class _ParseErrorInOneLine(logging.Filter):
    """aiohttp logs a request it cannot parse with a traceback whose message quotes the
    request line, ``?token=...`` included (issue 36, N7): one line instead, naming the kind of
    error and the peer, never the request."""

    def filter(self, record: logging.LogRecord) -> bool:
        exc = record.exc_info[1] if record.exc_info else None
        if isinstance(exc, HttpProcessingError):
            record.msg = "dashboard: a malformed request from %s refused (%s, HTTP %s)"
            peer = record.args[0] if isinstance(record.args, tuple) and record.args else "?"
            record.args = (peer, type(exc).__name__, exc.code)
            record.exc_info = record.exc_text = None
        return True


def _one_line_parse_errors() -> None:
    server_log = logging.getLogger("aiohttp.server")
    if not any(isinstance(f, _ParseErrorInOneLine) for f in server_log.filters):
        server_log.filters.insert(0, _ParseErrorInOneLine())  # before the repeat filter


def _compact(message: dict[str, Any]) -> str:
    return json.dumps(message, separators=(",", ":"), ensure_ascii=False)


class DashboardTransport(Transport):
    """``--http [HOST:]PORT`` (default host 127.0.0.1; port 0 picks a free one)."""

    kind = "http"

    def __init__(self, simulation: Simulation, argument: str, allowed_origins: list[str] | None = None,
                 token: str | None = None) -> None:
        self.simulation = simulation
        self.host, self.port = parse_host_port(argument)
        self.policy = AccessPolicy.for_address(self.host, allowed_origins or (), token)
        self.dashboard = Dashboard(simulation)
        self._pages: dict[web.WebSocketResponse, Viewer] = {}
        #: When each page last sent something (the longest silent goes first at MAX_PAGES).
        self._heard: dict[web.WebSocketResponse, float] = {}
        self._runner: web.AppRunner | None = None
        self._server: asyncio.AbstractServer | None = None
        self._gate: ConnectionGate | None = None
        self._sampler: asyncio.Task[None] | None = None
        self._closing: set[asyncio.Task[bool]] = set()
        #: The plots' samples: a failure stops them (one warning), the module goes on.
        self._sampling = SideChannel("the dashboard's plots")
        self._requests = Pace(REQUEST_RATE, REQUEST_BURST)
        self._frames = Pace(FRAME_RATE, MAX_PAGES)
        #: New pages refused because MAX_PAGES were open and heard within the idle time.
        self.pages_refused = 0

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> DashboardTransport:
        return cls(host.simulation, argument, list(host.option("http_allow_origins") or ()),
                   host.option("http_token") or os.environ.get(TOKEN_ENV) or None)

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> list[str]:
        _one_line_parse_errors()
        app = web.Application(middlewares=[self._guard], client_max_size=MAX_MESSAGE)
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/api/hello", self._api_hello)
        app.router.add_get("/api/frame", self._api_frame)
        add_rest_routes(app, self.dashboard)  # /api/command, /api/fault (api.py)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False,
                                     keepalive_timeout=HTTP_IDLE_S)
        await self._runner.setup()
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.host, self.port))
            sock.listen(128)
        except OSError:
            sock.close()
            await self._runner.cleanup()
            raise
        host, port = sock.getsockname()[:2]
        self.policy.port = port
        shown = f"[{host}]" if ":" in host else host
        assert self._runner.server is not None  # set up above
        self._gate = ConnectionGate(self._runner.server, MAX_CONNECTIONS, f"http {shown}:{port}")
        self._server = await asyncio.get_running_loop().create_server(self._gate, sock=sock)
        url = f"http://{shown}:{port}/"
        if self.policy.token is not None:
            log.warning("the dashboard listens beyond loopback, on %s: anyone who can reach it "
                        "and holds the token can drive the modules; open %s?token=... as printed "
                        "(docs/dashboard.md, Security)", url, url)
            return [f"{url}?token={self.policy.token}"]
        return [url]

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
        for ws in list(self._pages):
            with contextlib.suppress(Exception):
                await ws.close()
        if self._sampler is not None:
            self._sampler.cancel()
            self._sampler = None
        if self._gate is not None:
            self._gate.close_all()
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None
        if self._server is not None:
            await self._server.wait_closed()
            self._server = None

    # -- who may ask, and how often -----------------------------------------------------------

    @web.middleware
    async def _guard(self, request: web.Request, handler: Any) -> web.StreamResponse:
        """Origin, Host and token first (docs/dashboard.md, Security); then a request waits
        its turn (REQUEST_RATE over the port) with its connection's reading paused."""
        refusal = self.policy.refusal(request.headers, request.query, request.cookies,
                                      request.scheme)
        gate = self._gate
        assert gate is not None  # set before the port listens
        if refusal is None:
            gate.request_complete(request.transport)
        try:
            return await self._admitted(request, handler, refusal)
        finally:
            gate.answered(request.transport, upgraded=refusal is None and request.path == "/ws")

    async def _admitted(self, request: web.Request, handler: Any,
                        refusal: str | None) -> web.StreamResponse:
        if refusal is not None:
            peer = request.remote or "?"
            log.warning("dashboard: refused %s %s from %s: %s", request.method, request.path,
                        peer, refusal)
            return web.Response(status=403, text=f"tmcl-server dashboard: {refusal}\n")
        wait = self._requests.delay(MAX_WAIT_S)
        if wait is None:  # a backlog longer than MAX_WAIT_S already: answer at once
            return web.Response(status=503, headers={"Retry-After": "1"},
                                text="tmcl-server dashboard: too many requests, ask again later\n")
        if wait:
            transport = request.transport
            if transport is not None:
                transport.pause_reading()
            try:
                await asyncio.sleep(wait)
            finally:
                if transport is not None and not transport.is_closing():
                    transport.resume_reading()
            if transport is None or transport.is_closing():  # the client left meanwhile
                return web.Response(status=503)
        response = await handler(request)
        if (self.policy.token is not None and "token" in request.query
                and not response.prepared):  # the page's later requests carry it as a cookie
            response.set_cookie(self.policy.cookie_name, request.query["token"], httponly=True,
                                samesite="Strict", path="/")
        return response

    # -- plain HTTP ---------------------------------------------------------------------------

    async def _index(self, request: web.Request) -> web.StreamResponse:
        return web.FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-cache"})

    async def _api_hello(self, request: web.Request) -> web.Response:
        return web.json_response(self.dashboard.hello(), dumps=_compact)

    async def _api_frame(self, request: web.Request) -> web.Response:
        """The present state of one module (no samples or wire: those need a page's cursor)."""
        try:
            slot = int(request.query.get("module", next(iter(self.dashboard.modules))))
            frame = self.dashboard.frame(Viewer("http", slot), parameters=True)
        except (ValueError, ActionError) as exc:
            raise web.HTTPBadRequest(text=str(exc)) from None
        return web.json_response(frame, dumps=_compact)

    # -- pages --------------------------------------------------------------------------------

    async def _websocket(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(max_msg_size=MAX_MESSAGE, heartbeat=HEARTBEAT_S)
        await ws.prepare(request)
        peer = request.transport.get_extra_info("peername") if request.transport else None
        endpoint = f"http {peer[0]}:{peer[1]}" if peer else "http"
        viewer = Viewer(endpoint, next(iter(self.dashboard.modules)))
        if len(self._heard) >= MAX_PAGES:  # a page silent a minute makes room, else no room
            oldest = min(self._heard, key=self._heard.__getitem__)
            silent = time.monotonic() - self._heard[oldest]
            if silent < ESTABLISHED_IDLE_S:
                self.pages_refused += 1
                log.warning("dashboard: %d pages open (the limit), each heard within %.0f s: "
                            "a new one is refused (%d so far)", len(self._heard),
                            ESTABLISHED_IDLE_S, self.pages_refused)
                await ws.close(message=b"too many pages open")
                return ws
            log.warning("dashboard: %d pages open (the limit); closing %s, silent for %.1f s",
                        len(self._heard), self._pages[oldest].endpoint, silent)
            del self._heard[oldest]
            self._closing.add(asyncio.create_task(oldest.close(message=b"too many pages open")))
            self._closing = {task for task in self._closing if not task.done()}
        self._pages[ws] = viewer
        self._heard[ws] = time.monotonic()
        self.dashboard.watch(asyncio.get_running_loop())
        if self._sampler is None:
            self._sampler = asyncio.create_task(self._sample(), name="dashboard-sampler")
        acknowledged = asyncio.Event()
        acknowledged.set()
        feeder: asyncio.Task[None] | None = None
        pace = Pace(MESSAGE_RATE, MESSAGE_BURST)
        try:
            await ws.send_str(_compact(self.dashboard.hello()))
            feeder = asyncio.create_task(self._feed(ws, viewer, acknowledged), name="dashboard-page")
            while not ws.closed:
                message = await ws.receive(timeout=PAGE_IDLE_S)
                if message.type in (WSMsgType.CLOSE, WSMsgType.CLOSING, WSMsgType.CLOSED,
                                    WSMsgType.ERROR):
                    break
                self._heard[ws] = time.monotonic()
                self._gate.heard(request.transport)  # type: ignore[union-attr]
                if message.type != WSMsgType.TEXT:
                    continue
                answer = self._handle(message.data, viewer, acknowledged)
                if answer is not None:
                    await ws.send_str(_compact(answer))
                await pace.turn()  # a flood waits here; aiohttp then stops reading the socket
        except TimeoutError:
            log.info("dashboard page %s: silent for %.0f s, closed", viewer.endpoint, PAGE_IDLE_S)
            await ws.close(message=b"idle")
        except (ConnectionError, asyncio.CancelledError, RuntimeError):
            pass
        finally:
            if feeder is not None:
                feeder.cancel()
            del self._pages[ws]
            self._heard.pop(ws, None)
            self.dashboard.unwatch()
            if not self._pages and self._sampler is not None:
                self._sampler.cancel()
                self._sampler = None
        return ws

    def _handle(self, text: str, viewer: Viewer, acknowledged: asyncio.Event) -> dict[str, Any] | None:
        """One message of a page; whatever goes wrong is answered with one ``error`` message
        (nested too deeply, not JSON, a value a model refused), never a closed socket."""
        message: Any = None
        try:
            message = parse_json(text)  # bounded nesting and finite numbers (payload.py)
            if not isinstance(message, dict):
                raise ActionError("a message is a JSON object")
            op = message.get("op")
            if op == "ack":
                acknowledged.set()
                return None
            if op == "alive":
                return None
            return self.dashboard.act(message, viewer)
        except PayloadError as exc:
            error = f"message refused: {exc}"
        except (ValueError, TypeError) as exc:  # ActionError, a value a model refused
            error = str(exc)
        except Exception as exc:  # a bug: one line for the page, one rate-limited line here
            log.error("dashboard page %s: a message failed: %s: %s", viewer.endpoint,
                      type(exc).__name__, exc)
            error = f"the message failed: {type(exc).__name__}"
        return {"type": "error", "id": message.get("id") if isinstance(message, dict) else None,
                "message": error}

    async def _feed(self, ws: web.WebSocketResponse, viewer: Viewer,
                    acknowledged: asyncio.Event) -> None:
        """Frames for one page: each after the last was acknowledged, at most 10 a second."""
        loop = asyncio.get_running_loop()
        parameters_due = 0.0
        try:
            while not ws.closed:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(acknowledged.wait(), ACK_TIMEOUT_S)
                acknowledged.clear()
                await self._frames.turn()  # all pages share FRAME_RATE
                if ws.closed:
                    break
                began = loop.time()
                parameters = viewer.parameters and began >= parameters_due
                if parameters:
                    parameters_due = began + PARAMETER_PERIOD_S
                await ws.send_str(_compact(self.dashboard.frame(viewer, parameters)))
                await asyncio.sleep(max(0.0, FRAME_PERIOD_S - (loop.time() - began)))
        except (ConnectionError, RuntimeError) as exc:  # the page went away mid-send
            log.debug("dashboard page %s: %s", viewer.endpoint, exc)
        except Exception as exc:  # a frame that cannot be built: this page stops, nothing else
            log.error("dashboard page %s: its frames stopped: %s: %s", viewer.endpoint,
                      type(exc).__name__, exc)
            await ws.close(message=b"internal error")

    async def _sample(self) -> None:
        sample = self._sampling.guard(self.dashboard.sample, "sampling the axes")
        while not self._sampling.stopped:
            sample({viewer.slot for viewer in self._pages.values()})
            await asyncio.sleep(SAMPLE_PERIOD_S)
