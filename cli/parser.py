"""The ``starterbus`` command line: every command's name and help, and the options of the one asked for.

Start-up is kept short: a command's module (and with it the core, the plugins and the profiles) is imported
only when that command runs, and its options are built only when it is the command asked for (``--help``
lists the commands without importing any of them). Commands are named here by their module in
``starterbus.cli``; :mod:`starterbus.cli.main` runs the one asked for.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Sequence

from starterbus.cli.arguments import device_args, guard_args, json_flag

Handler = Callable[[argparse.Namespace], int]


def command_module(name: str) -> object:
    """The module of a command in ``starterbus.cli``, imported now."""
    return importlib.import_module(f"starterbus.cli.{name}")


def _handler(name: str, function: str) -> str:
    """A handler named ``module:function`` in ``starterbus.cli``, imported when the command runs."""
    return f"{name}:{function}"


def _setup(p: argparse.ArgumentParser, wanted: bool, name: str, function: str) -> None:
    """Add a command's own options (``module.function(p)``), only when it is the command asked for."""
    if wanted:
        getattr(command_module(name), function)(p)


def build_parser(argv: Sequence[str]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="starterbus",
        description="Monitor, configure and control soft starters over Modbus RTU, Profibus DP and DeviceNet.",
    )
    parser.add_argument("--version", action=_Version, nargs=0, help="print the version and exit")
    parser.add_argument(
        "-v", "--verbose", dest="log_level", action="count", default=0,
        help="before the command: the libraries' log (pymodbus, asyncua, canopen, paho, can) on stderr; -vv: debug",
    )  # fmt: skip
    sub = parser.add_subparsers(dest="command_name", required=True, metavar="COMMAND")

    p = sub.add_parser("models", help="list installed device models")
    json_flag(p)
    p.set_defaults(handler=_handler("info", "cmd_models"))

    p = sub.add_parser("params", help="list a model's parameters and measurements")
    p.add_argument("model", metavar="MODEL")
    json_flag(p)
    p.set_defaults(handler=_handler("info", "cmd_params"))

    p = sub.add_parser("transports", help="list installed transport plugins, capabilities and load errors")
    json_flag(p)
    p.set_defaults(handler=_handler("info", "cmd_transports"))

    p = sub.add_parser("read", help="read parameters/measurements (all measurements if no KEY)")
    device_args(p)
    p.add_argument("keys", nargs="*", metavar="KEY", help="key or manual address (motor_rated_current, 0x0100, p7, m3)")
    p.add_argument(
        "--raw", action="store_true", help="KEY is ADDRESS:COUNT: holding registers as they are (0x0100:4; Modbus only)"
    )
    p.set_defaults(handler=_handler("device_cmds", "cmd_read"), rest_into="keys")

    p = sub.add_parser("write", help="write parameters (engineering units or enum labels; validated first)")
    device_args(p)
    p.add_argument("assignments", nargs="+", metavar="KEY=VALUE")
    p.add_argument(
        "--accept-uncertain",
        action="store_true",
        help="acknowledge writing a code or scale the manual does not print (see `params`: certainty)",
    )
    p.add_argument(
        "--raw",
        action="store_true",
        help="KEY=VALUE is ADDRESS=VALUE into a holding register, bypassing the model's checks (Modbus only)",
    )
    guard_args(p)
    p.set_defaults(handler=_handler("device_cmds", "cmd_write"))

    p = sub.add_parser("status", help="read the decoded status")
    device_args(p)
    p.set_defaults(handler=_handler("device_cmds", "cmd_status"))

    for name, help_text in (
        ("start", "start the motor"),
        ("stop", "soft-stop the motor"),
        ("reset", "fault reset"),
    ):
        p = sub.add_parser(name, help=help_text)
        device_args(p)
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
        p.add_argument(
            "--force",
            action="store_true",
            help="send it even though the starter is controlled from elsewhere (keypad, terminals, another master)",
        )
        guard_args(p)
        p.set_defaults(handler=_handler("device_cmds", "cmd_command"), command=name)

    wants = next((arg for arg in argv if not arg.startswith("-")), "")  # global options (-v) take no value
    for name, module, setup, help_text in (
        ("simulate", "simulate", "add_arguments", "serve simulated soft starters behind protocol front ends"),
        ("decode", "decode", "add_subparsers", "annotate frames/telegrams of a protocol"),
        ("poll", "poll", "add_arguments", "poll a fleet file: live table, JSON lines, CSV log"),
        ("demo", "demo", "add_arguments", "the main job on a simulated mixed fleet (no hardware needed)"),
        ("crosscheck", "crosscheck", "add_arguments", "read one device through several URLs and compare"),
        ("scan", "scan", "add_arguments", "find the devices on a Modbus RTU line, gateway or DeviceNet bus"),
    ):
        p = sub.add_parser(name, help=help_text)
        _setup(p, wants == name, module, setup)
        p.set_defaults(handler=_handler(module, f"cmd_{name}"))

    for extend in _EXTENSIONS:
        extend(sub, wants)
    from starterbus.cli.examples import attach

    attach(sub)
    return parser


def _identify(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
    """``starterbus identify URL`` (DeviceNet issue); its module is imported only when asked for."""
    if wants == "identify":
        command_module("identify").add_parser(sub, wants)  # type: ignore[attr-defined]
    else:
        sub.add_parser("identify", help="read the device's identity (DeviceNet identity object)")


def _lazy(name: str, help_text: str) -> Callable[[argparse._SubParsersAction[argparse.ArgumentParser], str], None]:
    """A command whose module (with its ``add_parser``) is imported only when it is the command asked for."""

    def extend(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
        if wants == name:
            command_module(name).add_parser(sub, wants)  # type: ignore[attr-defined]
        else:
            sub.add_parser(name, help=help_text)

    return extend


def _lazy_group(
    module: str, commands: dict[str, str]
) -> Callable[[argparse._SubParsersAction[argparse.ArgumentParser], str], None]:
    """Several commands that one module's ``add_parser`` defines, imported only when one of them is asked for."""

    def extend(sub: argparse._SubParsersAction[argparse.ArgumentParser], wants: str) -> None:
        if wants in commands:
            command_module(module).add_parser(sub, wants)  # type: ignore[attr-defined]
            return
        for name, help_text in commands.items():
            sub.add_parser(name, help=help_text)

    return extend


class _Version(argparse.Action):
    """``--version``, looked up only when asked (importlib.metadata is slow to import)."""

    def __call__(self, parser: argparse.ArgumentParser, *_: object) -> None:
        from importlib.metadata import PackageNotFoundError, version

        try:
            text = version("starterbus")
        except PackageNotFoundError:
            text = "unknown (not installed)"
        print(f"starterbus {text}")
        parser.exit(0)


#: later commands register here: fn(subparsers, wanted_command); build a command's options only when wanted
_EXTENSIONS: list[Callable[[argparse._SubParsersAction[argparse.ArgumentParser], str], None]] = [
    _identify,
    _lazy("watch", "watch one device: status and chosen points, refreshed in place"),
    _lazy("validate", "check fleet files without opening any port or bus"),
    _lazy("completion", "print a shell completion script (bash, zsh, fish)"),
    _lazy_group("serve", {"serve": "the fleet on an MQTT broker as a Sparkplug B edge node, Prometheus metrics"}),
    _lazy_group(
        "ops_cmds",
        {
            "backup": "save every readable parameter of a device to an editable TOML file",
            "diff": "compare two parameter sets (backup file, URL@MODEL, defaults); exit 1 if they differ",
            "restore": "write a backup's differing parameters into a device (guarded, read back)",
            "history": "query a history database written by `poll --record`",
            "record": "record a start: status and currents at the line's fastest rate, CSV + PNG plot",
            "plot": "plot a start or a fault from a history database",
        },
    ),
    _lazy_group(
        "opcua_cmd",
        {
            "opcua": "serve a fleet over OPC UA (methods and writes through the guarded path)",
            "opcua-user": "add or change a user of the OPC UA server (password from a prompt or stdin)",
            "opcua-trust": "list the OPC UA client certificates refused (PKI/rejected), or trust one",
        },
    ),
]


def parse_arguments(argv: Sequence[str]) -> argparse.Namespace:
    """The command line parsed as ``main`` parses it (a bad one: usage and SystemExit 2, as argparse does)."""
    args_list = list(argv)
    parser = build_parser(args_list)
    args, extra = parser.parse_known_args(args_list)
    rest = getattr(args, "rest_into", None)
    if extra and rest is not None and not any(x.startswith("-") for x in extra):
        # argparse gives a trailing "*" positional nothing when an option sits between it and the
        # first positional (`read URL --model M KEY...`): the keys come back here
        getattr(args, rest).extend(extra)
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return args
