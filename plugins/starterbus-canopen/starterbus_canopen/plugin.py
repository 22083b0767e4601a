"""Entry point of the canopen transport: ``starterbus.transports`` -> ``PLUGIN``.

canopen and python-can are imported only when a transport, a simulator or the decoder is used.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping, Sequence
from typing import Any

from starterbus.core import (
    Annotation,
    Capability,
    ConfigurationError,
    DeviceUrl,
    Profile,
    RunningSimulator,
    Transport,
    TransportPlugin,
)
from starterbus_canopen.settings import CanopenSettings


def _int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


class CanopenPlugin(TransportPlugin):
    name = "canopen"
    summary = "CANopen master over python-can: SDO (expedited), TPDO1 status, RPDO1 commands, heartbeat"
    capabilities = frozenset(Capability)
    url_forms = (
        "canopen://INTERFACE/CHANNEL?node=N",
        "canopen://virtual/bus0?node=5",
        "canopen://socketcan/can0?node=5&bitrate=250000&heartbeat=100&master=127",
        "canopen://virtual/bus0?node=5&timeout=0.5&max_age=0.5&cycle=100",
    )
    requires_point_addresses = True
    address_parameter = "node"

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        from starterbus_canopen.transport import CanopenTransport

        return CanopenTransport(url, profile)

    def parse_address(self, value: object) -> tuple[int, int]:
        """``[index, subindex]``: index 0x1000..0xFFFF, subindex 0..0xFF."""
        if (
            not isinstance(value, (list, tuple))
            or len(value) != 2
            or not all(_int(v) for v in value)
            or not 0x1000 <= value[0] <= 0xFFFF
            or not 0 <= value[1] <= 0xFF
        ):
            raise ConfigurationError(
                f"{value!r} is not a CANopen address [index, subindex] (index 0x1000..0xFFFF, subindex 0..255)"
            )
        return int(value[0]), int(value[1])

    def parse_settings(self, settings: Mapping[str, Any]) -> CanopenSettings:
        """``[transports.canopen]``: node_ids = [lo, hi], device_type (0x1000), identity = {...} (0x1018)."""
        return CanopenSettings.parse(settings)

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        self.parse_settings(settings)

    # -- simulate (argparse glue in one module, see sim_cli) ------------------------------------------------------

    def add_simulator_arguments(self, parser: argparse.ArgumentParser) -> None:
        from starterbus_canopen.sim_cli import add_arguments

        add_arguments(parser)

    def start_simulators(
        self, args: argparse.Namespace, profile: Profile, starters: Sequence[object]
    ) -> list[RunningSimulator]:
        from starterbus_canopen.sim_cli import start

        return start(args, profile, starters)

    # -- decode ------------------------------------------------------------------------------------------------

    decoder_help = (
        "Each HEX argument is one CAN frame in candump syntax ID#DATA (e.g. 000#0105 605#4001200000000000 "
        "185#00A0C003); segmented SDO transfers are followed across the frames given; give --model to decode PDOs."
    )

    def decode(self, frames: Sequence[str], options: Mapping[str, object], profile: Profile | None) -> list[Annotation]:
        from starterbus_canopen.decoder import annotate_frames

        return annotate_frames(list(frames), profile)


PLUGIN = CanopenPlugin()
