"""The backup part of the JSON API: download a device's backup, its diff against the defaults or a file, and
the restore of a file.

The download and the diff read every parameter of the device now (a job in its bus worker, between polls); both
are reads, open to every visitor as the rest of the device page is. An uploaded file is checked before the
device is read: at most :data:`MAX_UPLOAD` bytes, UTF-8 (``core.textinput``'s decoder), a backup of a known
model (``ops.backup.loads``); any problem is one line naming the file. A restore is an operator's action (the
checks of :func:`starterbus.web.api._act`), of a text of at most :data:`MAX_UPLOAD` bytes too.
"""

from __future__ import annotations

import json
from typing import Any

from aiohttp import web

from starterbus.core.device import Device
from starterbus.core.errors import StarterbusError, UnsupportedOperationError, ValidationError
from starterbus.core.registry import get_profile
from starterbus.core.textinput import decode_text
from starterbus.ops import backup as backups
from starterbus.ops import diff
from starterbus.web import devices
from starterbus.web.actions import restore_device
from starterbus.web.api import _act, _error, _name, _server
from starterbus.web.auth import Session

MAX_UPLOAD = 256 * 1024  # a backup file is a few kB; anything far larger is not one


def add_routes(app: web.Application) -> None:
    app.router.add_get("/api/devices/{name}/backup", device_backup)
    app.router.add_post("/api/devices/{name}/diff", device_diff)
    app.router.add_post("/api/devices/{name}/restore", device_restore)


async def _read_now(request: web.Request, name: str) -> tuple[backups.Backup, str] | web.Response:
    """Every parameter of device ``name`` read now, and the backup file's text; or the refusal."""

    def take(dev: Device) -> tuple[backups.Backup, str]:
        taken = backups.take_backup(dev)
        return taken, backups.dumps(taken, dev.profile)

    try:
        return await _server(request).fleet.run(name, take)
    except UnsupportedOperationError as exc:
        return _error(409, str(exc))
    except StarterbusError as exc:
        return _error(502, str(exc))


async def device_backup(request: web.Request) -> web.Response:
    """As a backup file, or JSON with the diff against the profile's defaults (``?format=json``)."""
    name = _name(request)
    read = await _read_now(request, name)
    if isinstance(read, web.Response):
        return read
    taken, text = read
    if request.query.get("format") == "json":
        return web.json_response(
            {
                "taken": taken.taken,
                "values": {k: {"raw": e.raw, "text": e.text} for k, e in taken.parameters.items()},
                "diff_defaults": devices.backup_diff(taken, get_profile(taken.model)),
            }
        )
    stamp = taken.taken.replace(":", "").replace("-", "")[:15]
    return web.Response(
        text=text,
        content_type="application/toml",
        headers={"Content-Disposition": f'attachment; filename="{name}-{stamp}.toml"'},
    )


async def _upload(request: web.Request) -> bytes | None:
    """The request's body, or None once it is longer than :data:`MAX_UPLOAD` (the rest is not read)."""
    if request.content_length is not None and request.content_length > MAX_UPLOAD:
        return None
    data = bytearray()
    async for chunk in request.content.iter_chunked(64 * 1024):
        data += chunk
        if len(data) > MAX_UPLOAD:
            return None
    return bytes(data)


async def device_diff(request: web.Request) -> web.Response:
    """``POST`` the bytes of a backup file (``?file=NAME`` names it in errors): the device's parameters read now
    against the file's, ``a`` the file's and ``b`` the device's; only what differs."""
    name = _name(request)
    source = (request.query.get("file") or "the uploaded backup")[:200]
    data = await _upload(request)
    if data is None:
        return _error(413, f"{source}: larger than {MAX_UPLOAD // 1024} kB, not a backup file; nothing read")
    if not data.strip():
        return _error(422, f"{source}: empty, not a backup file; nothing read")
    try:
        uploaded, profile = backups.loads(decode_text(data, source, "backup"), source)
    except StarterbusError as exc:
        return _error(422, f"{exc}; nothing read")
    read = await _read_now(request, name)
    if isinstance(read, web.Response):
        return read
    taken, _text = read
    file_side = diff.ParameterSet(source, profile, uploaded.raws())
    device_side = diff.ParameterSet(name, get_profile(taken.model), taken.raws())
    return web.json_response(
        {
            "taken": taken.taken,
            "file": {"name": source, "model": uploaded.model, "taken": uploaded.taken},
            "model": taken.model,
            "diff": [row.as_json() for row in diff.compare(file_side, device_side)],
        }
    )


async def device_restore(request: web.Request) -> web.Response:
    """``POST {"backup": "TEXT OF THE FILE"}`` (an operator): the differing, allowed parameters written."""

    async def run(name: str, session: Session, body: dict[str, Any]) -> list[Any]:
        text = body.get("backup")
        if not isinstance(text, str):
            raise ValidationError("backup: give the backup file's text")
        size = len(text.encode("utf-8", "surrogatepass"))
        if size > MAX_UPLOAD:
            raise web.HTTPRequestEntityTooLarge(
                max_size=MAX_UPLOAD,
                actual_size=size,
                text=json.dumps(
                    {"error": f"the backup: larger than {MAX_UPLOAD // 1024} kB, not a backup file; nothing sent"}
                ),
                content_type="application/json",
            )
        return await restore_device(_server(request).fleet, name, text, actor=f"web:{session.user}")

    return await _act(request, run)
