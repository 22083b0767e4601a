"""``starterbus identify URL --model MODEL``: the identity the device reports (DeviceNet identity object)."""

from __future__ import annotations

import argparse

from starterbus.cli.output import emit_json, table
from starterbus.core.device import open_device


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wanted: str) -> None:
    p = sub.add_parser("identify", help="read the device's identity (DeviceNet identity object)")
    p.add_argument("url", metavar="URL", help="device URL, e.g. devicenet://virtual/bus0?mac=5")
    p.add_argument("--model", required=True, help="device model (jjr8000) or a profile .toml")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_identify)


def cmd_identify(args: argparse.Namespace) -> int:
    device = open_device(args.url, args.model)
    with device:
        identity = device.transport.identify()
    if args.json:
        emit_json({"device": args.url, "model": device.profile.name, "identity": identity})
    else:
        table(["attribute", "value"], [[key, value] for key, value in identity.items()])
    return 0
