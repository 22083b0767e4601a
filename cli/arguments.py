"""The options several commands share: a device (URL or fleet name), the fleet file, ``--json`` and the guard
of anything that writes or actuates (``--yes``, ``--dry-run``, ``--audit-log``), the history options of the
long-running commands."""

from __future__ import annotations

import argparse


def record_args(p: argparse.ArgumentParser, record_help: str) -> None:
    """``--record DB`` (its help says what the command does with it), ``--keep`` and ``--record-backlog``."""
    p.add_argument("--record", metavar="DB", help=record_help)
    p.add_argument("--keep", action="append", metavar="AGE|SIZE", help="history retention: 30d, 12h, 500MB")
    p.add_argument(
        "--record-backlog",
        type=int,
        default=10_000,
        metavar="N",
        help="samples kept in memory while the history cannot be written; older ones are dropped (default 10000)",
    )


def json_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")


def device_args(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "url",
        metavar="URL|NAME",
        help="device URL (modbus-rtu:///dev/ttyUSB0?unit=2&baudrate=9600) or a device name from the fleet file",
    )
    p.add_argument(
        "--model", default=None, help="device model (jjr5000, ssd1, jjr8000) or a profile .toml; required with a URL"
    )
    fleet_arg(p)
    p.set_defaults(resolve_target=True)
    json_flag(p)


def fleet_arg(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--fleet",
        metavar="FILE",
        default=None,
        help="fleet file for device names (default $STARTERBUS_FLEET, or `fleet` in ~/.config/starterbus/config.toml)",
    )


def guard_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--yes", "-y", action="store_true", help="do it without asking (required without a terminal)")
    p.add_argument("--dry-run", action="store_true", help="print the exact frames that would be sent; send nothing")
    p.add_argument(
        "--audit-log",
        metavar="PATH",
        default=None,
        help="append to this JSON-lines audit log (default $STARTERBUS_AUDIT_LOG or "
        "~/.local/state/starterbus/audit.jsonl)",
    )
