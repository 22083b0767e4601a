"""``starterbus decode PROTOCOL ...``: annotate frames with the plugin's own sans-IO decoder."""

from __future__ import annotations

import argparse

from starterbus.cli.output import emit_json, table
from starterbus.core.registry import get_profile, get_transport, transports


def add_subparsers(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="protocol", required=True, metavar="PROTOCOL")
    for entry in transports.load_all():
        plugin = entry.loaded
        if plugin is None or not plugin.has_decoder:
            continue
        p = sub.add_parser(plugin.name, help=f"decode {plugin.name} frames")
        p.add_argument("--model", default=None, help="device model, for names and engineering values")
        p.add_argument("--json", action="store_true", help="machine-readable output")
        plugin.add_decode_arguments(p)
        p.add_argument("data", nargs="+", metavar="HEX", help="bytes as hex (spaces allowed: '02 03 01 00 ...')")


def cmd_decode(args: argparse.Namespace) -> int:
    plugin = get_transport(args.protocol)
    profile = get_profile(args.model) if args.model else None
    annotations = plugin.decode(args, profile)
    if args.json:
        emit_json([a.as_json() for a in annotations])
    else:
        for a in annotations:
            print(a.title + (f"  ERROR: {a.error}" if a.error else ""))
            if a.fields:
                table(["field", "raw", "meaning"], a.fields)
            print()
    return 1 if any(a.error for a in annotations) else 0
