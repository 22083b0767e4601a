"""The JSON API behind the pages (docs/web.md lists it); the pages use nothing else.

Reads are open to every visitor. Logins, commands, writes and restores need TLS (or
``--http-allow-plaintext-commands``); actions need an operator's session, its CSRF token in ``X-CSRF-Token``, a
JSON body and, when the browser sends one, an ``Origin`` of this server. They go through the fleet's remote path
(:meth:`AsyncFleet.remote_command`, ``remote_write``: the fleet file's ``remote`` table, then the guarded path:
validation, read-back, the audit record ``web:USER``).
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any, Protocol

from aiohttp import web

from starterbus.aio import AsyncFleet, RemoteNotAllowed
from starterbus.core.errors import (
    ConfigurationError,
    StarterbusError,
    UnknownPointError,
    UnsupportedOperationError,
    ValidationError,
)
from starterbus.core.guarded import GuardedOperationError
from starterbus.core.registry import get_profile
from starterbus.web import devices
from starterbus.web.actions import COMMANDS
from starterbus.web.auth import COOKIE, Auth, LoginRefused, Session
from starterbus.web.settings import WebSettings
from starterbus.web.view import FleetView

Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]


class ServerView(Protocol):
    """What the API's handlers use of the server that routes to them (:class:`~starterbus.web.server.WebServer`)."""

    fleet: AsyncFleet
    settings: WebSettings
    view: FleetView
    auth: Auth

    def secure(self, request: web.Request) -> bool: ...

    def actions_allowed(self, request: web.Request) -> bool: ...


SERVER: web.AppKey[ServerView] = web.AppKey("server")


def add_routes(app: web.Application) -> None:
    r = app.router
    r.add_get("/api/fleet", fleet)
    r.add_get("/api/stream", stream)
    r.add_get("/api/session", session_info)
    r.add_post("/api/login", login)
    r.add_post("/api/logout", logout)
    r.add_get("/api/devices/{name}", device)
    r.add_get("/api/devices/{name}/events", device_events)
    r.add_get("/api/devices/{name}/starts", device_starts)
    r.add_get("/api/devices/{name}/starts/{event}", device_start)
    r.add_get("/api/devices/{name}/history", device_history)
    r.add_post("/api/devices/{name}/command", device_command)
    r.add_post("/api/devices/{name}/write", device_write)


def _server(request: web.Request) -> ServerView:
    return request.app[SERVER]


def _error(status: int, message: str, **more: object) -> web.Response:
    return web.json_response({"error": message, **more}, status=status)


def _name(request: web.Request) -> str:
    name = request.match_info["name"]
    if name not in _server(request).fleet.config.devices_by_name:
        raise web.HTTPNotFound(text=json.dumps({"error": f"no device named {name!r}"}), content_type="application/json")
    return name


# -- the fleet ----------------------------------------------------------------------------------------------


async def fleet(request: web.Request) -> web.Response:
    response = web.Response(text=_server(request).view.snapshot_json(), content_type="application/json")
    response.enable_compression()  # 200 kB for 1000 devices, 15 kB gzipped; when the browser accepts it
    return response


async def stream(request: web.Request) -> web.StreamResponse:
    """Server-sent events: ``snapshot`` first, then ``update`` with the changed rows every interval. A page that
    has the rows as of an event id (``?after=ID``, or ``Last-Event-ID`` when the browser reconnects) starts with
    only the rows changed since; ``?device=NAME`` (a device page) carries that device's row only."""
    view = _server(request).view
    device = request.query.get("device")
    if device is not None and device not in view.rows:
        return _error(404, f"no device {device!r} in the fleet")
    response = web.StreamResponse(
        headers={"Content-Type": "text/event-stream", "Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    )
    await response.prepare(request)
    queue = view.subscribe(request.headers.get("Last-Event-ID") or request.query.get("after"), device)
    try:
        await response.write(b"retry: 2000\n\n")
        while True:
            message = await queue.get()
            if message is None:
                break
            await response.write(message)
    except (ConnectionResetError, asyncio.CancelledError):
        pass
    finally:
        view.unsubscribe(queue)
    with contextlib.suppress(ConnectionResetError):
        await response.write_eof()
    return response


# -- sessions -----------------------------------------------------------------------------------------------


def _session(request: web.Request) -> Session | None:
    return _server(request).auth.session(request.cookies.get(COOKIE))


async def session_info(request: web.Request) -> web.Response:
    server = _server(request)
    session = _session(request)
    return web.json_response(
        {
            "user": session.user if session else None,
            "role": session.role.value if session else None,
            "csrf": session.csrf if session else None,
            "logins": bool(server.settings.users),
            "actions_allowed": server.actions_allowed(request),
            "history": server.settings.history is not None,
        }
    )


def _origin_ok(request: web.Request) -> bool:
    origin = request.headers.get("Origin")
    if origin is None:
        return True
    host = request.headers.get("X-Forwarded-Host") if _server(request).settings.behind_proxy else None
    return origin.split("://", 1)[-1] == (host or request.host)


async def _json_body(request: web.Request) -> dict[str, Any]:
    if request.content_type != "application/json":
        raise web.HTTPUnsupportedMediaType(text='{"error": "send application/json"}', content_type="application/json")
    try:
        body = await request.json()
    except ValueError:
        body = None
    except web.HTTPRequestEntityTooLarge as exc:  # aiohttp's own refusal is text; every error here is JSON
        raise web.HTTPRequestEntityTooLarge(
            max_size=request.client_max_size,
            actual_size=request.content_length or 0,
            text=json.dumps({"error": f"the request is larger than {request.client_max_size // 1024} kB"}),
            content_type="application/json",
        ) from exc
    if not isinstance(body, dict):
        raise web.HTTPBadRequest(text='{"error": "the body must be a JSON object"}', content_type="application/json")
    return body


async def login(request: web.Request) -> web.Response:
    server = _server(request)
    if not server.actions_allowed(request):
        return _error(403, "logins need TLS (https): start serve with --http-cert/--http-key or behind a TLS proxy")
    if not _origin_ok(request):
        return _error(403, "cross-site request refused")
    body = await _json_body(request)
    user, password = body.get("user"), body.get("password")
    if not isinstance(user, str) or not isinstance(password, str) or not user:
        return _error(400, "give user and password")
    try:
        session = await server.auth.login(request.remote or "?", user, password)
    except LoginRefused:
        return _error(401, "wrong user name or password, or too many attempts: try again later")
    response = web.json_response({"user": session.user, "role": session.role.value, "csrf": session.csrf})
    response.set_cookie(
        COOKIE,
        session.id,
        httponly=True,
        samesite="Strict",
        secure=server.secure(request),
        path="/",
    )
    return response


async def logout(request: web.Request) -> web.Response:
    server = _server(request)
    session = _session(request)
    if session is not None:
        if not server.auth.csrf_ok(session, request.headers.get("X-CSRF-Token")):
            return _error(403, "missing or wrong CSRF token")
        server.auth.logout(session.id)
    response = web.json_response({"user": None})
    response.del_cookie(COOKIE, path="/")
    return response


async def _operator(request: web.Request) -> Session | web.Response:
    """The operator's session of an action, or the refusal (nothing is sent to any device then)."""
    server = _server(request)
    if not server.actions_allowed(request):
        return _error(403, "actions need TLS (https); refused, nothing sent")
    session = _session(request)
    if session is None:
        return _error(401, "log in as an operator first; refused, nothing sent")
    if not session.operator:
        return _error(403, f"{session.user} is {session.role.value}: only operators act; refused, nothing sent")
    if not _origin_ok(request) or not server.auth.csrf_ok(session, request.headers.get("X-CSRF-Token")):
        return _error(403, "missing or wrong CSRF token; refused, nothing sent")
    return session


# -- a device -----------------------------------------------------------------------------------------------


async def device(request: web.Request) -> web.Response:
    server = _server(request)
    name = _name(request)
    config = server.fleet.config.devices_by_name[name]
    detail = devices.device_detail(
        config, get_profile(config.model), server.view.samples.get(name), server.view.rows[name]
    )
    return web.json_response(detail)


def _history(request: web.Request) -> Path:
    db = _server(request).settings.history
    if db is None:
        raise web.HTTPNotFound(
            text='{"error": "no history: start serve with --record DB"}', content_type="application/json"
        )
    return db


def _float(request: web.Request, key: str) -> float | None:
    text = request.query.get(key)
    if not text:
        return None
    try:
        return float(text)
    except ValueError:
        raise web.HTTPBadRequest(
            text=json.dumps({"error": f"{key}={text!r}: not a number of seconds since the epoch"}),
            content_type="application/json",
        ) from None


async def _in_thread(fn: Callable[[], object]) -> web.Response:
    try:
        return web.json_response(await asyncio.to_thread(fn))
    except ConfigurationError as exc:
        return _error(404, str(exc))


async def device_events(request: web.Request) -> web.Response:
    name, db = _name(request), _history(request)
    since = _float(request, "since")
    after = request.query.get("after")
    if after is not None and not (after.isascii() and after.isdigit()):
        return _error(400, f"after={after!r}: not an event id")
    last = int(after) if after is not None else None
    profile = get_profile(_server(request).fleet.config.devices_by_name[name].model)
    return await _in_thread(lambda: devices.events(db, name, since, last, profile=profile))


async def device_starts(request: web.Request) -> web.Response:
    name, db = _name(request), _history(request)
    return await _in_thread(lambda: devices.starts(db, name))


async def device_start(request: web.Request) -> web.Response:
    name, db = _name(request), _history(request)
    try:
        event = int(request.match_info["event"])
    except ValueError:
        return _error(400, "the event is a number")
    return await _in_thread(lambda: devices.start_plot(db, name, event))


async def device_history(request: web.Request) -> web.Response:
    name, db = _name(request), _history(request)
    key = request.query.get("key")
    since, until = _float(request, "since"), _float(request, "until")
    if since is None:
        since = time.time() - 3600.0
    if not key:
        return await _in_thread(lambda: {"keys": devices.history_keys(db, name)})
    return await _in_thread(lambda: devices.series(db, name, key, since, until))


def _outcomes_json(outcomes: list[Any]) -> list[dict[str, object]]:
    return [o.as_json() for o in outcomes]


Action = Callable[[str, Session, dict[str, Any]], Awaitable[list[Any]]]


async def _act(request: web.Request, run: Action) -> web.Response:
    session = await _operator(request)
    if isinstance(session, web.Response):
        return session
    name = _name(request)
    body = await _json_body(request)
    try:
        outcomes = await run(name, session, body)
    except RemoteNotAllowed as exc:
        return _error(403, f"{exc}; refused, nothing sent")
    except (ValidationError, UnknownPointError) as exc:
        return _error(422, f"{exc}; refused, nothing sent")
    except UnsupportedOperationError as exc:
        return _error(409, f"{exc}; refused, nothing sent")
    except GuardedOperationError as exc:
        return _error(502, str(exc), outcomes=_outcomes_json(exc.outcomes))
    except StarterbusError as exc:
        return _error(502, str(exc))
    return web.json_response({"ok": all(o.ok for o in outcomes), "outcomes": _outcomes_json(outcomes)})


async def device_command(request: web.Request) -> web.Response:
    async def run(name: str, session: Session, body: dict[str, Any]) -> list[Any]:
        command = COMMANDS.get(str(body.get("command")))
        if command is None:
            raise ValidationError(f"command {body.get('command')!r}: one of {', '.join(COMMANDS)}")
        fleet = _server(request).fleet
        return [await fleet.remote_command(name, command, actor=f"web:{session.user}")]

    return await _act(request, run)


async def device_write(request: web.Request) -> web.Response:
    async def run(name: str, session: Session, body: dict[str, Any]) -> list[Any]:
        values = body.get("values")
        if not isinstance(values, dict) or not values:
            raise ValidationError("values: give {KEY: VALUE, ...}")
        for key, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float, str)):
                raise ValidationError(f"{key}: {value!r} is not a number or a text")
        fleet = _server(request).fleet
        return await fleet.remote_write(name, values, actor=f"web:{session.user}")

    return await _act(request, run)
