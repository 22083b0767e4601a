"""``starterbus opcua FLEET.toml --endpoint opc.tcp://HOST:PORT``: serve a fleet over OPC UA (and ``opcua-user``).

``serve --opcua`` starts the same server (:class:`starterbus.opcua.server.OpcUaServer`) beside the MQTT bridge.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import getpass
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from starterbus.cli.arguments import record_args
from starterbus.cli.lifetime import exit_code, until_signalled
from starterbus.cli.output import emit_json, emit_json_line
from starterbus.core.errors import ConfigurationError
from starterbus.core.outfiles import write_atomically
from starterbus.core.registry import get_profile
from starterbus.core.status import Command
from starterbus.core.supervision import Supervisor
from starterbus.core.timestamps import iso_time
from starterbus.fleet.config import FleetConfig, RemotePolicy, load_fleet

if TYPE_CHECKING:
    from starterbus.opcua.server import OpcUaSettings
    from starterbus.ops.history_writer import HistoryWriter
    from starterbus.ops.recorder import HistoryRecorder


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wanted: str) -> None:
    p = sub.add_parser("opcua", help="serve a fleet over OPC UA (methods and writes through the guarded path)")
    p.add_argument("fleet", nargs="?", metavar="FLEET.toml", help="fleet file (not with --demo)")
    p.add_argument("--endpoint", default="opc.tcp://0.0.0.0:4840/starterbus", help="listen here (default %(default)s)")
    p.add_argument("--demo", action="store_true", help="serve the simulated demo fleet (remote control enabled)")
    p.add_argument("--users", metavar="FILE", help="users file with hashed passwords and roles (see opcua-user)")
    p.add_argument(
        "--pki",
        metavar="DIR",
        default="opcua-pki",
        help="directory of the server certificate; one is generated there on first run (default %(default)s)",
    )
    p.add_argument("--cert", metavar="DER", help="use this server certificate (with --key) instead of --pki")
    p.add_argument("--key", metavar="PEM", help="private key of --cert")
    p.add_argument(
        "--trust-clients",
        metavar="DIR",
        help="the trusted client certificates are in DIR (default: PKI/trusted; unknown ones go to PKI/rejected)",
    )
    p.add_argument(
        "--trust-any-client",
        action="store_true",
        help="accept any client certificate (trials only; default: only those in the trusted folder)",
    )
    p.add_argument(
        "--cert-ip",
        action="append",
        default=[],
        metavar="IP",
        help="an IP address a generated server certificate names (repeatable; the endpoint's is named already)",
    )
    p.add_argument("--anonymous", action="store_true", help="let anonymous clients read and subscribe (never write)")
    p.add_argument(
        "--allow-insecure", action="store_true", help="also offer security policy None (unsigned, unencrypted)"
    )
    p.add_argument(
        "--application-uri", default="", help="the server's application URI (default urn:starterbus:HOST:opcua)"
    )
    p.add_argument(
        "--locale", choices=["en", "zh"], default="en", help="language of display names (the other: descriptions)"
    )
    record_args(p, "also write samples and events to this SQLite history, served by HistoryRead")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument(
        "--metrics",
        metavar="HOST:PORT",
        help="Prometheus endpoint and health probes (/healthz, /readyz), e.g. 127.0.0.1:9478",
    )
    p.add_argument("--json", action="store_true", help="one JSON line when the server is up (endpoint, devices...)")
    p.set_defaults(handler=cmd_opcua)

    p = sub.add_parser("opcua-trust", help="list the refused OPC UA client certificates, or trust one")
    p.add_argument("--pki", metavar="DIR", default="opcua-pki", help="the server's PKI directory (default %(default)s)")
    p.add_argument("name", nargs="?", metavar="NAME", help="a file of PKI/rejected (or its thumbprint's start)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_opcua_trust)

    p = sub.add_parser("opcua-user", help="add or change a user of the OPC UA server (password asked, stored hashed)")
    p.add_argument("users", metavar="USERS.toml", help="users file (created if missing)")
    p.add_argument("name", metavar="NAME")
    p.add_argument("--role", choices=["operator", "read-only"], default="read-only", help="default %(default)s")
    p.add_argument("--delete", action="store_true", help="remove the user instead")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_opcua_user)


def demo_remote(config: FleetConfig) -> FleetConfig:
    """The demo fleet with every command and every configured writable parameter open to remote callers."""
    devices = {}
    buses = []
    for bus in config.buses:
        changed = []
        for original in bus.devices:
            profile = get_profile(original.model)
            writable = frozenset(profile.point(k).key for k in original.parameters if profile.point(k).writable)
            commands = frozenset({Command.START, Command.SOFT_STOP, Command.FAULT_RESET})
            device = dataclasses.replace(original, remote=RemotePolicy(commands, writable))
            devices[device.name] = device
            changed.append(device)
        buses.append(dataclasses.replace(bus, devices=tuple(changed)))
    return dataclasses.replace(config, buses=tuple(buses), devices_by_name=devices)


def _need_asyncua() -> None:
    try:
        import asyncua  # noqa: F401
    except ImportError:
        raise ConfigurationError(
            "the OPC UA server needs asyncua, an optional part: pip install 'starterbus[opcua]'"
        ) from None


def cmd_opcua(args: argparse.Namespace) -> int:
    _need_asyncua()
    from starterbus.opcua.server import OpcUaSettings
    from starterbus.opcua.users import load_users

    if args.demo == bool(args.fleet):
        raise ConfigurationError("give a fleet file or --demo (one of them)")
    users = load_users(args.users) if args.users else {}
    settings = OpcUaSettings(
        endpoint=args.endpoint,
        pki_dir=args.pki,
        users=users,
        anonymous=args.anonymous,
        allow_insecure=args.allow_insecure,
        certificate=args.cert,
        private_key=args.key,
        trusted_clients=args.trust_clients,
        trust_any_client=args.trust_any_client,
        certificate_addresses=tuple(args.cert_ip),
        application_uri=args.application_uri,
        locale=args.locale,
        history=args.record,
    )
    settings.check()
    if args.keep and not args.record:
        raise ConfigurationError("--keep needs --record DB (the history it keeps)")
    if args.demo:
        from starterbus.fleet.demo import demo_fleet

        with demo_fleet() as demo:
            return asyncio.run(_serve(demo_remote(demo.config), settings, args))
    return asyncio.run(_serve(load_fleet(args.fleet), settings, args))


async def _serve(config: FleetConfig, settings: object, args: argparse.Namespace) -> int:
    from starterbus.opcua.server import OpcUaSettings

    assert isinstance(settings, OpcUaSettings)
    stop = asyncio.Event()
    supervisor = Supervisor()  # the poller's threads and the server's tasks: a fatal failure stops it, exit 1
    recorder = None
    if args.record:  # as poll --record: refused (one line) before anything listens
        from starterbus.ops.recorder import for_fleet

        recorder = await asyncio.to_thread(
            for_fleet, args.record, config, args.keep, backlog=args.record_backlog, supervisor=supervisor
        )
    try:
        return await _serve_recorded(config, settings, args, supervisor, recorder, stop)
    finally:
        if recorder is not None:
            await asyncio.to_thread(recorder.close)  # what waits is written (the poller has stopped)


async def _serve_recorded(
    config: FleetConfig,
    settings: OpcUaSettings,
    args: argparse.Namespace,
    supervisor: Supervisor,
    recorder: HistoryRecorder | None,
    stop: asyncio.Event,
) -> int:
    from starterbus.aio import AsyncFleet
    from starterbus.opcua.server import OpcUaServer, security_names

    interrupted = until_signalled(stop, args.duration, supervisor)
    async with (
        AsyncFleet(config, supervisor=supervisor, sink=recorder) as fleet,
        OpcUaServer(fleet, settings) as server,
    ):
        history = recorder.writer if recorder is not None else None
        metrics = _start_health(fleet.poller, args.metrics, server, history)
        policies = security_names(settings.allow_insecure)
        if args.json:
            emit_json_line(
                {
                    "event": "ready",
                    "endpoint": server.endpoint_url,
                    "devices": [d.name for d in config.devices],
                    "security": policies,
                    "users": len(settings.users),
                    "anonymous": settings.anonymous,
                    "metrics": metrics,
                    "history": str(recorder.path) if recorder is not None else None,
                }
            )
        else:
            count = len(settings.users)
            users = f"{count} user{'' if count == 1 else 's'}" + (", anonymous read-only" if settings.anonymous else "")
            security = "Basic256Sha256, Aes256_Sha256_RsaPss, Aes128_Sha256_RsaOaep: Sign, SignAndEncrypt"
            security += ", None" if settings.allow_insecure else ""
            clients = "any client certificate" if settings.trust_any_client else f"clients: {settings.trusted_folder()}"
            security += f"; {clients}"
            print(f"OPC UA: {len(config.devices)} devices on {server.endpoint_url} ({security}; {users})", flush=True)
            if metrics:
                print(f"  Prometheus metrics: {metrics}", flush=True)
            if recorder is not None:
                print(f"  history: {recorder.path} (recorded and served by HistoryRead)", flush=True)
        await stop.wait()
    return exit_code(interrupted, supervisor)


def _start_health(
    poller: object, address: str | None, server: object, history: HistoryWriter | None = None
) -> str | None:
    """systemd's notifications, and with ``--metrics`` the fleet's series, the logins' (``starterbus_opcua_*``),
    ``/healthz`` and ``/readyz``; returns the metrics URL."""
    from starterbus.fleet.health import notify_systemd
    from starterbus.fleet.poller import FleetPoller
    from starterbus.opcua.logins import LoginCollector
    from starterbus.opcua.server import OpcUaServer
    from starterbus.ops.service_metrics import ServiceCollector
    from starterbus.serve.prometheus import FleetCollector, start_metrics_server

    assert isinstance(poller, FleetPoller) and isinstance(server, OpcUaServer)
    notify_systemd(poller)  # under systemd: READY=1 after the first round, WATCHDOG=1 while the polls progress
    if address is None:
        return None
    collector = FleetCollector()
    collector.poller = poller
    host, port, _server = start_metrics_server(
        address, collector, ServiceCollector(poller.supervisor, history), LoginCollector(lambda: server.logins)
    )
    return f"http://{host}:{port}/metrics"


def cmd_opcua_trust(args: argparse.Namespace) -> int:
    """Without a name: the rejected and the trusted client certificates. With one: move it to trusted/."""
    _need_asyncua()
    from starterbus.opcua.trust import REJECTED, TRUSTED, certificates, describe, trust

    pki = Path(args.pki)
    if not pki.is_dir():
        raise ConfigurationError(f"{pki}: no such PKI directory (the server's --pki)")
    if args.name:
        target = trust(pki, args.name)
        if args.json:
            emit_json({"trusted": str(target)})
        else:
            print(f"trusted {target} (the server reads it at the next session)")
        return 0
    listing = {folder: [describe(p) for p in certificates(pki / folder)] for folder in (REJECTED, TRUSTED)}
    if args.json:
        emit_json(
            {
                folder: [
                    {"file": c.file, "subject": c.subject, "uri": c.uri, "thumbprint": c.thumbprint,
                     "not_after": iso_time(c.not_after.timestamp())}
                    for c in infos
                ]
                for folder, infos in listing.items()
            }
        )  # fmt: skip
        return 0
    for folder, infos in listing.items():
        print(f"{pki / folder}: {len(infos)} certificate{'' if len(infos) == 1 else 's'}")
        for c in infos:
            print(f"  {c.file}  {c.subject!r}  {c.uri}  valid until {c.not_after:%Y-%m-%d}")
    if listing[REJECTED]:
        print(f"trust one: starterbus opcua-trust --pki {pki} NAME")
    return 0


def cmd_opcua_user(args: argparse.Namespace) -> int:
    _need_asyncua()
    from starterbus.opcua.users import Role, UserEntry, dump_users, hash_password, load_users

    path = Path(args.users)
    users = load_users(path) if path.exists() else {}
    if args.delete:
        if users.pop(args.name, None) is None:
            raise ConfigurationError(f"{path}: no user {args.name!r}")
    else:
        password = _read_password(args.name)
        users[args.name] = UserEntry(args.name, Role(args.role), hash_password(password))
    write_atomically(path, dump_users(users), replace=True, mode=0o600)  # password hashes: private from the start
    if args.json:
        role = None if args.delete else args.role
        emit_json({"file": str(path), "user": args.name, "action": "removed" if args.delete else "set", "role": role})
    else:
        print(f"{path}: {'removed' if args.delete else 'set'} {args.name}")
    return 0


def _read_password(name: str) -> str:
    """From the terminal (asked twice), or the first line of standard input; never from the command line."""
    if sys.stdin.isatty():
        first = getpass.getpass(f"password for {name}: ")
        if getpass.getpass("again: ") != first:
            raise ConfigurationError("the passwords differ; nothing changed")
        password = first
    else:
        password = sys.stdin.readline().rstrip("\r\n")
    if len(password) < 8:
        raise ConfigurationError("a password needs at least 8 characters; nothing changed")
    return password
