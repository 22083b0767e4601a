"""``starterbus crosscheck --model M URL URL...``: one device through several paths, an agreement table."""

from __future__ import annotations

import argparse

from starterbus.cli.output import emit_json, table
from starterbus.core.errors import ConfigurationError
from starterbus.fleet.crosscheck import crosscheck


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--model", required=True, help="device model")
    p.add_argument("urls", nargs="+", metavar="URL", help="two or more URLs reaching the SAME device")
    p.add_argument("--keys", nargs="*", default=None, metavar="KEY", help="compare only these keys")
    p.add_argument("--no-parameters", action="store_true", help="compare measurements and status only")
    p.add_argument("--all", action="store_true", help="also list rows that fewer than two paths report")
    p.add_argument("--json", action="store_true", help="machine-readable output")


def _cell(text: str | None, width: int = 32) -> str:
    if text is None:
        return "-"
    return text if len(text) <= width else text[: width - 1] + "…"


def cmd_crosscheck(args: argparse.Namespace) -> int:
    if len(args.urls) < 2:
        raise ConfigurationError("crosscheck needs at least two URLs reaching the same device")
    report = crosscheck(args.urls, args.model, args.keys, include_parameters=not args.no_parameters)
    if args.json:
        emit_json(report.as_json())
        return 0 if report.ok else 1
    for i, path in enumerate(report.paths, 1):
        state = f"error: {path.error}" if path.error else f"{path.transport}"
        print(f"[{i}] {path.url}  ({state})")
    rows = [r for r in report.rows if args.all or r.agree is not None]
    table(
        ["what", *[f"[{i}]" for i in range(1, len(report.paths) + 1)], "agree"],
        [
            [
                r.what,
                *[_cell(x) for x in r.readings],
                "-" if r.agree is None else ("yes" if r.agree else "NO"),
            ]
            for r in rows
        ],
    )
    disagreements = sum(1 for r in report.rows if r.agree is False)
    print(f"{report.compared} compared, {disagreements} disagree: {'AGREE' if report.ok else 'DISAGREE'}")
    return 0 if report.ok else 1
