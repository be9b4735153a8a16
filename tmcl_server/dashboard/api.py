"""The dashboard's REST face, for scripts and CI steps (docs/dashboard.md, "REST API"):

    POST   /api/command   one TMCL command: the body a line as ``tmcl send`` takes it
                          (``SAP 4, 0, 51200``, ``GAP MaxVelocity 0``), or JSON: {"command":
                          LINE} or {"opcode"|"cmd", "type", "motor", "value"}; the module by
                          ``?module=A`` or "module" (default the first); the reply, decoded
    POST   /api/fault     a fault in the fault language (docs/faults.md): the body a spec
                          (``noreply:opcode=GAP,count=1``), or JSON {"fault": SPEC or TABLE} or
                          a table with a "kind"; the fault installed, and all of them
    GET    /api/fault     the faults installed
    DELETE /api/fault     every fault removed (``?id=N``: that one)

Nothing here checks who asks: every request has passed web.py's guard first, the same
Host/Origin/token rules (:class:`~tmcl_server.dashboard.guard.AccessPolicy`) and rate limits
as the page and its WebSocket.  Nothing here acts either: commands and faults go the page's
way, :meth:`~tmcl_server.dashboard.core.Dashboard.act` (a command through the router like a
host's, traced as ``http HOST:PORT``; a fault through the one fault parser and injector).
Answers are JSON; a request that cannot be carried out gets 400 and ``{"error": ...}``.
"""

from __future__ import annotations

import json
import logging
from functools import partial
from typing import Any

from aiohttp import web

from tmcl_server.dashboard.core import ActionError, Dashboard, Viewer
from tmcl_server.transports.mqtt.payload import PayloadError, parse_json

log = logging.getLogger(__name__)

#: Answers keep their arrows (→) as characters: one JSON object, as printed by curl.
_dumps = partial(json.dumps, ensure_ascii=False)
#: JSON keys of a command given by its fields ("opcode" is the REST spelling of "cmd").
_FIELDS = ("cmd", "type", "motor", "value")


def add_routes(app: web.Application, dashboard: Dashboard) -> None:
    """The REST routes on the dashboard's application (behind its guard middleware)."""
    api = RestApi(dashboard)
    app.router.add_post("/api/command", api.command)
    app.router.add_post("/api/fault", api.add_fault)
    app.router.add_get("/api/fault", api.list_faults)
    app.router.add_delete("/api/fault", api.remove_faults)


class RestApi:
    def __init__(self, dashboard: Dashboard) -> None:
        self.dashboard = dashboard

    async def command(self, request: web.Request) -> web.Response:
        async def build() -> dict[str, Any]:
            body = await _body(request)
            message: dict[str, Any] = {"op": "command"}
            if isinstance(body, str) or "command" in body:
                line = body if isinstance(body, str) else body["command"]
                if not isinstance(line, str):
                    raise ActionError('"command" must be a TMCL line such as "SAP 4, 0, 51200"')
                slot = _module(request, {} if isinstance(body, str) else body, self.dashboard)
                message.update(_parse_line(line, self.dashboard.module(slot).type), module=slot)
                return message
            fields = dict(body)
            if "opcode" in fields:
                if "cmd" in fields:
                    raise ActionError('give either "opcode" or "cmd", not both')
                fields["cmd"] = fields.pop("opcode")
            unknown = sorted(set(fields) - {*_FIELDS, "module"})
            if unknown:
                raise ActionError(f"unknown field(s) {', '.join(unknown)}; use command, or opcode, "
                                  "type, motor, value (and module)")
            message.update({k: fields[k] for k in _FIELDS if k in fields},
                           module=_module(request, fields, self.dashboard))
            return message

        return await self._act(request, build, drop=("type", "id"))

    async def add_fault(self, request: web.Request) -> web.Response:
        async def build() -> dict[str, Any]:
            body = await _body(request)
            if isinstance(body, dict) and "fault" in body:
                body = body["fault"]
            return {"op": "fault", "fault": body}

        return await self._act(request, build, drop=("type", "id"))

    async def list_faults(self, request: web.Request) -> web.Response:
        async def build() -> dict[str, Any]:
            return {"op": "faults"}

        return await self._act(request, build, drop=("type", "id"))

    async def remove_faults(self, request: web.Request) -> web.Response:
        async def build() -> dict[str, Any]:
            if "id" not in request.query:
                return {"op": "clear_faults"}
            text = request.query["id"]
            if not text.isdigit():
                raise ActionError(f"id must be a fault's number, got {text!r}")
            return {"op": "remove_fault", "fault": int(text)}

        return await self._act(request, build, drop=("type", "id"))

    async def _act(self, request: web.Request, build: Any, drop: tuple[str, ...]) -> web.Response:
        """The message ``build()`` makes, carried out by the page's own :meth:`Dashboard.act`."""
        peer = request.transport.get_extra_info("peername") if request.transport else None
        viewer = Viewer(f"http {peer[0]}:{peer[1]}" if peer else "http",
                        next(iter(self.dashboard.modules)))
        try:
            answer = self.dashboard.act(await build(), viewer) or {}
        except (PayloadError, ValueError, TypeError) as exc:  # ActionError is a ValueError
            return web.json_response({"error": str(exc)}, status=400, dumps=_dumps)
        except Exception as exc:  # a bug: one line here, one for the client, the server goes on
            log.error("dashboard REST %s %s failed: %s: %s", request.method, request.path,
                      type(exc).__name__, exc)
            return web.json_response({"error": f"the request failed: {type(exc).__name__}"},
                                     status=500, dumps=_dumps)
        return web.json_response({k: v for k, v in answer.items() if k not in drop}, dumps=_dumps)


async def _body(request: web.Request) -> str | dict[str, Any]:
    """The body: a JSON object (bounded nesting, finite numbers), or else its text."""
    try:
        text = (await request.read()).decode("utf-8")
    except UnicodeDecodeError:
        raise ActionError("the body is not UTF-8 text") from None
    stripped = text.strip()
    if request.content_type == "application/json" or stripped.startswith("{"):
        body = parse_json(stripped)
        if not isinstance(body, dict):
            raise ActionError("a JSON body must be an object")
        return body
    if not stripped:
        raise ActionError("the body is empty: give a TMCL line or a fault spec")
    return stripped


def _module(request: web.Request, body: dict[str, Any], dashboard: Dashboard) -> int:
    """The module asked for: ``"module"`` in the body, else ``?module=``, else the first."""
    if "module" in body:
        slot = body["module"]
    elif "module" in request.query:
        text = request.query["module"]
        if not text.isdigit():
            raise ActionError(f"module must be a number, got {text!r}")
        slot = int(text)
    else:
        slot = next(iter(dashboard.modules))
    return dashboard.module(slot).slot


def _parse_line(line: str, kind: Any) -> dict[str, int]:
    """A line as ``tmcl send`` reads it (its own parser: mnemonics, operands, names)."""
    from tmcl_server.decode import vocabulary
    from tmcl_server.tool.line import LineError, parse_command

    try:
        command = parse_command(line, vocabulary(kind))
    except LineError as exc:
        raise ActionError(str(exc)) from None
    return {"cmd": command.opcode, "type": command.type, "motor": command.motor,
            "value": command.value}
