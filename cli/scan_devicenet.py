"""``starterbus scan devicenet://INTERFACE/CHANNEL``: the MAC ids answering on a DeviceNet bus, their identity
objects and models, and a fleet file to start from (docs/commissioning.md). Explicit messaging only."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from starterbus.cli.output import emit_json, table
from starterbus.core.errors import ConfigurationError
from starterbus.core.profile import Profile
from starterbus.core.url import DeviceUrl

NAME = "devicenet"
MAX_MAC = 63


def mac_range(text: str) -> tuple[int, int]:
    first, _, last = text.partition("-")
    try:
        lo, hi = int(first), int(last or first)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not A-B (e.g. 1-20)") from None
    if not 0 <= lo <= hi <= MAX_MAC:
        raise argparse.ArgumentTypeError(f"{text!r}: MAC ids are 0..{MAX_MAC}, the first no larger than the last")
    return lo, hi


def _profiles(names: str | None) -> list[Profile]:
    from starterbus.core.registry import get_profile, profiles

    chosen = [n.strip() for n in names.split(",")] if names else profiles.names()
    usable = [p for p in (get_profile(name) for name in chosen) if p.supports(NAME)]
    if not usable:
        raise ConfigurationError(f"scan: none of {', '.join(chosen)} has a DeviceNet interface")
    return usable


def bus_url(url: DeviceUrl) -> str:
    """The bus's URL for a fleet file: without the per-node parameters the scan added."""
    base, _, query = url.text.partition("?")
    kept = [p for p in query.split("&") if p and p.partition("=")[0] not in ("mac", "timeout", "control")]
    return f"{base}?{'&'.join(kept)}" if kept else base


def fleet_text(url: DeviceUrl, found: Sequence[object]) -> str:
    from starterbus.transports.devicenet.scan import Node

    lines = [
        "# Written by `starterbus scan`: check the names and models, then `starterbus validate` this file",
        "# and `starterbus poll` it (docs/commissioning.md).",
        "",
        "[[bus]]",
        'name = "devicenet-1"',
        f'url = "{bus_url(url)}"',
    ]
    for node in found:
        assert isinstance(node, Node)
        if node.model is None:
            lines += ["", f"  # MAC {node.mac} answered ({node.identity.get('product_name')!r}): {node.why}"]
            continue
        lines += ["", "  [[bus.device]]", f'  name = "{node.model}-{node.mac}"', f'  model = "{node.model}"']
        lines.append(f"  address = {node.mac}")
    return "\n".join(lines) + "\n"


def run_scan(args: argparse.Namespace, url: DeviceUrl, target: Path | None) -> int:
    from starterbus.core.outfiles import write_atomically
    from starterbus.transports.devicenet.scan import scan_bus

    if args.units or args.baudrates or args.parities or args.quick:
        raise ConfigurationError("scan devicenet: --units, --baudrates, --parities and --quick are Modbus options")
    lo, hi = args.macs or (0, MAX_MAC)
    profiles = _profiles(args.models)

    def progress(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    try:
        found = scan_bus(url, profiles, list(range(lo, hi + 1)), timeout=args.timeout or 0.1, progress=progress)
    except KeyboardInterrupt:
        print("scan: interrupted; nothing written", file=sys.stderr)
        return 130
    if target is not None:
        write_atomically(target, fleet_text(url, found), replace=args.force)
    if args.json:
        emit_json({
            "url": url.text, "output": str(target) if target else None,
            "found": [{"mac": n.mac, "model": n.model, "identity": n.identity, "why": n.why} for n in found],
        })  # fmt: skip
    elif found:
        rows = [(n.mac, n.identity.get("product_name"), n.identity.get("serial_number"), n.model or "?", n.why)
                for n in found]  # fmt: skip
        table(("mac", "product", "serial", "model", "why"), rows)
    else:
        print("scan: no node answered", file=sys.stderr)
    return 0 if found else 1
