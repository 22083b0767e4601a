"""``backup``, ``diff``, ``restore`` (and, from :mod:`starterbus.cli.ops_history_cmds`, ``history``, ``record``,
``plot``): the operator workflows of :mod:`starterbus.ops`."""

from __future__ import annotations

import argparse
import sys

from starterbus.cli.arguments import device_args, fleet_arg
from starterbus.cli.device_cmds import _show_outcomes, _user, prompt_hook, show_dry_run, write_previews
from starterbus.cli.output import emit_json, table
from starterbus.core.audit import AuditLog
from starterbus.core.device import open_device
from starterbus.core.errors import ConfigurationError, StarterbusError
from starterbus.core.guarded import GuardedOperationError
from starterbus.core.outfiles import check_target
from starterbus.ops import backup as backups
from starterbus.ops import restore as restores
from starterbus.ops.diff import compare, load_pair


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser], wanted: str) -> None:
    from starterbus.cli import ops_history_cmds

    p = sub.add_parser("backup", help="save every readable parameter of a device to an editable TOML file")
    device_args(p)
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="the backup file to write (TOML); - = stdout")
    p.add_argument("--force", action="store_true", help="replace FILE if it exists (default: refuse)")
    p.set_defaults(handler=cmd_backup)

    p = sub.add_parser(
        "diff",
        help="compare two parameter sets: backup FILE, device URL@MODEL or NAME, or defaults[@MODEL]; "
        "exit 1 if they differ",
    )
    p.add_argument("a", metavar="A", help="backup file, URL@MODEL (or URL with --model), device NAME, defaults[@MODEL]")
    p.add_argument("b", metavar="B")
    p.add_argument("--model", help="the model of a side given as a bare URL")
    fleet_arg(p)
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(handler=cmd_diff)

    p = sub.add_parser("restore", help="write a backup's differing parameters into a device (guarded, read back)")
    p.add_argument("file", metavar="FILE", help="a backup written by `starterbus backup`")
    device_args(p)
    p.add_argument("--accept-uncertain", action="store_true", help="acknowledge codes or scales the manual lacks")
    p.add_argument("--yes", "-y", action="store_true", help="do it without asking (required without a terminal)")
    p.add_argument("--dry-run", action="store_true", help="show the diff and the exact frames; send nothing")
    p.add_argument("--audit-log", metavar="PATH", default=None, help="the JSON-lines audit log (see `write`)")
    p.set_defaults(handler=cmd_restore)

    ops_history_cmds.add_parsers(sub, wanted)


def cmd_backup(args: argparse.Namespace) -> int:
    to_stdout = args.output == "-"
    if to_stdout and args.json:
        raise ConfigurationError("-o - and --json both write to standard output: give one of them")
    if not to_stdout:
        check_target(args.output, force=args.force, what="backup file")  # before the device is opened
    with open_device(args.url, args.model) as device:
        taken = backups.take_backup(device)
    if to_stdout:
        sys.stdout.write(backups.dumps(taken, device.profile))
        print(f"{len(taken.parameters)} parameters of {device.describe()} written to stdout", file=sys.stderr)
        return 0
    backups.save(taken, device.profile, args.output, replace=args.force)
    if args.json:
        emit_json({"device": args.url, "model": taken.model, "file": args.output, "parameters": len(taken.parameters)})
    else:
        print(f"{len(taken.parameters)} parameters of {device.describe()} saved to {args.output}")
    return 0


def cmd_diff(args: argparse.Namespace) -> int:
    try:
        a, b = load_pair(args.a, args.b, args.model, lookup=lambda name: _named(name, args.fleet))
        rows = compare(a, b)
    except (StarterbusError, OSError) as exc:
        if args.json:
            emit_json({"error": str(exc)})
        else:
            print(f"starterbus: error: {exc}", file=sys.stderr)
        return 2
    note = ""
    if a.profile.name != b.profile.name:
        note = f"different models: {a.profile.name} and {b.profile.name}"
    if args.json:
        emit_json(
            {
                "a": a.source,
                "b": b.source,
                "models": [a.profile.name, b.profile.name],
                "equal": not rows,
                "differences": [r.as_json() for r in rows],
                "not_compared": sorted(set(a.missing) | set(b.missing)),
            }
        )
    elif rows:
        table(["key", "address", "parameter", "A", "B"], [[r.key, r.address, r.label, r.a, r.b] for r in rows])
        print(f"{len(rows)} differ (A = {a.source}, B = {b.source}){'; ' + note if note else ''}")
    else:
        print(f"equal: {a.source} and {b.source}")
    if not args.json and (a.missing or b.missing):
        print(f"not compared (the profile prints no default): {', '.join(sorted({*a.missing, *b.missing}))}")
    return 1 if rows else 0


def _named(name: str, fleet: str | None) -> tuple[str, str]:
    from starterbus.cli.target import lookup

    device = lookup(name, fleet, neither="an existing backup file, a device URL (URL@MODEL) or `defaults[@MODEL]`")
    return device.url, device.model


def cmd_restore(args: argparse.Namespace) -> int:
    taken, _ = backups.load(args.file)
    device = open_device(
        args.url, args.model, audit=AuditLog(args.audit_log), actor=f"cli:{_user()}", confirm=prompt_hook(args)
    )
    with device:
        plan = restores.plan(taken, device, accept_uncertain=args.accept_uncertain)
        if not args.json:
            _show_plan(plan)
        if args.dry_run:
            show_dry_run(args, write_previews(device, [(p.point, p.raw) for p in plan.planned]), **_plan_json(plan))
            return 0
        try:
            outcomes = restores.execute(plan, device, accept_uncertain=args.accept_uncertain)
        except GuardedOperationError:
            _show_outcomes(args, device, device.guard.last_outcomes, to=sys.stderr)
            raise
        except StarterbusError:
            if device.guard.last_outcomes:
                _show_outcomes(args, device, device.guard.last_outcomes, to=sys.stderr)
            raise
    if args.json:
        emit_json({"device": args.url, **_plan_json(plan), "written": [o.as_json() for o in outcomes]})
    elif outcomes:
        _show_outcomes(args, device, outcomes)
        print(f"restored {len({o.key for o in outcomes})} parameters of {args.file} into {device.describe()}")
    else:
        print(f"nothing to write: {device.describe()} already holds {args.file}")
    return 0


def _show_plan(plan: restores.RestorePlan) -> None:
    if plan.rows:
        table(["key", "parameter", "backup", "device now"], [[r.key, r.label, r.a, r.b] for r in plan.rows])
    for key, why in plan.skipped:
        print(f"not restored: {key}: {why}")


def _plan_json(plan: restores.RestorePlan) -> dict[str, object]:
    return {
        "differences": [r.as_json() for r in plan.rows],
        "not_restored": [{"key": k, "reason": why} for k, why in plan.skipped],
    }
