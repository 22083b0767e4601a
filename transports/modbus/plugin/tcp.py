"""Entry point of the ``modbus-tcp`` transport: Modbus TCP (MBAP) to a gateway or a TCP device."""

from __future__ import annotations

from collections.abc import Mapping

from starterbus.core import (
    ALL_CAPABILITIES,
    ConfigurationError,
    DeviceUrl,
    PluginOption,
    Profile,
    RunningSimulator,
    SimulatedStarter,
    Transport,
    TransportPlugin,
    parse_host_port,
    resolve_options,
)
from starterbus.spaces.modbus import SPACE_NAME, ModbusSettings
from starterbus.transports.modbus.transport.tcp import NAME, ModbusTcpConfig, ModbusTcpTransport


class ModbusTcpPlugin(TransportPlugin):
    name = NAME
    address_space = SPACE_NAME
    address_parameter = "unit"
    summary = "Modbus TCP (MBAP, FC03/FC06) to a Modbus TCP/RTU gateway or a Modbus TCP device"
    capabilities = ALL_CAPABILITIES
    url_forms = ("modbus-tcp://HOST:PORT?unit=2&timeout=1&retries=2&outstanding=1",)

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        return ModbusTcpTransport(url, profile, ModbusTcpConfig.from_tcp_url(url, profile))

    simulator_options = (
        PluginOption(
            "address", flag="--modbus-tcp", metavar="HOST:PORT",
            help="serve the units as a Modbus TCP gateway (port 0: a free one, printed)",
        ),
    )  # fmt: skip

    def start_simulator(
        self, options: Mapping[str, object], starters: Mapping[int, SimulatedStarter]
    ) -> list[RunningSimulator]:
        from starterbus.transports.modbus.simulator.tcp import ModbusTcpSimulator

        values = resolve_options(self.simulator_options, options, f"{NAME} simulator")
        address = values.text("address")
        if address is None:
            return []
        for unit, starter in starters.items():
            profile = starter.profile
            if not profile.supports(NAME):
                raise ConfigurationError(profile.no_interface(NAME))
            lo, hi = ModbusSettings.of(profile).unit_ids
            if not max(1, lo) <= unit <= hi:
                raise ConfigurationError(
                    f"--unit {unit}: {profile.display_name} Modbus slave addresses are {max(1, lo)}..{hi}"
                )
        host, port = parse_host_port(address, default_host="0.0.0.0", option="--modbus-tcp")
        return [ModbusTcpSimulator(dict(starters), host, port).start()]


PLUGIN = ModbusTcpPlugin()
