"""The web server of ``serve --http``: aiohttp on the event loop that already runs the fleet and the edge node.

```python
async with AsyncFleet(config) as fleet:
    async with WebServer(fleet, WebSettings("127.0.0.1", 8080, users=load_users("users.toml"))) as web:
        print(web.url)
        ...  # serves until the block ends
```

Nothing here blocks the loop: device I/O runs in the poller's bus workers (:meth:`AsyncFleet.run`,
``remote_command``/``remote_write``), the history database and password checks in worker threads.
"""

from __future__ import annotations

import asyncio
import contextlib
import ipaddress
import ssl
from collections.abc import Awaitable, Callable, Mapping
from pathlib import Path
from typing import Any

from aiohttp import web

from starterbus.aio import AsyncFleet
from starterbus.core.errors import ConfigurationError
from starterbus.web import api, backup_api
from starterbus.web.auth import Auth
from starterbus.web.settings import WebSettings
from starterbus.web.view import FleetView

ASSETS = Path(__file__).parent / "assets"
Handler = Callable[[web.Request], Awaitable[web.StreamResponse]]
SERVER = api.SERVER

#: the pages load nothing from elsewhere: scripts, styles and data from this server only
SECURITY_HEADERS = {
    "Content-Security-Policy": (
        "default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
        "connect-src 'self'; frame-ancestors 'none'; base-uri 'none'; form-action 'self'"
    ),
    "X-Content-Type-Options": "nosniff",
    "X-Frame-Options": "DENY",
    "Referrer-Policy": "same-origin",
}


class WebServer:
    """The pages and the JSON API for ``fleet``, served until the ``async with`` block ends."""

    def __init__(self, fleet: AsyncFleet, settings: WebSettings) -> None:
        self.fleet = fleet
        self.settings = settings
        self.view = FleetView(fleet.config, self._line_stats, interval=settings.interval)
        self.auth = Auth(settings.users, settings.logins)
        self.url = ""
        self._runner: web.AppRunner | None = None
        self._stop = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []

    def _line_stats(self) -> Mapping[str, Any]:
        poller = self.fleet.poller
        return poller.line_stats() if poller is not None else {}

    def secure(self, request: web.Request) -> bool:
        """Whether the browser reached us over TLS (directly, or through a trusted proxy on this host)."""
        if request.secure:
            return True
        if not self.settings.behind_proxy:
            return False
        peer = request.remote or ""
        try:
            loopback = ipaddress.ip_address(peer).is_loopback
        except ValueError:
            loopback = False
        return loopback and request.headers.get("X-Forwarded-Proto", "").lower() == "https"

    def actions_allowed(self, request: web.Request) -> bool:
        return self.secure(request) or self.settings.allow_plaintext_commands

    def app(self) -> web.Application:
        app = web.Application(middlewares=[_headers], client_max_size=1024 * 1024)
        app[SERVER] = self
        api.add_routes(app)
        backup_api.add_routes(app)
        app.router.add_get("/", _page("fleet.html"))
        app.router.add_get("/device/{name}", _page("device.html"))
        app.router.add_static("/assets/", ASSETS, append_version=False)
        return app

    async def __aenter__(self) -> WebServer:
        self.settings.check()
        context = None
        if self.settings.tls:
            context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
            try:
                context.load_cert_chain(self.settings.cert or "", self.settings.key)
            except (OSError, ssl.SSLError) as exc:
                raise ConfigurationError(f"--http-cert/--http-key: {exc}") from exc
        self._runner = web.AppRunner(self.app(), access_log=None, handle_signals=False)
        await self._runner.setup()
        site = web.TCPSite(self._runner, self.settings.host, self.settings.port, ssl_context=context)
        try:
            await site.start()
        except OSError as exc:
            await self._runner.cleanup()
            raise ConfigurationError(
                f"--http {self.settings.host}:{self.settings.port}: cannot listen: {exc.strerror or exc}"
            ) from exc
        host, port = _bound(site)
        scheme = "https" if context is not None else "http"
        self.url = f"{scheme}://{_url_host(host)}:{port}/"
        supervisor = self.fleet.supervisor
        self._tasks = [
            supervisor.task("web-samples", lambda: self.view.consume(self.fleet.samples()), restart=True),
            supervisor.task("web-flusher", lambda: self.view.run_flusher(self._stop), restart=True),
        ]
        return self

    async def __aexit__(self, *exc: object) -> None:
        self._stop.set()
        for task in self._tasks:
            task.cancel()
        for task in self._tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task
        for queue in list(self.view._clients):  # end every event stream, so the runner need not wait for it
            with contextlib.suppress(asyncio.QueueFull):
                queue.put_nowait(None)
        if self._runner is not None:
            await self._runner.cleanup()
        self.auth.close()


def _bound(site: web.TCPSite) -> tuple[str, int]:
    server = site._server
    sockets = getattr(server, "sockets", None) or []
    if sockets:
        name = sockets[0].getsockname()
        return str(name[0]), int(name[1])
    return site._host or "127.0.0.1", site._port


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def _page(name: str) -> Handler:
    async def handler(_request: web.Request) -> web.StreamResponse:
        return web.FileResponse(ASSETS / name, headers={"Cache-Control": "no-cache"})

    return handler


@web.middleware
async def _headers(request: web.Request, handler: Handler) -> web.StreamResponse:
    response = await handler(request)
    for name, value in SECURITY_HEADERS.items():
        response.headers.setdefault(name, value)
    if request.path.startswith("/assets/"):  # revalidated (ETag: a 304): after an upgrade, never an old script
        response.headers.setdefault("Cache-Control", "no-cache")
    if request.app[SERVER].settings.tls:
        response.headers.setdefault("Strict-Transport-Security", "max-age=31536000")
    return response
