"""The glue between ``starterbus simulate``'s options and :class:`CanopenSimulator` (the only argparse code)."""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from starterbus.core import ConfigurationError, Profile, RunningSimulator, SimulatedStarter


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--canopen",
        metavar="INTERFACE:CHANNEL",
        help="serve the starters as CANopen nodes on a python-can bus (e.g. virtual:bus0, socketcan:can0)",
    )
    parser.add_argument(
        "--canopen-node",
        type=int,
        action="append",
        default=None,
        help="CANopen node id (1-127) of each simulated starter, in --unit order; default: the --unit values",
    )
    parser.add_argument("--canopen-bitrate", type=int, default=None, help="bit rate of the CAN interface")
    parser.add_argument("--canopen-heartbeat", type=int, default=1000, metavar="MS", help="producer heartbeat (0x1017)")
    parser.add_argument(
        "--canopen-master-timeout",
        type=int,
        default=1000,
        metavar="MS",
        help="consumer heartbeat time for the master (0x1016:01): its loss soft-stops a bus-held run (0: off)",
    )
    parser.add_argument("--canopen-master", type=int, default=127, help="the master's node id (its heartbeat)")


def start(args: argparse.Namespace, profile: Profile, starters: Sequence[object]) -> list[RunningSimulator]:
    spec = getattr(args, "canopen", None)
    if not spec:
        if getattr(args, "canopen_node", None):
            raise ConfigurationError("--canopen-node needs --canopen INTERFACE:CHANNEL")
        return []
    from starterbus_canopen.simulator import CanopenSimulator

    if not profile.supports("canopen"):
        raise ConfigurationError(
            f"{profile.display_name} has no CANopen interface (it speaks: {', '.join(profile.transports)})"
        )
    interface, sep, channel = str(spec).partition(":")
    if not sep or not interface or not channel:
        raise ConfigurationError(f"--canopen {spec!r}: expected INTERFACE:CHANNEL, e.g. virtual:bus0")
    nodes = list(args.canopen_node or getattr(args, "unit", None) or [1])
    if len(nodes) != len(starters):
        raise ConfigurationError(f"{len(nodes)} --canopen-node value(s) for {len(starters)} simulated starter(s)")
    simulator = CanopenSimulator(
        (interface, channel),
        bitrate=args.canopen_bitrate,
        heartbeat_ms=args.canopen_heartbeat,
        consumer_ms=args.canopen_master_timeout,
        master=args.canopen_master,
    )
    for node, starter in zip(nodes, starters, strict=True):
        if not isinstance(starter, SimulatedStarter):
            raise ConfigurationError(f"not a simulated starter: {starter!r}")
        simulator.add_node(starter, node)
    try:
        simulator.start()
    except BaseException:
        simulator.close()
        raise
    return [simulator]
