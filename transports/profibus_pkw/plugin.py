"""Entry point of the ``profibus-pkw`` transport: URL -> transport, simulator options, decoder options."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from starterbus.core import (
    Annotation,
    Capability,
    ConfigurationError,
    DeviceUrl,
    Kind,
    PluginOption,
    Profile,
    RunningSimulator,
    SimulatedStarter,
    Transport,
    TransportPlugin,
    parse_host_port,
    resolve_options,
)
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, Direction, Part, Ppo
from starterbus.transports.profibus_pkw.decoder import annotate_hex
from starterbus.transports.profibus_pkw.settings import ProfibusSettings, profibus_settings
from starterbus.transports.profibus_pkw.transport import ProfibusPkwTransport, ProfibusSimTransport
from starterbus.transports.profibus_pkw.url import LinkSettings


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
        settings = LinkSettings.from_url(url, profile)
        kind = ProfibusSimTransport if settings.variant == "sim" else ProfibusPkwTransport
        return kind(url, profile, settings)

    def parse_settings(self, settings: Mapping[str, Any]) -> ProfibusSettings:
        """``[transports.profibus-pkw]``: ppo, stations, errors (parsed by the loader), refusals."""
        return ProfibusSettings.parse(settings)

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        self.parse_settings(settings)

    # -- simulator ---------------------------------------------------------------------------------------

    simulator_options = (
        PluginOption(
            "gateway", flag="--profibus-gateway", metavar="HOST:PORT",
            help="serve the starters as DP stations behind a simulated Modbus TCP gateway",
        ),
        PluginOption("ppo", flag="--ppo", type=int, choices=(1, 3), default=1, help="PPO type of the DP slaves"),
        PluginOption(
            "out", flag="--profibus-out", type=int, default=0, metavar="REG",
            help="holding register of station 1's output words",
        ),
        PluginOption(
            "in", flag="--profibus-in", type=int, default=0, metavar="REG",
            help="register of station 1's input words (FC03 and FC04 both read them)",
        ),
        PluginOption(
            "cycle", flag="--profibus-cycle", type=float, default=0.005, metavar="S",
            help="the gateway's DP cycle in seconds",
        ),
        PluginOption(
            "latency", flag="--profibus-latency", type=int, default=0, metavar="N",
            help="DP cycles before a slave's PKW response shows",
        ),
    )  # fmt: skip

    def start_simulator(
        self, options: Mapping[str, object], starters: Mapping[int, SimulatedStarter]
    ) -> list[RunningSimulator]:
        values = resolve_options(self.simulator_options, options, f"{PROTOCOL} simulator")
        target = values.text("gateway")
        if not target:
            return []
        from starterbus.transports.profibus_pkw.simulator import ProfibusGatewaySimulator

        for station, starter in starters.items():
            profile = starter.profile
            if not profile.supports(PROTOCOL):
                raise ConfigurationError(f"{profile.display_name} has no Profibus interface")
            limits = profibus_settings(profile).stations
            if not limits[0] <= station <= limits[1]:
                raise ConfigurationError(
                    f"--unit {station}: {profile.display_name} DP stations are {limits[0]}..{limits[1]}"
                )
        host, port = parse_host_port(target, option="--profibus-gateway")
        sim = ProfibusGatewaySimulator(
            list(starters.values()),
            host,
            port,
            Ppo(values.integer("ppo") or 1),
            out=values.integer("out") or 0,
            inp=values.integer("in") or 0,
            cycle=values.number("cycle") or 0.005,
            latency=values.integer("latency") or 0,
            stations=list(starters),
        )
        return [sim.start()]

    # -- decoder ------------------------------------------------------------------------------------------

    decoder_options = (
        PluginOption("ppo", flag="--ppo", type=int, choices=(1, 3), default=1, help="telegram type"),
        PluginOption(
            "direction", flag="--direction", choices=("out", "in"), required=True,
            help="out = master -> slave (IND/PWE/STW), in = slave -> master (IND/PWE/ZSW/ACT)",
        ),
        PluginOption(
            "part", flag="--part", choices=("all", "pkw", "pzd"), default="all",
            help="the bytes are a whole telegram, or only its PKW or PZD half (the manual's examples)",
        ),
        PluginOption(
            "kind", flag="--kind", choices=("parameter", "measurement"),
            help="what a response's INDL addresses (a response does not say; default: show both)",
        ),
    )  # fmt: skip

    def decode(self, frames: Sequence[str], options: Mapping[str, object], profile: Profile | None) -> list[Annotation]:
        values = resolve_options(self.decoder_options, options, f"{PROTOCOL} decoder")
        ppo = Ppo(values.integer("ppo") or 1)
        part = Part(values.text("part") or "all")
        if part is Part.PKW and not ppo.has_pkw:
            raise ConfigurationError("--part pkw needs --ppo 1 (PPO3 has no PKW area)")
        kind_text = values.text("kind")
        kind = Kind(kind_text) if kind_text else None
        return annotate_hex(frames, ppo, Direction(values.text("direction") or ""), part, profile, kind)


PLUGIN = ProfibusPkwPlugin()
