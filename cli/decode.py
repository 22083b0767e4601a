"""``starterbus decode PROTOCOL ...``: annotate frames with the plugin's own sans-IO decoder."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Iterable
from typing import Any

from starterbus.cli.output import emit_json, table
from starterbus.cli.plugin_args import ARGPARSE, OptionMapper, declared, plugin_order, warn
from starterbus.core.errors import ConfigurationError, PluginError, StarterbusError
from starterbus.core.registry import get_profile, get_transport, transports
from starterbus.core.textinput import read_text_file
from starterbus.core.transport import Annotation, TransportPlugin

#: what ``decode NAME`` itself defines; a plugin's options must leave these alone
_OWN_FLAGS = ("-h", "--help", "--model", "--json", "--file", "-f")
_OWN_DESTS = ("help", "model", "json", "file", "data", "protocol", "handler", "command_name", "plugin_args")


def add_subparsers(parser: argparse.ArgumentParser) -> None:
    # `decode --json PROTOCOL ...` as well as `decode PROTOCOL --json ...`; the protocol's own --json has no
    # default, or its False would overwrite the True given before the protocol
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    sub = parser.add_subparsers(dest="protocol", required=True, metavar="PROTOCOL")
    for entry in plugin_order(transports.load_all()):
        plugin = entry.loaded
        if plugin is None:
            warn(f"transport plugin {entry.name!r} left out: {entry.error}")
            continue
        try:
            _add_decoder(sub, plugin)
        except Exception as exc:  # a declaration that raises: this plugin only
            warn(f"transport plugin {plugin.name!r} left out: its decoder cannot be declared ({exc})")


def _add_decoder(sub: argparse._SubParsersAction[argparse.ArgumentParser], plugin: TransportPlugin) -> None:
    if not plugin.has_decoder:
        return
    mapper = OptionMapper(dict.fromkeys(_OWN_FLAGS, "the command"), set(_OWN_DESTS))
    made: list[argparse.ArgumentParser] = []

    def command() -> argparse.ArgumentParser:
        if not made:
            made.append(sub.add_parser(plugin.name, help=f"decode {plugin.name} frames"))
            if plugin.decoder_help:
                made[0].epilog = plugin.decoder_help
        return made[0]

    if plugin.uses_argparse_decoder:
        accepted = mapper.add_argparse(plugin, plugin.add_decode_arguments, command)
    else:
        accepted = mapper.add_typed(plugin, declared(plugin, "decoder_options"), command)
    if not accepted:
        return
    p = command()
    p.add_argument("--model", default=None, help="device model, for names and engineering values")
    p.add_argument("--json", action="store_true", default=argparse.SUPPRESS, help="machine-readable output")
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
    p.set_defaults(plugin_args=mapper)


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
        data += frame_lines(read_text_file(path, "frame log").splitlines())
    if (not args.data and not args.file) or "-" in args.data:
        data += frame_lines(sys.stdin)
    if not data:
        raise ConfigurationError("no frames given (arguments, --file FILE, or lines on stdin)")
    return data


def cmd_decode(args: argparse.Namespace) -> int:
    args.data = _inputs(args)
    plugin = get_transport(args.protocol)
    profile = get_profile(args.model) if args.model else None
    mapper: OptionMapper = args.plugin_args
    annotations: list[Annotation]
    try:
        if mapper.accepted[plugin.name][0] == ARGPARSE:
            legacy: Any = plugin  # the deprecated decode(args, profile)
            annotations = legacy.decode(args, profile)
        else:
            annotations = plugin.decode(args.data, mapper.given(args, plugin.name), profile)
    except StarterbusError:
        raise
    except Exception as exc:
        raise PluginError(f"transport plugin {plugin.name!r} failed to decode: {type(exc).__name__}: {exc}") from exc
    if args.json:
        emit_json([a.as_json() for a in annotations])
    else:
        for a in annotations:
            print(a.title + (f"  ERROR: {a.error}" if a.error else ""))
            if a.fields:
                table(["field", "raw", "meaning"], a.fields)
            print()
    return 1 if any(a.error for a in annotations) else 0
