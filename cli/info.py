"""``starterbus models``, ``params MODEL`` and ``transports``: what is installed and what a model holds."""

from __future__ import annotations

import argparse
from typing import Any

from starterbus.cli.output import emit_json, table
from starterbus.core.model import PointDef
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile, profiles, transports


def cmd_models(args: argparse.Namespace) -> int:
    rows: list[dict[str, Any]] = []
    for entry in profiles.load_all():
        prof = entry.loaded
        rows.append(
            {
                "name": entry.name,
                "display_name": prof.display_name if prof else None,
                "vendor": prof.vendor if prof else None,
                "transports": sorted(prof.transports) if prof else [],
                "parameters": len(prof.parameters) if prof else 0,
                "measurements": len(prof.measurements) if prof else 0,
                "source": ", ".join(entry.distributions),
                "error": entry.error,
            }
        )
    if args.json:
        emit_json(rows)
    else:
        table(
            ["model", "name", "transports", "params", "measurements", "from", "error"],
            [
                [
                    r["name"],
                    r["display_name"],
                    ", ".join(r["transports"]),
                    r["parameters"],
                    r["measurements"],
                    r["source"],
                    r["error"] or "",
                ]
                for r in rows
            ],
        )
    return 0


def point_json(point: PointDef) -> dict[str, object]:
    return {
        "key": point.key,
        "kind": point.kind.value,
        "address": point.address,
        "name_zh": point.name_zh,
        "name_en": point.name_en,
        "addresses": {proto: f"0x{addr:04X}" for proto, addr in point.addresses.items()},
        "raw_min": point.raw_min,
        "raw_max": point.raw_max,
        "scale": point.scale,
        "min": point.to_engineering(point.raw_min),
        "max": point.to_engineering(point.raw_max),
        "unit": point.unit,
        "access": point.access.value,
        "default": point.default,
        "enum": (
            {
                "name": point.enum.name,
                "values": {str(k): {"en": v.en, "zh": v.zh} for k, v in point.enum.labels.items()},
            }
            if point.enum
            else None
        ),
        "scale_assumed": point.scale_assumed,
        "note": point.note,
    }


def _range_text(point: PointDef) -> str:
    if point.enum is not None:
        return ", ".join(
            f"{k}={v.en}" for k, v in sorted(point.enum.labels.items()) if point.raw_min <= k <= point.raw_max
        )
    lo, hi = point.to_engineering(point.raw_min), point.to_engineering(point.raw_max)
    text = f"{lo}..{hi} {point.unit}".rstrip()
    if point.scale != 1:
        text += f" (raw {point.raw_min}..{point.raw_max} x{point.scale:g}{', assumed' if point.scale_assumed else ''})"
    return text


def profile_json(profile: Profile) -> dict[str, object]:
    return {
        "model": profile.name,
        "display_name": profile.display_name,
        "vendor": profile.vendor,
        "transports": {k: _jsonable(v) for k, v in profile.transports.items()},
        "faults": {str(k): {"en": v.en, "zh": v.zh} for k, v in profile.faults.labels.items()},
        "notes": list(profile.notes),
        "measurements": [point_json(p) for p in profile.measurements],
        "parameters": [point_json(p) for p in profile.parameters],
    }


def _jsonable(value: object) -> object:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if hasattr(value, "en"):
        return {"en": value.en, "zh": getattr(value, "zh", "")}
    return value


def cmd_params(args: argparse.Namespace) -> int:
    profile = get_profile(args.model)
    if args.json:
        emit_json(profile_json(profile))
        return 0
    protos = sorted({proto for p in profile.points.values() for proto in p.addresses})
    for title, points in (("measurements", profile.measurements), ("parameters", profile.parameters)):
        print(f"{profile.display_name} {title}")
        table(
            ["address", "key", "name", "名称", *protos, "range", "access"],
            [
                [
                    p.address,
                    p.key,
                    p.name_en,
                    p.name_zh,
                    *[f"0x{p.addresses[x]:04X}" if x in p.addresses else "" for x in protos],
                    _range_text(p),
                    p.access.value,
                ]
                for p in points
            ],
        )
        print()
    if profile.notes:
        print("notes:")
        for note in profile.notes:
            print(f"  - {note}")
    return 0


def cmd_transports(args: argparse.Namespace) -> int:
    rows: list[dict[str, Any]] = []
    for entry in transports.load_all():
        plugin = entry.loaded
        rows.append(
            {
                "name": entry.name,
                "summary": plugin.summary if plugin else None,
                "capabilities": sorted(c.value for c in plugin.capabilities) if plugin else [],
                "url_forms": list(plugin.url_forms) if plugin else [],
                "decoder": plugin.has_decoder if plugin else False,
                "target": entry.target,
                "source": ", ".join(entry.distributions),
                "error": entry.error,
            }
        )
    if args.json:
        emit_json(rows)
    else:
        table(
            ["transport", "capabilities", "from", "status"],
            [[r["name"], ", ".join(r["capabilities"]), r["source"], r["error"] or "ok"] for r in rows],
        )
    return 0
