"""The demo fleet with the web server and the history, run in a thread of the test process.

The tests reach the simulated starters directly (``demo.starters``), so an action through the page is checked
where it lands; the audit log and the history database are files in a temporary folder.
"""

from __future__ import annotations

import asyncio
import http.cookiejar
import json
import os
import sys
import threading
import traceback
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from starterbus.aio import AsyncFleet
from starterbus.cli.opcua_cmd import demo_remote
from starterbus.core.audit import ENV_VAR, AuditLog
from starterbus.core.registry import get_transport
from starterbus.fleet.config import parse_fleet
from starterbus.fleet.demo import DemoFleet, start_demo_fleet
from starterbus.ops.recorder import for_fleet
from starterbus.ops.throttle import Throttle
from starterbus.ops.users import Role, UserEntry, hash_password
from starterbus.web.server import WebServer
from starterbus.web.settings import WebSettings

PASSWORD = "operator-password"
#: few iterations: the tests check who may log in, not PBKDF2's cost
USERS = {
    "olga": UserEntry("olga", Role.OPERATOR, hash_password(PASSWORD, iterations=1000)),
    "rita": UserEntry("rita", Role.READ_ONLY, hash_password(PASSWORD, iterations=1000)),
}


@dataclass
class WebDemo:
    url: str
    demo: DemoFleet
    fleet: AsyncFleet
    web: WebServer
    audit: Path
    history: Path
    loop: asyncio.AbstractEventLoop
    extra: dict[str, Any] = field(default_factory=dict)

    def forget_failed_logins(self) -> None:
        """Clear the login throttle (on the server's loop, where it lives)."""

        async def clear() -> None:
            self.web.auth.throttle = Throttle(self.web.auth.policy.throttle)

        asyncio.run_coroutine_threadsafe(clear(), self.loop).result(10)

    def audit_records(self) -> list[dict[str, object]]:
        return AuditLog(self.audit).read()


def _threads() -> str:
    """Every other thread of the process and its innermost calls (what a loop that did not stop waits for)."""
    frames = sys._current_frames()
    lines = []
    for thread in threading.enumerate():
        frame = frames.get(thread.ident or 0)
        if thread is not threading.current_thread() and frame is not None:
            calls = [f"{f.name} ({Path(f.filename).name}:{f.lineno})" for f in traceback.extract_stack(frame)[-3:]]
            lines.append(f"{thread.name}: {' > '.join(calls)}")
    return "; ".join(lines)


def _with_modbus_tcp(demo: DemoFleet, name: str) -> DemoFleet:
    address = next(d.address for bus in demo.config.buses for d in bus.devices if d.name == name)
    assert address is not None, f"{name}: a demo device with no address"
    starter = demo.starters[name]
    (front,) = get_transport("modbus-tcp").start_simulator({"address": "127.0.0.1:0"}, {address: starter})
    demo.simulators.append(front)  # closed with the demo's
    url = front.client_urls()[address].partition("?")[0]
    text = (
        f'{demo.fleet_toml}\n[[bus]]\nname = "{name}-modbus-tcp"\nurl = "{url}"'
        f'\n\n  [[bus.device]]\n  name = "{name}-tcp"\n  model = "{starter.profile.name}"\n  address = {address}\n'
    )
    return DemoFleet(text, parse_fleet(text, "<demo fleet>"), demo.starters, demo.simulators)


@contextmanager
def web_demo(tmp: Path, *, period: float = 0.5, modbus_tcp: str | None = None, **settings: Any) -> Iterator[WebDemo]:
    """The demo fleet polled every ``period`` s, recorded into ``tmp/history.db``, served on a free port.

    ``modbus_tcp``: a demo device whose starter also gets a Modbus TCP front end (a second communication module
    on the same simulated starter), in the fleet as the device ``NAME-tcp`` on a bus of its own.
    """
    audit, history = tmp / "audit.jsonl", tmp / "history.db"
    before = os.environ.get(ENV_VAR)
    os.environ[ENV_VAR] = str(audit)  # the guarded path and the recorder's audit follower use this file
    ready = threading.Event()
    box: dict[str, Any] = {}
    loop = asyncio.new_event_loop()
    stop = asyncio.Event()

    async def main() -> None:
        demo = await asyncio.to_thread(start_demo_fleet, period)
        try:
            if modbus_tcp is not None:
                demo = _with_modbus_tcp(demo, modbus_tcp)
            config = demo_remote(demo.config)
            recorder = for_fleet(history, config)  # as serve's: audit records named by the fleet's device names
            options = {"users": USERS, "history": history, "host": "127.0.0.1", "port": 0, **settings}
            try:
                async with (
                    AsyncFleet(config, sink=recorder) as fleet,
                    WebServer(fleet, WebSettings(**options)) as web,
                ):
                    box["demo"] = WebDemo(web.url, demo, fleet, web, audit, history, loop)
                    ready.set()
                    await stop.wait()
            finally:
                recorder.close()
        finally:
            demo.close()

    def run() -> None:
        try:
            loop.run_until_complete(main())
        except BaseException as exc:  # reported by the waiting test
            box["error"] = exc
            ready.set()

    thread = threading.Thread(target=run, name="web-demo", daemon=True)
    thread.start()
    try:
        ready.wait(60)
        if "error" in box:
            raise box["error"]
        yield box["demo"]
    finally:
        loop.call_soon_threadsafe(stop.set)
        thread.join(30)
        if thread.is_alive():  # (closing a loop that still runs would hide why behind "Cannot close a running loop")
            raise RuntimeError(f"the web demo did not stop within 30 s of its end; threads: {_threads()}")
        loop.close()
        if before is None:
            os.environ.pop(ENV_VAR, None)
        else:
            os.environ[ENV_VAR] = before


class Client:
    """A visitor of the JSON API with its own cookies (a session once logged in) and CSRF token."""

    def __init__(self, base: str) -> None:
        self.base = base.rstrip("/")
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))
        self.csrf: str | None = None

    def call(
        self, method: str, path: str, body: object = None, headers: dict[str, str] | None = None
    ) -> tuple[int, Any]:
        """``body`` is sent as JSON, or as it is when it is bytes (a file upload)."""
        raw = isinstance(body, bytes)
        data = body if isinstance(body, bytes) else json.dumps(body).encode() if body is not None else None
        request = urllib.request.Request(self.base + path, data=data, method=method)
        if data is not None:
            request.add_header("Content-Type", "application/octet-stream" if raw else "application/json")
        if self.csrf:
            request.add_header("X-CSRF-Token", self.csrf)
        for k, v in (headers or {}).items():
            request.add_header(k, v)
        try:
            with self.opener.open(request, timeout=20) as r:
                return r.status, json.loads(r.read() or b"null")
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read() or b"null")

    def login(self, user: str, password: str = PASSWORD) -> int:
        status, body = self.call("POST", "/api/login", {"user": user, "password": password})
        if status == 200:
            self.csrf = body["csrf"]
        return status
