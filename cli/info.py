"""``starterbus models``, ``params MODEL`` and ``transports``: what is installed and what a model holds."""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from typing import Any

from starterbus.cli.output import emit_json, table
from starterbus.core.address_space import speakers
from starterbus.core.model import PRINTED, Certainty, PointDef
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
                "transports": _speakers(prof) if prof else [],
                "address_spaces": sorted(prof.spaces) if prof else [],
                "overlays": list(prof.overlays) if prof else [],
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


def _speakers(profile: Profile) -> list[str]:
    """The installed transports that serve the model: those speaking one of its address spaces."""
    return sorted(name for space in profile.spaces for name in speakers(space))


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
        "writable_values": sorted(point.writable_values) if point.writable_values is not None else None,
        "enum": (
            {
                "name": point.enum.name,
                "values": {
                    str(k): {"en": v.en, "zh": v.zh, **point.enum.provenance(k).as_json()}
                    for k, v in sorted(point.enum.labels.items())
                },
            }
            if point.enum
            else None
        ),
        "certainty": {
            "address": point.address_source.as_json(),
            "scale": point.scale_source.as_json(),
            "default": point.default_source.as_json(),
            "codes": _weakest(point).value,
        },
        "scale_assumed": point.scale_assumed,
        "note": point.note,
    }


_ORDER = (Certainty.PRINTED, Certainty.INFERRED, Certainty.ASSUMED)


def _weakest(point: PointDef) -> Certainty:
    """The least certain of the point's address, scale (non-enum) and codes in its range (enum)."""
    found = [point.address_source.certainty]
    if point.enum is not None:
        found += [point.enum.provenance(k).certainty for k in point.enum.labels if point.raw_min <= k <= point.raw_max]
    else:
        found.append(point.scale_source.certainty)
    return max(found, key=_ORDER.index)


RANGE_WIDTH = 96  # the table's range column; the whole text is in --json and in the footnotes


def _short(text: str, width: int = RANGE_WIDTH) -> str:
    """A long list of choices, cut at a choice boundary with the count of the rest."""
    if len(text) <= width:
        return text
    parts, shown = text.split(", "), ""
    for i, part in enumerate(parts):
        more = f", … (+{len(parts) - i}, see --json)"
        if len(shown) + len(part) + 2 + len(more) > width and shown:
            return shown + more
        shown = f"{shown}, {part}" if shown else part
    return shown


def _address_text(address: object) -> str:
    if address is None:
        return ""
    return f"0x{address:04X}" if isinstance(address, int) else str(address)


def _range_text(point: PointDef) -> str:
    if point.enum is not None:
        parts = []
        for k, v in sorted(point.enum.labels.items()):
            if point.raw_min <= k <= point.raw_max:
                source = point.enum.provenance(k)
                parts.append(f"{k}={v.en}" + ("" if source.printed else f" ({source.certainty.value})"))
        return ", ".join(parts)
    lo, hi = point.to_engineering(point.raw_min), point.to_engineering(point.raw_max)
    text = f"{lo}..{hi} {point.unit}".rstrip()
    if point.scale != 1:
        assumed = "" if point.scale_source.printed else f", {point.scale_source.certainty.value}"
        text += f" (raw {point.raw_min}..{point.raw_max} x{point.scale:g}{assumed})"
    if point.writable_values is not None:
        text += f"; writable: only {', '.join(map(str, sorted(point.writable_values)))}"
    return text


def _footnotes(points: list[PointDef]) -> list[str]:
    """One line per non-printed address, scale, code table or default, with the profile's reason."""
    lines = []
    for p in points:
        if not p.address_source.printed:
            lines.append(f"{p.address} {p.key}: address {p.address_source.text()}")
        if p.enum is not None:
            seen: dict[str, list[int]] = {}
            for k in sorted(p.enum.labels):
                source = p.enum.provenance(k)
                if not source.printed and p.raw_min <= k <= p.raw_max:
                    seen.setdefault(source.text(), []).append(k)
            for text, codes in seen.items():
                lines.append(
                    f"{p.address} {p.key}: code{'s' if len(codes) > 1 else ''} {', '.join(map(str, codes))} {text}"
                )
        elif not p.scale_source.printed:
            lines.append(f"{p.address} {p.key}: scale x{p.scale:g} {p.scale_source.text()}")
    return lines


def profile_json(profile: Profile) -> dict[str, object]:
    return {
        "model": profile.name,
        "display_name": profile.display_name,
        "vendor": profile.vendor,
        "transports": {k: _jsonable(v) for k, v in profile.spaces.items()},
        "served_by": _speakers(profile),
        "faults": {
            str(k): {"en": v.en, "zh": v.zh, **profile.fault_sources.get(k, PRINTED).as_json()}
            for k, v in sorted(profile.faults.labels.items())
        },
        "notes": list(profile.notes),
        "measurements": [point_json(p) for p in profile.measurements],
        "parameters": [point_json(p) for p in profile.parameters],
    }


def _jsonable(value: object) -> object:
    if isinstance(value, Mapping):
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
            ["address", "key", "name", "名称", *protos, "range", "access", "source"],
            [
                [
                    p.address,
                    p.key,
                    p.name_en,
                    p.name_zh,
                    *[_address_text(p.addresses.get(x)) for x in protos],
                    _short(_range_text(p)),
                    p.access.value,
                    _weakest(p).value,
                ]
                for p in points
            ],
        )
        print()
    uncertain = _footnotes(profile.measurements + profile.parameters)
    if uncertain:
        print(
            "not printed in the manual (how the profile reads it; writing such a parameter needs an acknowledgement):"
        )
        for line in uncertain:
            print(f"  - {line}")
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
