"""``starterbus decode PROTOCOL ...``: annotate frames with the plugin's own sans-IO decoder."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterable

from starterbus.cli.output import emit_json, table
from starterbus.core.errors import ConfigurationError
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
        p.add_argument(
            "data",
            nargs="*",
            metavar="HEX",
            help="bytes as hex (spaces allowed: '02 03 01 00 ...'); none or '-': one frame per line from stdin",
        )
        p.add_argument(
            "--file",
            "-f",
            action="append",
            default=[],
            metavar="FILE",
            help="frames from a file, one per line: hex dumps or candump logs ('(time) can0 ID#DATA')",
        )


_CANDUMP = re.compile(r"^\(\s*[0-9.]+\)\s+\S+\s+(\S+)")


def frame_lines(lines: Iterable[str]) -> list[str]:
    """Frames from text lines: hex dumps or candump log lines; blank lines and ``#`` comments skipped."""
    frames = []
    for line in lines:
        text = line.split("#", 1)[0] if not _looks_like_can(line) else line
        text = text.strip()
        if not text:
            continue
        match = _CANDUMP.match(text)
        frames.append(match.group(1) if match else text)
    return frames


def _looks_like_can(line: str) -> bool:
    """``ID#DATA`` (candump) uses '#' itself: a comment starts a line or follows whitespace."""
    head = line.strip()
    return bool(head) and not head.startswith("#") and re.search(r"[0-9A-Fa-f]#", head) is not None


def _inputs(args: argparse.Namespace) -> list[str]:
    data: list[str] = [d for d in args.data if d != "-"]
    for path in args.file:
        try:
            with open(path, encoding="utf-8") as f:
                data += frame_lines(f)
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigurationError(f"{path}: cannot read frames: {exc}") from None
    if (not args.data and not args.file) or "-" in args.data:
        data += frame_lines(sys.stdin)
    if not data:
        raise ConfigurationError("no frames given (arguments, --file FILE, or lines on stdin)")
    return data


def cmd_decode(args: argparse.Namespace) -> int:
    args.data = _inputs(args)
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
