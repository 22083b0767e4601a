"""``starterbus validate FLEET.toml...``: check fleet files (models, keys, addresses, URLs) without opening anything."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from starterbus.cli.output import emit_json, table
from starterbus.core.errors import StarterbusError


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
    p = sub.add_parser(
        "validate",
        help="check fleet files without opening any port or bus",
        description="Load each fleet file as `poll` would (models, keys, addresses, URLs, remote rules) and "
        "report every device; opens nothing. Exit 0 when all are valid, 1 otherwise.",
    )
    p.add_argument("fleets", nargs="+", metavar="FLEET.toml")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_validate)


def cmd_validate(args: argparse.Namespace) -> int:
    from starterbus.fleet.config import load_fleet

    results: list[dict[str, Any]] = []
    for path in args.fleets:
        try:
            fleet = load_fleet(path)
        except StarterbusError as exc:
            results.append({"file": path, "valid": False, "error": str(exc), "devices": []})
            continue
        devices = [
            {
                "name": d.name,
                "bus": d.bus,
                "model": d.model,
                "url": d.url,
                "period": d.period,
                "points": list(d.measurements + d.parameters),
                "remote_commands": sorted(c.value for c in d.remote.commands),
                "remote_write": sorted(d.remote.write),
            }
            for d in fleet.devices
        ]
        results.append({"file": path, "valid": True, "error": None, "devices": devices})
    if args.json:
        emit_json(results)
    else:
        for result in results:
            if not result["valid"]:
                print(f"starterbus: error: {result['error']}", file=sys.stderr)
                continue
            devices = result["devices"]
            print(f"{result['file']}: valid, {len(devices)} devices")
            table(
                ["device", "bus", "model", "url", "remote"],
                [
                    [d["name"], d["bus"], d["model"], d["url"],
                     ", ".join(d["remote_commands"] + [f"write {k}" for k in d["remote_write"]]) or "-"]
                    for d in devices
                ],
            )  # fmt: skip
    return 0 if all(r["valid"] for r in results) else 1
