"""``starterbus simulate``: serve simulated starters behind one or more protocol front ends."""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time

from starterbus.cli.output import emit_json_line
from starterbus.cli.plugin_args import ARGPARSE, OptionMapper, declared, plugin_order, warn
from starterbus.cli.sim_script import parse_script
from starterbus.core.errors import ConfigurationError, PluginError, StarterbusError
from starterbus.core.profile import Profile
from starterbus.core.registry import get_profile, transports
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.textinput import read_text_file
from starterbus.core.transport import RunningSimulator


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Serve simulated soft starters behind protocol front ends, for rehearsals without hardware. "
        "Several models may share one line: --unit 2:jjr5000 --unit 3:ssd1."
    )
    parser.epilog = "script lines: AT UNIT ACTION [ARG], e.g. '5 2 fault 6', '9 2 clear', '12 3 start', '20 3 stop'"
    own = [
        parser.add_argument(
            "--model", default=None, help="device model for units given without one (jjr5000, ssd1, ...)"
        ),
        parser.add_argument(
            "--unit",
            action="append",
            default=None,
            metavar="ADDR[:MODEL]",
            help="address of a simulated starter (Modbus unit id, DP station), optionally with its own model; "
            "repeat for several on one line (default 1)",
        ),
        parser.add_argument("--load", type=float, default=0.8, help="running current as a fraction of rated current"),
        parser.add_argument("--duration", type=float, default=None, help="stop after this many seconds"),
        parser.add_argument(
            "--fault", action="append", default=[], metavar="UNIT:CODE", help="start with a fault active"
        ),
        parser.add_argument("--script", metavar="FILE", help="timed events: AT UNIT fault CODE|clear|start|stop"),
        parser.add_argument("--json", action="store_true", help="print where each front end listens as JSON"),
    ]
    mapper = OptionMapper()
    mapper.hold(own)
    mapper.taken_flags.update({"-h": "the command", "--help": "the command"})
    mapper.taken_dests.update({"help", "handler", "command_name", "plugin_args"})
    for entry in plugin_order(transports.load_all()):
        plugin = entry.loaded
        if plugin is None:
            warn(f"transport plugin {entry.name!r} left out: {entry.error}")
            continue

        def group(name: str = plugin.name) -> argparse._ActionsContainer:
            return parser.add_argument_group(f"{name} front end")

        try:
            if plugin.uses_argparse_simulator:
                mapper.add_argparse(plugin, plugin.add_simulator_arguments, group)
            else:
                options = declared(plugin, "simulator_options")
                if options:
                    mapper.add_typed(plugin, options, group)
        except Exception as exc:  # a declaration that raises: this plugin only
            warn(f"transport plugin {plugin.name!r} left out: its options cannot be declared ({exc})")
    parser.set_defaults(plugin_args=mapper)


def _units(args: argparse.Namespace) -> list[tuple[int, Profile]]:
    units: list[tuple[int, Profile]] = []
    for text in args.unit or ["1"]:
        addr, _, model = str(text).partition(":")
        if not addr.strip().isdigit():
            raise ConfigurationError(f"--unit {text}: give ADDR or ADDR:MODEL (e.g. 2 or 2:ssd1)")
        model = model.strip() or args.model
        if not model:
            raise ConfigurationError(f"--unit {text}: no model (give --model or ADDR:MODEL)")
        units.append((int(addr), get_profile(model)))
    addresses = [a for a, _ in units]
    if len(set(addresses)) != len(addresses):
        raise ConfigurationError(f"--unit given twice with the same address: {addresses}")
    return units


def _start(args: argparse.Namespace, profile: Profile, starters: dict[int, SimulatedStarter]) -> list[RunningSimulator]:
    """Every accepted plugin's front ends the command line asks for (typed call, or the deprecated hook)."""
    mapper: OptionMapper = args.plugin_args
    running: list[RunningSimulator] = []
    try:
        for entry in plugin_order(transports.entries()):
            plugin = entry.loaded
            if plugin is None or plugin.name not in mapper.accepted:
                continue
            try:
                if mapper.accepted[plugin.name][0] == ARGPARSE:
                    running.extend(plugin.start_simulators(args, profile, list(starters.values())))
                else:
                    given = mapper.given(args, plugin.name)
                    if given:
                        running.extend(plugin.start_simulator(given, starters))
            except StarterbusError:
                raise
            except Exception as exc:
                raise PluginError(
                    f"transport plugin {plugin.name!r} failed to start its front end: {type(exc).__name__}: {exc}"
                ) from exc
    except BaseException:
        for sim in running:
            sim.close()
        raise
    return running


def cmd_simulate(args: argparse.Namespace) -> int:
    units = _units(args)
    profile = units[0][1]
    starters = {addr: SimulatedStarter(p, load=args.load) for addr, p in units}
    events = []
    if args.script:
        events = parse_script(read_text_file(args.script, "script"), args.script, set(starters))
    for spec in args.fault:
        unit, _, code = spec.partition(":")
        if not unit.isdigit() or not code.isdigit() or int(unit) not in starters:
            raise ConfigurationError(f"--fault {spec}: give UNIT:CODE for a simulated unit")
        starters[int(unit)].inject_fault(int(code))
    args.unit = list(starters)
    running: list[RunningSimulator] = []
    interrupted = False
    try:
        running.extend(_start(args, profile, starters))
        if not running:
            raise ConfigurationError("no front end asked for: give at least one of the protocol options (see --help)")
        if args.json:
            listing = {
                "units": {str(a): p.name for a, p in units},
                "front_ends": [{"listen": sim.describe(), "urls": sim.client_urls()} for sim in running],
            }
            emit_json_line(listing)
        else:
            for sim in running:
                for line in sim.describe():
                    print(line, flush=True)
        stop = threading.Event()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: stop.set())
        began = time.monotonic()
        deadline = None if args.duration is None else began + args.duration
        try:
            while not stop.is_set():
                now = time.monotonic()
                while events and events[0].at <= now - began:
                    print(f"script: {events.pop(0).apply(starters)}", file=sys.stderr, flush=True)
                waits = [0.5]
                if deadline is not None:
                    waits.append(deadline - now)
                if events:
                    waits.append(began + events[0].at - now)
                if deadline is not None and now >= deadline:
                    break
                stop.wait(max(0.0, min(waits)))
        except KeyboardInterrupt:
            interrupted = True
    finally:
        for sim in running:
            sim.close()
    return 130 if interrupted else 0
