"""Entry point of the ``starterbus`` command: parser and dispatch; each command lives in its own module."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from collections.abc import Callable, Sequence

from starterbus.cli import crosscheck, decode, demo, device_cmds, info, poll, simulate
from starterbus.core.errors import StarterbusError

Handler = Callable[[argparse.Namespace], int]


def _json_flag(p: argparse.ArgumentParser) -> None:
    p.add_argument("--json", action="store_true", help="machine-readable output")


def _device_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("url", metavar="URL", help="device URL, e.g. modbus-rtu:///dev/ttyUSB0?unit=2&baudrate=9600")
    p.add_argument("--model", required=True, help="device model (jjr5000, ssd1, jjr8000) or a profile .toml")
    _json_flag(p)


def _guard_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--yes", "-y", action="store_true", help="do it without asking (required without a terminal)")
    p.add_argument("--dry-run", action="store_true", help="print the exact frames that would be sent; send nothing")
    p.add_argument(
        "--audit-log",
        metavar="PATH",
        default=None,
        help="append to this JSON-lines audit log (default $STARTERBUS_AUDIT_LOG or "
        "~/.local/state/starterbus/audit.jsonl)",
    )


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="starterbus",
        description="Monitor, configure and control soft starters over Modbus RTU, Profibus DP and DeviceNet.",
    )
    sub = parser.add_subparsers(dest="command_name", required=True, metavar="COMMAND")

    p = sub.add_parser("models", help="list installed device models")
    _json_flag(p)
    p.set_defaults(handler=info.cmd_models)

    p = sub.add_parser("params", help="list a model's parameters and measurements")
    p.add_argument("model", metavar="MODEL")
    _json_flag(p)
    p.set_defaults(handler=info.cmd_params)

    p = sub.add_parser("transports", help="list installed transport plugins, capabilities and load errors")
    _json_flag(p)
    p.set_defaults(handler=info.cmd_transports)

    p = sub.add_parser("read", help="read parameters/measurements (all measurements if no KEY)")
    _device_args(p)
    p.add_argument("keys", nargs="*", metavar="KEY", help="key or manual address (motor_rated_current, 0x0100, p7, m3)")
    p.set_defaults(handler=device_cmds.cmd_read, rest_into="keys")

    p = sub.add_parser("write", help="write parameters (engineering units or enum labels; validated first)")
    _device_args(p)
    p.add_argument("assignments", nargs="+", metavar="KEY=VALUE")
    p.add_argument(
        "--accept-uncertain",
        action="store_true",
        help="acknowledge writing a code or scale the manual does not print (see `params`: certainty)",
    )
    _guard_args(p)
    p.set_defaults(handler=device_cmds.cmd_write)

    p = sub.add_parser("status", help="read the decoded status")
    _device_args(p)
    p.set_defaults(handler=device_cmds.cmd_status)

    for name, help_text in (
        ("start", "start the motor"),
        ("stop", "soft-stop the motor"),
        ("reset", "fault reset"),
    ):
        p = sub.add_parser(name, help=help_text)
        _device_args(p)
        p.add_argument("--show-status", action="store_true", help="show the whole status reached")
        p.add_argument(
            "--wait",
            type=float,
            default=5.0,
            metavar="S",
            help="seconds to wait for the state the command asks for (default 5); not reached: exit 1",
        )
        if name == "start":
            p.add_argument(
                "--hold",
                action="store_true",
                help="keep the connection (and the run command) with a live status until Ctrl-C, then soft-stop",
            )
            p.add_argument("--hold-for", type=float, metavar="S", help="as --hold, but soft-stop after S seconds")
        else:
            p.set_defaults(hold=False, hold_for=None)
        _guard_args(p)
        p.set_defaults(handler=device_cmds.cmd_command, command=name)

    wants = argv[0] if argv else ""
    p = sub.add_parser("simulate", help="serve simulated soft starters behind protocol front ends")
    if wants == "simulate":  # loading every plugin only when this command is used
        simulate.add_arguments(p)
    p.set_defaults(handler=simulate.cmd_simulate)

    p = sub.add_parser("decode", help="annotate frames/telegrams of a protocol")
    if wants == "decode":
        decode.add_subparsers(p)
    p.set_defaults(handler=decode.cmd_decode)

    p = sub.add_parser("poll", help="poll a fleet file: live table, JSON lines, CSV log")
    poll.add_arguments(p)
    p.set_defaults(handler=poll.cmd_poll)

    p = sub.add_parser("demo", help="the main job on a simulated mixed fleet (no hardware needed)")
    demo.add_arguments(p)
    p.set_defaults(handler=demo.cmd_demo)

    p = sub.add_parser("crosscheck", help="read one device through several URLs and compare")
    crosscheck.add_arguments(p)
    p.set_defaults(handler=crosscheck.cmd_crosscheck)

    for extend in _EXTENSIONS:
        extend(sub, wants)
    return parser


#: later commands (fleet polling, demo, crosscheck, identify) register here: fn(subparsers, wanted_command)
_EXTENSIONS: list[Callable[[argparse._SubParsersAction[argparse.ArgumentParser], str], None]] = []

from starterbus.cli import identify  # noqa: E402  (DeviceNet issue: `starterbus identify URL`)

_EXTENSIONS.append(identify.add_parser)
_EXTENSIONS.append(__import__("starterbus.cli.serve", fromlist=["add_parser"]).add_parser)  # issue 15: serve


def _quiet_libraries() -> None:
    """pymodbus logs connection failures itself; starterbus reports them as one typed error, once."""
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


def main(argv: Sequence[str] | None = None) -> int:
    args_list = list(sys.argv[1:] if argv is None else argv)
    _quiet_libraries()
    try:
        parser = build_parser(args_list)
        args, extra = parser.parse_known_args(args_list)
        rest = getattr(args, "rest_into", None)
        if extra and rest is not None and not any(x.startswith("-") for x in extra):
            # argparse gives a trailing "*" positional nothing when an option sits between it and the
            # first positional (`read URL --model M KEY...`): the keys come back here
            getattr(args, rest).extend(extra)
        elif extra:
            parser.error(f"unrecognized arguments: {' '.join(extra)}")
        handler: Handler = args.handler
        return handler(args)
    except StarterbusError as exc:
        print(f"starterbus: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:
        print(f"starterbus: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # output piped into `head` and the like
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141


if __name__ == "__main__":
    sys.exit(main())
