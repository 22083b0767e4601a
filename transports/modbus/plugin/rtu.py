"""Entry point of the ``modbus-rtu`` transport (and its ``+tcp``, ``+rfc2217`` and ``+socket`` variants)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from starterbus.core import (
    ALL_CAPABILITIES,
    Annotation,
    ConfigurationError,
    DeviceUrl,
    PluginOption,
    Profile,
    RunningSimulator,
    SimulatedStarter,
    Transport,
    TransportPlugin,
    parse_hex,
    parse_host_port,
    resolve_options,
)
from starterbus.spaces.modbus import SPACE_NAME, ModbusSettings
from starterbus.transports.modbus.decoder import annotate
from starterbus.transports.modbus.settings import TRANSPORT, modbus_settings
from starterbus.transports.modbus.simulator.rtu import ModbusRtuSimulator
from starterbus.transports.modbus.transport.rtu import ModbusRtuTransport
from starterbus.transports.modbus.url import ModbusRtuConfig


class ModbusRtuPlugin(TransportPlugin):
    name = TRANSPORT
    address_space = SPACE_NAME
    requires_point_addresses = True
    address_parameter = "unit"
    summary = "Modbus RTU (FC03/FC06) on a serial port, or RTU frames over TCP through a serial device server"
    capabilities = ALL_CAPABILITIES
    url_forms = (
        "modbus-rtu:///dev/ttyUSB0?unit=2&baudrate=9600&parity=E&stopbits=1&timeout=0.3&retries=2",
        "modbus-rtu://COM3?unit=2",
        "modbus-rtu+tcp://HOST:PORT?unit=2",
        "modbus-rtu+rfc2217://HOST:PORT?unit=2",
        "modbus-rtu+socket://HOST:PORT?unit=2",
    )

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        return ModbusRtuTransport(url, profile, ModbusRtuConfig.from_url(url, profile))

    def parse_settings(self, settings: Mapping[str, Any]) -> ModbusSettings:
        """The ``modbus`` address space's table (``starterbus.spaces.modbus`` parses it when a profile loads)."""
        return ModbusSettings.parse(settings)

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        self.parse_settings(settings)

    # -- simulator ----------------------------------------------------------------------------------------------

    simulator_options = (
        PluginOption(
            "port", flag="--modbus-rtu", metavar="PORT|PTY",
            help="serve Modbus RTU on a serial port, or on a new pseudo-terminal with PTY (prints its path)",
        ),
        PluginOption("tcp", metavar="HOST:PORT", help="serve Modbus RTU frames over TCP"),
        PluginOption(
            "baudrate", type=int, aliases=("--baudrate",),
            help="Modbus line baud rate (default: the model's default, 9600)",
        ),
        PluginOption(
            "parity", type=str.upper, choices=("N", "E", "O"), default="N", aliases=("--parity",),
            help="Modbus parity N, E or O",
        ),
        PluginOption("stopbits", type=int, choices=(1, 2), default=1, aliases=("--stopbits",), help="Modbus stop bits"),
    )  # fmt: skip

    def start_simulator(
        self, options: Mapping[str, object], starters: Mapping[int, SimulatedStarter]
    ) -> list[RunningSimulator]:
        values = resolve_options(self.simulator_options, options, f"{TRANSPORT} simulator")
        port, tcp = values.text("port"), values.text("tcp")
        if port is None and tcp is None:
            if values.given:
                raise ConfigurationError("the Modbus line options need --modbus-rtu PORT|PTY or --modbus-rtu-tcp")
            return []
        first = next(iter(starters.values()), None)
        default = modbus_settings(first.profile if first else None).default_baudrate
        baudrate = values.integer("baudrate") or default
        for unit, starter in starters.items():
            profile = starter.profile
            if not profile.supports(TRANSPORT):
                raise ConfigurationError(profile.no_interface(TRANSPORT))
            settings = modbus_settings(profile)
            lo, hi = settings.unit_ids
            if not max(1, lo) <= unit <= hi:
                raise ConfigurationError(
                    f"--unit {unit}: {profile.display_name} Modbus slave addresses are {max(1, lo)}..{hi}"
                )
            choices = settings.baudrates
            if choices and baudrate not in choices:
                raise ConfigurationError(
                    f"--baudrate {baudrate}: {profile.display_name} speaks {', '.join(map(str, choices))} baud"
                )
        parity, stopbits = values.text("parity") or "N", values.integer("stopbits") or 1
        served = dict(starters)

        def simulator(**where: Any) -> RunningSimulator:
            return ModbusRtuSimulator(served, baudrate=baudrate, parity=parity, stopbits=stopbits, **where).start()

        running: list[RunningSimulator] = []
        try:
            if port is not None:
                running.append(simulator(pty=True) if port.upper() == "PTY" else simulator(port=port))
            if tcp is not None:
                running.append(simulator(tcp=parse_host_port(tcp, default_host="0.0.0.0", option="--modbus-rtu-tcp")))
        except BaseException:
            for sim in running:
                sim.close()
            raise
        return running

    # -- decoder ------------------------------------------------------------------------------------------------

    decoder_options = (
        PluginOption(
            "direction", flag="--direction", choices=("request", "response"),
            help="what the (first) frame is; guessed when not given (a FC06 frame reads as a request)",
        ),
        PluginOption(
            "no_crc", flag="--no-crc", type=bool,
            help="the frame is printed without its CRC (JJR8000 manual examples)",
        ),
        PluginOption(
            "address", flag="--address", type=lambda text: int(text, 0), metavar="ADDRESS",
            help="start register of the request a lone FC03 response answers (names its values)",
        ),
    )  # fmt: skip

    def decode(self, frames: Sequence[str], options: Mapping[str, object], profile: Profile | None) -> list[Annotation]:
        values = resolve_options(self.decoder_options, options, f"{TRANSPORT} decoder")
        data = parse_hex(frames)
        return annotate(
            data,
            profile,
            direction=values.text("direction"),
            crc=not values.switch("no_crc"),
            address=values.integer("address"),
        )


PLUGIN = ModbusRtuPlugin()
