"""The dashboard's web server (aiohttp, on the server's own event loop): ``--http [HOST:]PORT``.

Routes: ``/`` the page, ``/static/...`` its files (no CDN: it works offline), ``/ws`` one
WebSocket per open page, ``/api/hello`` and ``/api/frame?module=A`` the same JSON for scripts.

Update protocol (docs/dashboard.md): the server sends ``hello`` once, then ``frame`` messages,
each after the page acknowledged the previous one (``{"op": "ack"}``, sent when the page has
drawn it), at most :data:`FRAME_PERIOD_S` apart: a slow browser gets fewer frames, never a
backlog.  Samples of the axes are taken every :data:`SAMPLE_PERIOD_S` (wall) on simulated time,
so a frame carries every sample since the page's last one.  The page's other messages
(``view``, ``command``, ``switch``, ``load``, ``input``, ``analog``, ``breakpoint``) are
carried out by :class:`~tmcl_server.dashboard.core.Dashboard`.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import socket
from pathlib import Path
from typing import TYPE_CHECKING, Any

from aiohttp import WSMsgType, web

from tmcl_server.dashboard.core import ActionError, Dashboard, Viewer
from tmcl_server.endpoints import parse_host_port
from tmcl_server.transports.base import Transport, TransportHost

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


def _compact(message: dict[str, Any]) -> str:
    return json.dumps(message, separators=(",", ":"), ensure_ascii=False)


class DashboardTransport(Transport):
    """``--http [HOST:]PORT`` (default host 127.0.0.1; port 0 picks a free one)."""

    kind = "http"

    def __init__(self, simulation: Simulation, argument: str) -> None:
        self.simulation = simulation
        self.host, self.port = parse_host_port(argument)
        self.dashboard = Dashboard(simulation)
        self._pages: dict[web.WebSocketResponse, Viewer] = {}
        self._runner: web.AppRunner | None = None
        self._sampler: asyncio.Task[None] | None = None

    @classmethod
    def build(cls, host: TransportHost, argument: str) -> DashboardTransport:
        return cls(host.simulation, argument)

    # -- lifecycle ----------------------------------------------------------------------------

    async def start(self) -> list[str]:
        app = web.Application()
        app.router.add_get("/", self._index)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/api/hello", self._api_hello)
        app.router.add_get("/api/frame", self._api_frame)
        app.router.add_static("/static/", STATIC, follow_symlinks=False)
        self._runner = web.AppRunner(app, access_log=None, handle_signals=False)
        await self._runner.setup()
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        sock = socket.socket(family, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((self.host, self.port))
        except OSError:
            sock.close()
            await self._runner.cleanup()
            raise
        host, port = sock.getsockname()[:2]
        await web.SockSite(self._runner, sock).start()
        shown = f"[{host}]" if ":" in host else host
        return [f"http://{shown}:{port}/"]

    async def close(self) -> None:
        for ws in list(self._pages):
            with contextlib.suppress(Exception):
                await ws.close()
        if self._sampler is not None:
            self._sampler.cancel()
            self._sampler = None
        if self._runner is not None:
            await self._runner.cleanup()
            self._runner = None

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
        ws = web.WebSocketResponse(max_msg_size=1 << 20)
        await ws.prepare(request)
        peer = request.transport.get_extra_info("peername") if request.transport else None
        endpoint = f"http {peer[0]}:{peer[1]}" if peer else "http"
        viewer = Viewer(endpoint, next(iter(self.dashboard.modules)))
        self._pages[ws] = viewer
        self.dashboard.watch(asyncio.get_running_loop())
        if self._sampler is None:
            self._sampler = asyncio.create_task(self._sample(), name="dashboard-sampler")
        acknowledged = asyncio.Event()
        acknowledged.set()
        feeder: asyncio.Task[None] | None = None
        try:
            await ws.send_str(_compact(self.dashboard.hello()))
            feeder = asyncio.create_task(self._feed(ws, viewer, acknowledged), name="dashboard-page")
            async for message in ws:
                if message.type != WSMsgType.TEXT:
                    continue
                answer = self._handle(message.data, viewer, acknowledged)
                if answer is not None:
                    await ws.send_str(_compact(answer))
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            if feeder is not None:
                feeder.cancel()
            del self._pages[ws]
            self.dashboard.unwatch()
            if not self._pages and self._sampler is not None:
                self._sampler.cancel()
                self._sampler = None
        return ws

    def _handle(self, text: str, viewer: Viewer, acknowledged: asyncio.Event) -> dict[str, Any] | None:
        message: Any = None
        try:
            message = json.loads(text)
            if not isinstance(message, dict):
                raise ActionError("a message is a JSON object")
            if message.get("op") == "ack":
                acknowledged.set()
                return None
            return self.dashboard.act(message, viewer)
        except (ValueError, TypeError) as exc:  # ActionError, bad JSON, a value a model refused
            return {"type": "error", "id": message.get("id") if isinstance(message, dict) else None,
                    "message": str(exc)}

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
                began = loop.time()
                parameters = viewer.parameters and began >= parameters_due
                if parameters:
                    parameters_due = began + PARAMETER_PERIOD_S
                await ws.send_str(_compact(self.dashboard.frame(viewer, parameters)))
                await asyncio.sleep(max(0.0, FRAME_PERIOD_S - (loop.time() - began)))
        except (ConnectionError, RuntimeError) as exc:  # the page went away mid-send
            log.debug("dashboard page %s: %s", viewer.endpoint, exc)

    async def _sample(self) -> None:
        while True:
            self.dashboard.sample({viewer.slot for viewer in self._pages.values()})
            await asyncio.sleep(SAMPLE_PERIOD_S)
