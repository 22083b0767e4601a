"""Entry point of the ``modbus-rtu`` transport (and its ``+tcp``, ``+rfc2217`` and ``+socket`` variants)."""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any

from starterbus.core import settings_check as check
from starterbus.core.errors import ConfigurationError
from starterbus.core.profile import Profile
from starterbus.core.simulator import SimulatedStarter
from starterbus.core.transport import ALL_CAPABILITIES, Annotation, RunningSimulator, Transport, TransportPlugin
from starterbus.core.url import DeviceUrl
from starterbus.transports.modbus.annotate import annotate, parse_hex
from starterbus.transports.modbus.client import ModbusRtuTransport
from starterbus.transports.modbus.config import ModbusRtuConfig
from starterbus.transports.modbus.simulator import ModbusRtuSimulator, parse_host_port
from starterbus.transports.modbus.slave import TRANSPORT


def _add_option(group: argparse._ActionsContainer, names: Sequence[str], **kwargs: object) -> None:
    """Add an option with its short alias when no other transport took the alias, else only the long name."""
    try:
        group.add_argument(*names, **kwargs)  # type: ignore[arg-type]
    except argparse.ArgumentError:
        group.add_argument(names[0], **kwargs)  # type: ignore[arg-type]


class ModbusRtuPlugin(TransportPlugin):
    name = TRANSPORT
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

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        """The keys this transport reads from ``[transports.modbus-rtu]`` (``exceptions`` is parsed by the loader)."""
        check.known_keys(settings, ("max_read_registers", "unit_ids", "baudrates", "default_baudrate", "exceptions"))
        check.int_value(settings, "max_read_registers", 1, 125)
        check.int_range(settings, "unit_ids", 0, 247)
        check.int_list(settings, "baudrates", 1, 10_000_000)
        check.int_value(settings, "default_baudrate", 1, 10_000_000)

    # -- simulator ----------------------------------------------------------------------------------------------

    def add_simulator_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--modbus-rtu", metavar="PORT|PTY", default=None,
            help="serve Modbus RTU on a serial port, or on a new pseudo-terminal with PTY (prints its path)",
        )  # fmt: skip
        parser.add_argument(
            "--modbus-rtu-tcp", metavar="HOST:PORT", default=None, help="serve Modbus RTU frames over TCP"
        )
        _add_option(
            parser, ["--modbus-rtu-baudrate", "--baudrate"], dest="modbus_rtu_baudrate", type=int, default=None,
            help="Modbus line baud rate (default: the model's default, 9600)",
        )  # fmt: skip
        _add_option(
            parser, ["--modbus-rtu-parity", "--parity"], dest="modbus_rtu_parity", choices=["N", "E", "O"],
            type=str.upper, default="N", help="Modbus parity N, E or O (default N)",
        )  # fmt: skip
        _add_option(
            parser, ["--modbus-rtu-stopbits", "--stopbits"], dest="modbus_rtu_stopbits", type=int, choices=[1, 2],
            default=1, help="Modbus stop bits (default 1)",
        )  # fmt: skip

    def start_simulators(
        self, args: argparse.Namespace, profile: Profile, starters: Sequence[object]
    ) -> list[RunningSimulator]:
        port = getattr(args, "modbus_rtu", None)
        tcp = getattr(args, "modbus_rtu_tcp", None)
        if port is None and tcp is None:
            return []
        if not profile.supports(TRANSPORT):
            raise ConfigurationError(f"{profile.display_name} has no Modbus RTU interface")
        units = list(getattr(args, "unit", None) or [1])
        settings = profile.transport_settings(TRANSPORT)
        lo, hi = settings.get("unit_ids", [1, 247])
        for unit in units:
            if not max(1, lo) <= unit <= hi:
                raise ConfigurationError(
                    f"--unit {unit}: {profile.display_name} Modbus slave addresses are {max(1, lo)}..{hi}"
                )
        baudrate = args.modbus_rtu_baudrate or int(settings.get("default_baudrate", 9600))
        choices = [int(b) for b in settings.get("baudrates", [])]
        if choices and baudrate not in choices:
            raise ConfigurationError(
                f"--baudrate {baudrate}: {profile.display_name} speaks {', '.join(map(str, choices))} baud"
            )
        served: dict[int, SimulatedStarter] = {}
        for unit, starter in zip(units, starters, strict=True):
            if not isinstance(starter, SimulatedStarter):
                raise ConfigurationError(f"unit {unit}: {starter!r} is not a SimulatedStarter")
            served[unit] = starter
        line = {"baudrate": baudrate, "parity": args.modbus_rtu_parity, "stopbits": args.modbus_rtu_stopbits}
        running: list[RunningSimulator] = []
        try:
            if port is not None:
                if port.upper() == "PTY":
                    running.append(ModbusRtuSimulator(served, pty=True, **line).start())
                else:
                    running.append(ModbusRtuSimulator(served, port=port, **line).start())
            if tcp is not None:
                running.append(ModbusRtuSimulator(served, tcp=parse_host_port(tcp), **line).start())
        except BaseException:
            for sim in running:
                sim.close()
            raise
        return running

    # -- decoder ------------------------------------------------------------------------------------------------

    def add_decode_arguments(self, parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--direction", choices=["request", "response"], default=None,
            help="what the (first) frame is; guessed when not given (a FC06 frame reads as a request)",
        )  # fmt: skip
        parser.add_argument(
            "--no-crc", action="store_true", help="the frame is printed without its CRC (JJR8000 manual examples)"
        )
        parser.add_argument(
            "--address", type=lambda text: int(text, 0), default=None,
            help="start register of the request a lone FC03 response answers (names its values)",
        )  # fmt: skip

    def decode(self, args: argparse.Namespace, profile: Profile | None) -> list[Annotation]:
        data = parse_hex(args.data)
        return annotate(data, profile, direction=args.direction, crc=not args.no_crc, address=args.address)


PLUGIN = ModbusRtuPlugin()
