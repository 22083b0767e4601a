"""Entry point of the ``profibus-pkw`` transport: URL -> transport, simulator options, decoder options."""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any

from starterbus.core import settings_check as check
from starterbus.core.errors import ConfigurationError, Refusal
from starterbus.core.model import Kind
from starterbus.core.profile import Profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.transport import Annotation, Capability, RunningSimulator, Transport, TransportPlugin
from starterbus.core.url import DeviceUrl
from starterbus.transports.profibus_pkw.decoder import annotate_hex
from starterbus.transports.profibus_pkw.slave import UNSUPPORTED_TASK
from starterbus.transports.profibus_pkw.telegram import PROTOCOL, Direction, Part, Ppo
from starterbus.transports.profibus_pkw.transport import LinkSettings, ProfibusPkwTransport


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 0xFFFF:
        raise ConfigurationError(f"--profibus-gateway {text!r}: expected HOST:PORT (PORT 0 = any free port)")
    return host or "127.0.0.1", int(port)


class ProfibusPkwPlugin(TransportPlugin):
    name = PROTOCOL
    requires_point_addresses = True
    address_parameter = "station"
    summary = (
        "Profibus DP vendor PKW (parameters) + PZD (control/status), PPO1/PPO3, via simulation or Modbus TCP gateway"
    )
    capabilities = frozenset(Capability)
    url_forms = (
        "profibus-pkw+sim://[NAME]?ppo=1|3&cycle=0.01",
        "profibus-pkw+gateway://HOST:PORT?ppo=1|3&out=0&in=0&unit=1&cycle=0.01[&in_fc=3|4]",
    )

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        return ProfibusPkwTransport(url, profile, LinkSettings.from_url(url, profile))

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        """The keys this transport reads from ``[transports.profibus-pkw]`` (``errors`` is parsed by the loader)."""
        check.known_keys(settings, ("ppo", "stations", "errors", "refusals"))
        check.int_list(settings, "ppo", 1, 3, choices=(1, 3))
        check.int_range(settings, "stations", 0, 127)
        names = {r.name.lower() for r in Refusal} | {UNSUPPORTED_TASK}
        for name, value in check.sub_table(settings, "refusals").items():
            if name not in names:
                raise ConfigurationError(f"refusals.{name}: unknown refusal (known: {', '.join(sorted(names))})")
            if value != "response 2" and (
                isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 0xFFFF
            ):
                raise ConfigurationError(f"refusals.{name}: {value!r} is not an error number or 'response 2'")

    # -- simulator ---------------------------------------------------------------------------------------

    def add_simulator_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--profibus-gateway",
            metavar="HOST:PORT",
            default=None,
            help="serve the starters as DP stations behind a simulated Modbus TCP gateway",
        )
        parser.add_argument("--ppo", type=int, choices=(1, 3), default=1, help="PPO type of the DP slaves (default 1)")
        parser.add_argument(
            "--profibus-out",
            type=int,
            default=0,
            metavar="REG",
            help="holding register of station 1's output words (default 0)",
        )
        parser.add_argument(
            "--profibus-in",
            type=int,
            default=0,
            metavar="REG",
            help="register of station 1's input words (default 0; FC03 and FC04 both read them)",
        )
        parser.add_argument(
            "--profibus-cycle",
            type=float,
            default=0.005,
            metavar="S",
            help="the gateway's DP cycle in seconds (default 0.005)",
        )
        parser.add_argument(
            "--profibus-latency",
            type=int,
            default=0,
            metavar="N",
            help="DP cycles before a slave's PKW response shows (default 0)",
        )

    def start_simulators(
        self, args: argparse.Namespace, profile: Profile, starters: Sequence[object]
    ) -> list[RunningSimulator]:
        target = getattr(args, "profibus_gateway", None)
        if not target:
            return []
        from starterbus.transports.profibus_pkw.gateway_sim import ProfibusGatewaySimulator

        if not profile.supports(PROTOCOL):
            raise ConfigurationError(f"{profile.display_name} has no Profibus interface")
        host, port = _host_port(target)
        sims = [s for s in starters if isinstance(s, SimulatedStarter)]
        stations = list(getattr(args, "unit", None) or range(1, len(sims) + 1))
        limits = profile.transport_settings(PROTOCOL).get("stations")
        for station in stations:
            if limits and not limits[0] <= station <= limits[1]:
                raise ConfigurationError(
                    f"--unit {station}: {profile.display_name} DP stations are {limits[0]}..{limits[1]}"
                )
        sim = ProfibusGatewaySimulator(
            sims,
            host,
            port,
            Ppo(args.ppo),
            out=args.profibus_out,
            inp=args.profibus_in,
            cycle=args.profibus_cycle,
            latency=args.profibus_latency,
            stations=stations,
        )
        return [sim.start()]

    # -- decoder ------------------------------------------------------------------------------------------

    def add_decode_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--ppo", type=int, choices=(1, 3), default=1, help="telegram type (default 1)")
        parser.add_argument(
            "--direction",
            choices=("out", "in"),
            required=True,
            help="out = master -> slave (IND/PWE/STW), in = slave -> master (IND/PWE/ZSW/ACT)",
        )
        parser.add_argument(
            "--part",
            choices=("all", "pkw", "pzd"),
            default="all",
            help="the bytes are a whole telegram, or only its PKW or PZD half (the manual's examples)",
        )
        parser.add_argument(
            "--kind",
            choices=("parameter", "measurement"),
            default=None,
            help="what a response's INDL addresses (a response does not say; default: show both)",
        )

    def decode(self, args: argparse.Namespace, profile: Profile | None) -> list[Annotation]:
        ppo = Ppo(args.ppo)
        part = Part(args.part)
        if part is Part.PKW and not ppo.has_pkw:
            raise ConfigurationError("--part pkw needs --ppo 1 (PPO3 has no PKW area)")
        kind = Kind(args.kind) if args.kind else None
        return annotate_hex(args.data, ppo, Direction(args.direction), part, profile, kind)


PLUGIN = ProfibusPkwPlugin()
