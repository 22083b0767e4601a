"""``starterbus identify URL|NAME``: the identity the device reports (DeviceNet identity object)."""

from __future__ import annotations

import argparse

from starterbus.cli.arguments import device_args
from starterbus.cli.output import emit_json, table
from starterbus.core.device import open_device


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wanted: str) -> None:
    p = sub.add_parser("identify", help="read the device's identity (DeviceNet identity object)")
    device_args(p)
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
