"""``serve --http``: the web dashboard on ``serve``'s event loop (the history of ``--record`` on its device pages)."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

from starterbus.core.errors import ConfigurationError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--http", metavar="HOST:PORT", help="also serve the web dashboard here, e.g. 127.0.0.1:8080")
    p.add_argument(
        "--http-users", metavar="FILE", help="who may log in on the web pages (default: the --opcua-users file)"
    )
    p.add_argument("--http-cert", metavar="PEM", help="TLS certificate chain of the web server")
    p.add_argument("--http-key", metavar="PEM", help="its private key")
    p.add_argument(
        "--http-allow-plaintext-commands",
        action="store_true",
        help="accept web logins and actions without TLS (trials on a trusted network only)",
    )
    p.add_argument(
        "--http-behind-proxy",
        action="store_true",
        help="a TLS reverse proxy on this host forwards to --http (trust its X-Forwarded-Proto)",
    )


def settings(args: argparse.Namespace) -> Any:
    """The web server's settings, checked before anything starts (None without ``--http``)."""
    if not args.http:
        for option in ("http_users", "http_cert", "http_key"):
            if getattr(args, option):
                raise ConfigurationError(f"--{option.replace('_', '-')} needs --http HOST:PORT")
        return None
    from starterbus.core.textinput import parse_host_port
    from starterbus.ops.users import load_users
    from starterbus.web.settings import WebSettings

    host, port = parse_host_port(args.http, option="--http")
    users_file = args.http_users or args.opcua_users
    web = WebSettings(
        host,
        port,
        users=load_users(users_file) if users_file else {},
        cert=args.http_cert,
        key=args.http_key,
        allow_plaintext_commands=args.http_allow_plaintext_commands,
        behind_proxy=args.http_behind_proxy,
        history=Path(args.record) if args.record else None,
    )
    web.check()
    return web


@contextlib.asynccontextmanager
async def running(web: Any, fleet: Any) -> AsyncIterator[Any]:
    """The web server (``--http``) beside ``fleet``; yields it (None without ``--http``)."""
    if web is None:
        yield None
        return
    from starterbus.web.server import WebServer

    async with WebServer(fleet, web) as server:
        yield server
