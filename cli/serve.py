"""``starterbus serve FLEET.toml --mqtt URL --opcua URL --http HOST:PORT``: the fleet as a Sparkplug B edge node,
an OPC UA server and web pages (any of them), one process, one poller."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import socket
import sys
from contextlib import AsyncExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

from starterbus.cli import serve_web
from starterbus.cli.arguments import record_args
from starterbus.cli.lifetime import exit_code, until_signalled
from starterbus.cli.output import emit_json_line
from starterbus.cli.serve_edge import Edge, edge_node, print_banner
from starterbus.core.errors import ConfigurationError

if TYPE_CHECKING:
    from starterbus.fleet.config import FleetConfig


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wanted: str) -> None:
    p = sub.add_parser("serve", help="serve the fleet: Sparkplug B (MQTT), OPC UA, web pages, Prometheus (one poller)")
    p.add_argument("fleet", metavar="FLEET.toml", nargs="?", help="fleet file (or --demo)")
    p.add_argument("--demo", action="store_true", help="serve the simulated demo fleet (no hardware)")
    p.add_argument(
        "--mqtt",
        metavar="URL",
        action="append",
        help="broker: mqtt://HOST[:PORT] or mqtts://HOST[:PORT]; repeat for a list, tried in turn",
    )
    p.add_argument("--group", default="starterbus", help="Sparkplug group id (default starterbus)")
    p.add_argument("--node", default=None, help="Sparkplug edge node id (default: the host name)")
    p.add_argument("--client-id", default=None, help="MQTT client id (default starterbus-GROUP-NODE)")
    p.add_argument("--ca-file", help="CA certificate(s) to verify the broker (mqtts)")
    p.add_argument("--cert-file", help="client certificate (mqtts)")
    p.add_argument("--key-file", help="client certificate's key (mqtts)")
    p.add_argument(
        "--credentials",
        metavar="FILE",
        help="user name (line 1) and password (line 2); default $STARTERBUS_MQTT_USERNAME/$STARTERBUS_MQTT_PASSWORD",
    )
    p.add_argument("--allow-plaintext-commands", action="store_true", help="accept DCMDs on a connection without TLS")
    p.add_argument("--state-file", type=Path, help="where bdSeq persists (default ~/.local/state/starterbus/)")
    p.add_argument("--refresh", type=float, default=60.0, help="republish every value this often, s (0: never)")
    p.add_argument(
        "--deadband",
        metavar="[KEY=]STEPS",
        action="append",
        default=[],
        help="report a value once it moved this many resolution steps (default 1); KEY=STEPS for one point; repeatable",
    )
    p.add_argument("--buffer-file", type=Path, help="store-and-forward buffer (default: beside the state file)")
    p.add_argument("--buffer-messages", type=int, default=1_000_000, help="DDATA kept while the broker is away")
    p.add_argument("--buffer-size", type=float, default=100.0, help="MB of DDATA kept while the broker is away")
    p.add_argument("--buffer-age", type=float, default=86_400.0, help="oldest buffered DDATA kept, s")
    p.add_argument("--command-max-age", type=float, default=10.0, help="refuse DCMDs older than this, s")
    p.add_argument(
        "--command-max-skew", type=float, default=5.0, help="refuse DCMDs dated further in the future than this, s"
    )
    p.add_argument(
        "--command-max-bytes", type=int, default=65_536, help="refuse larger NCMD/DCMD payloads, unparsed (bytes)"
    )
    record_args(p, "also write samples and events to this SQLite history")
    p.add_argument("--primary-host", metavar="ID", help="publish only while this primary host's STATE is online")
    p.add_argument("--metrics", metavar="HOST:PORT", help="Prometheus endpoint, e.g. 127.0.0.1:9477")
    p.add_argument("--opcua", metavar="URL", help="also serve the fleet over OPC UA here, e.g. opc.tcp://0.0.0.0:4840")
    p.add_argument("--opcua-users", metavar="FILE", help="OPC UA users file (see `starterbus opcua-user`)")
    p.add_argument(
        "--opcua-pki", metavar="DIR", default="opcua-pki", help="OPC UA server PKI directory (default %(default)s)"
    )
    p.add_argument("--opcua-anonymous", action="store_true", help="let anonymous OPC UA clients read (never write)")
    p.add_argument("--opcua-allow-insecure", action="store_true", help="also offer OPC UA security None (trials only)")
    p.add_argument(
        "--opcua-trust-any-client",
        action="store_true",
        help="accept any OPC UA client certificate (trials only; default: those in OPCUA_PKI/trusted)",
    )
    serve_web.add_arguments(p)
    p.add_argument("--reconnect-delay", type=float, default=2.0, help="wait between connection attempts, s")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("-v", "--verbose", action="store_true", help="log every connection event")
    p.add_argument("--json", action="store_true", help="one JSON line once it runs (broker, topic, devices...)")
    p.set_defaults(handler=cmd_serve)


def cmd_serve(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.WARNING,
        format="starterbus serve: %(message)s",
        stream=sys.stderr,
    )
    logging.getLogger("starterbus.serve").setLevel(logging.INFO if args.verbose else logging.WARNING)
    if args.demo == bool(args.fleet):
        raise ConfigurationError("serve: give a FLEET.toml or --demo (one of them)")
    if args.mqtt is None and not args.demo:
        if not (args.http or args.opcua):
            raise ConfigurationError("serve: give --mqtt URL, --opcua URL or --http HOST:PORT (what to serve)")
        given = [f"--{o.replace('_', '-')}" for o in MQTT_ONLY if getattr(args, o)]
        if given:
            raise ConfigurationError(f"serve: {', '.join(given)} needs --mqtt URL")
    return asyncio.run(_serve(args))


#: options of the edge node only: refused without ``--mqtt`` rather than ignored
MQTT_ONLY = ("ca_file", "cert_file", "key_file", "credentials", "allow_plaintext_commands", "primary_host",
             "state_file", "buffer_file", "client_id")  # fmt: skip


def _opcua_server(args: argparse.Namespace, fleet: object) -> contextlib.AbstractAsyncContextManager[object]:
    """The OPC UA server of ``serve --opcua``: the same server as ``starterbus opcua``, on the same fleet."""
    if not args.opcua:
        return contextlib.nullcontext()
    from starterbus.cli.opcua_cmd import _need_asyncua

    _need_asyncua()
    from starterbus.opcua.server import OpcUaServer, OpcUaSettings
    from starterbus.opcua.users import load_users

    settings = OpcUaSettings(
        endpoint=args.opcua,
        pki_dir=args.opcua_pki,
        users=load_users(args.opcua_users) if args.opcua_users else {},
        anonymous=args.opcua_anonymous,
        allow_insecure=args.opcua_allow_insecure,
        trust_any_client=args.opcua_trust_any_client,
        history=args.record,  # HistoryRead serves what --record writes
    )
    settings.check()
    server: contextlib.AbstractAsyncContextManager[object] = OpcUaServer(fleet, settings)  # type: ignore[arg-type]
    return server


def _opcua_metrics(args: argparse.Namespace, box: list[object]) -> list[Any]:
    """With ``--opcua``, the series of its logins (``starterbus_opcua_*``), once the server in ``box`` started."""
    if not args.opcua:
        return []
    from starterbus.opcua.logins import LoginCollector

    return [LoginCollector(lambda: getattr(box[0], "logins", None) if box else None)]


async def _serve(args: argparse.Namespace) -> int:
    from starterbus.aio import AsyncFleet
    from starterbus.core.supervision import Supervisor
    from starterbus.fleet.config import load_fleet
    from starterbus.ops.recorder import for_fleet as recorder_for_fleet
    from starterbus.ops.service_metrics import ServiceCollector
    from starterbus.serve.driver import EdgeNodeDriver
    from starterbus.serve.prometheus import FleetCollector, start_metrics_server

    supervisor = Supervisor()  # every thread and task of the service: a fatal failure stops it, exit 1
    interrupted: list[int] = []  # SIGINT once Ctrl-C stopped it: exit 130 after the clean shutdown
    node = args.node or socket.gethostname().split(".")[0]
    if args.opcua:  # where it listens: checked before the fleet, the broker or anything else starts
        from starterbus.opcua.endpoint import parse_endpoint

        parse_endpoint(args.opcua)
    if args.metrics:
        from starterbus.core.textinput import parse_host_port

        parse_host_port(args.metrics, option="--metrics")
    web = serve_web.settings(args)  # --http: its address, users file and TLS files, checked first too
    async with AsyncExitStack() as cleanup:  # closed in reverse: buffer, broker, history, demo
        demo = None
        if args.demo:
            from starterbus.fleet.demo import start_demo_fleet

            demo = await asyncio.to_thread(start_demo_fleet, 1.0)
            cleanup.callback(demo.close)
            config = demo.config
            if web is not None:  # the web pages of the demo may act (MQTT still refuses plaintext DCMDs)
                from starterbus.cli.opcua_cmd import demo_remote

                config = demo_remote(config)
        else:
            config = await asyncio.to_thread(load_fleet, args.fleet)
        recorder = None
        if args.record:  # checked (and refused, one line) before the broker or the poller starts
            recorder = await asyncio.to_thread(
                recorder_for_fleet, args.record, config, args.keep, backlog=args.record_backlog, supervisor=supervisor
            )
            cleanup.push_async_callback(asyncio.to_thread, recorder.close)  # what waits is written
        # the Sparkplug edge node with --mqtt (--demo: an embedded broker); --http/--opcua alone serve without one
        edge = await edge_node(args, config, node, cleanup) if args.mqtt or args.demo else None
        collector = FleetCollector(edge.session if edge is not None else None)
        running = AsyncFleet(config, supervisor=supervisor, sink=recorder)
        driver = (
            None
            if edge is None
            else EdgeNodeDriver(
                running, edge.session, edge.brokers, state_file=edge.state_file, on_sample=collector.observe,
                retry_delay=args.reconnect_delay,
            )
        )  # fmt: skip  # subscribed before the first poll: nothing polled while OPC UA and the web start is lost
        async with running as fleet:
            collector.poller = fleet.poller
            from starterbus.fleet.health import notify_systemd

            assert fleet.poller is not None  # started by `async with`
            notify_systemd(fleet.poller)  # under systemd: READY=1 after the first round, WATCHDOG=1 while polls go on
            stop = asyncio.Event()
            interrupted = until_signalled(stop, args.duration, supervisor)
            metrics = None
            opcua_box: list[object] = []  # the OPC UA server once started (its login series)
            if args.metrics:
                history = recorder.writer if recorder is not None else None
                more = [ServiceCollector(supervisor, history), *_opcua_metrics(args, opcua_box)]
                mhost, mport, _server = start_metrics_server(args.metrics, collector, *more)
                metrics = f"http://{mhost}:{mport}/metrics"
            if demo is not None:
                _run_demo_scenario(fleet.poller, demo, stop, asyncio.get_running_loop())
            async with (
                _opcua_server(args, fleet) as opcua,
                serve_web.running(web, fleet) as http,
            ):  # the banner once every listener is up
                opcua_box.append(opcua)
                listeners = {
                    "metrics": metrics,
                    "opcua": getattr(opcua, "endpoint_url", None),
                    "http": http.url if http is not None else None,
                }
                _report(args, config, edge, node, listeners)
                if driver is None:
                    await stop.wait()
                else:
                    await driver.run(stop)
    return exit_code(interrupted, supervisor)


def _report(
    args: argparse.Namespace, config: FleetConfig, edge: Edge | None, node: str, listeners: dict[str, str | None]
) -> None:
    """Once every listener is up: ``--json``'s one ready line, else the banner for a person."""
    if args.json:
        ready: dict[str, object] = {"event": "ready", "devices": [d.name for d in config.devices]}
        if edge is not None:
            ready |= {
                "broker": edge.brokers[0].describe(),
                "brokers": [b.describe() for b in edge.brokers],
                "buffer_file": str(edge.buffer_file),
                "embedded_broker": edge.embedded,
                "topic": f"{edge.session.topic_prefix}/+/{node}",
                "group": args.group,
                "node": node,
                "commands": edge.options.commands_allowed,
            }
        else:
            ready |= {"broker": None, "brokers": [], "embedded_broker": False, "commands": False}
        emit_json_line(ready | listeners)
        return
    if edge is not None:
        print_banner(edge.session, node, edge.brokers, edge.embedded, edge.options.commands_allowed)
    else:
        print(f"starterbus serve: {len(config.devices)} devices, no MQTT (no --mqtt)", flush=True)
    for label, key in (("Prometheus metrics", "metrics"), ("web dashboard", "http"), ("OPC UA", "opcua")):
        if listeners[key]:
            print(f"  {label}: {listeners[key]}", flush=True)


def _run_demo_scenario(poller: object, demo: object, stop: asyncio.Event, loop: asyncio.AbstractEventLoop) -> None:
    """The demo's scripted starts, faults, resets and stops, over and over, so the broker sees changes."""
    import time

    from starterbus.fleet.demo import DemoFleet, scenario
    from starterbus.fleet.poller import FleetPoller

    assert isinstance(poller, FleetPoller) and isinstance(demo, DemoFleet)

    def run() -> None:
        while not poller.stopping.is_set():
            start = time.monotonic()
            for at, _what, action in scenario(30.0):
                if poller.stopping.wait(max(0.0, start + at - time.monotonic())):
                    return
                action(poller, demo)
            if poller.stopping.wait(max(0.0, start + 32 - time.monotonic())):
                return

    poller.supervisor.thread("demo-scenario", run).start()
