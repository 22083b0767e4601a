"""The Sparkplug B edge node of ``starterbus serve --mqtt`` (or ``--demo``'s embedded broker), made from the
command line: its brokers, session, bdSeq state file and store-and-forward buffer, the options that shape them
(``--deadband``, ``--buffer-*``), and the banner that says where it publishes."""

from __future__ import annotations

import argparse
import asyncio
from contextlib import AsyncExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from starterbus.core.errors import ConfigurationError

if TYPE_CHECKING:
    from starterbus.fleet.config import FleetConfig
    from starterbus.serve.broker import BrokerOptions
    from starterbus.serve.history import Bounds
    from starterbus.serve.session import EdgeSession, SessionOptions


@dataclass
class Edge:
    """The Sparkplug edge node of ``--mqtt`` (or ``--demo``'s embedded broker): its brokers, session and buffer."""

    session: EdgeSession
    options: SessionOptions
    brokers: list[BrokerOptions]
    state_file: Path
    buffer_file: Path
    embedded: bool


async def edge_node(args: argparse.Namespace, config: FleetConfig, node: str, cleanup: AsyncExitStack) -> Edge:
    """The edge node's parts; what must be closed (the embedded broker, the buffer) goes on ``cleanup``."""
    from starterbus.serve.broker import BrokerOptions, load_credentials, parse_broker_url
    from starterbus.serve.session import EdgeSession, SessionOptions
    from starterbus.serve.state import default_state_file, load_bdseq
    from starterbus.serve.store import SqliteStore, default_buffer_file

    if args.mqtt is None:
        from starterbus.serve.embedded import start_mosquitto

        broker_proc = await asyncio.to_thread(start_mosquitto)
        cleanup.callback(broker_proc.close)
        urls = [broker_proc.url]
    else:
        urls = args.mqtt
    username, password = load_credentials(args.credentials)
    brokers = [
        BrokerOptions(
            *parse_broker_url(url),
            args.ca_file,
            args.cert_file,
            args.key_file,
            username,
            password,
            client_id=args.client_id or f"starterbus-{args.group}-{node}",
        )
        for url in urls
    ]
    bounds = buffer_bounds(args)
    options = SessionOptions(
        group=args.group,
        node=node,
        refresh=args.refresh,
        buffer_messages=bounds.messages,
        buffer_size=bounds.size,
        buffer_age=bounds.age,
        command_max_age=args.command_max_age,
        command_max_skew=args.command_max_skew,
        command_max_bytes=args.command_max_bytes,
        commands_allowed=all(b.tls for b in brokers) or args.allow_plaintext_commands,
        primary_host=args.primary_host,
        servers=len(brokers),
    )
    state_file = args.state_file or default_state_file(args.group, node)
    bdseq = await asyncio.to_thread(load_bdseq, state_file)
    steps, per_key = parse_deadbands(args.deadband)
    buffer_file = args.buffer_file or default_buffer_file(state_file)
    store = await asyncio.to_thread(SqliteStore.open, buffer_file, bounds)
    cleanup.callback(store.close)
    session = EdgeSession.for_fleet(
        config, options, deadband_steps=steps, deadband_per_key=per_key, bdseq=bdseq, store=store
    )
    return Edge(session, options, brokers, state_file, buffer_file, args.mqtt is None)


def buffer_bounds(args: argparse.Namespace) -> Bounds:
    """The store-and-forward buffer's bounds from ``--buffer-messages``, ``--buffer-size`` (MB), ``--buffer-age``."""
    from starterbus.serve.history import Bounds

    for option, value in (("messages", args.buffer_messages), ("size", args.buffer_size), ("age", args.buffer_age)):
        if not value > 0:
            raise ConfigurationError(f"--buffer-{option} {value:g}: must be greater than 0")
    return Bounds(args.buffer_messages, int(args.buffer_size * 1_000_000), args.buffer_age)


def parse_deadbands(items: list[str]) -> tuple[float, dict[str, float]]:
    """``["2", "phase_a_current=5"]`` -> (2.0, {"phase_a_current": 5.0}); steps are >= 0."""
    steps, per_key = 1.0, {}
    for item in items:
        key, _, text = item.rpartition("=")
        try:
            value = float(text)
        except ValueError:
            value = -1.0
        if not value >= 0:
            raise ConfigurationError(f"--deadband {item!r}: expected STEPS or KEY=STEPS with STEPS >= 0")
        if key:
            per_key[key] = value
        else:
            steps = value
    return steps, per_key


def print_banner(session: object, node: str, brokers: object, embedded: bool, commands_allowed: bool) -> None:
    """What ``serve`` prints for a person once it runs (``--json``: one JSON line instead)."""
    from starterbus.serve.broker import BrokerOptions
    from starterbus.serve.session import EdgeSession

    assert isinstance(session, EdgeSession) and isinstance(brokers, list)
    broker = brokers[0]
    assert isinstance(broker, BrokerOptions)
    commands = "as the fleet file allows" if commands_allowed else "refused (plaintext)"
    where = f"{session.topic_prefix}/+/{node} on {', '.join(b.describe() for b in brokers)}"
    print(f"starterbus serve: {len(session.devices)} devices as {where}; commands {commands}", flush=True)
    if embedded:
        print(
            "  embedded broker: a local mosquitto for trying it out, not for production\n"
            f"  watch the traffic: mosquitto_sub -h 127.0.0.1 -p {broker.port} -t 'spBv1.0/#' -v"
            "   (payloads are Sparkplug B protobuf)",
            flush=True,
        )
