"""Entry point of the devicenet transport: ``starterbus.transports`` -> ``PLUGIN``.

Heavy modules (python-can, the scanner, the simulator) are imported only when a hook needs them.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

from starterbus.core import (
    Annotation,
    Capability,
    ConfigurationError,
    DeviceUrl,
    PluginOption,
    Profile,
    RunningSimulator,
    Transport,
    TransportPlugin,
    resolve_options,
)
from starterbus.transports.devicenet.settings import DeviceNetSettings, devicenet_settings

if TYPE_CHECKING:
    from starterbus.core import SimulatedStarter


class DeviceNetPlugin(TransportPlugin):
    name = "devicenet"
    address_parameter = "mac"
    period_parameter = "period"
    summary = "DeviceNet master (scanner) over python-can: polled I/O assemblies 1/101/2/102, explicit messaging"
    capabilities = frozenset({Capability.READ_MEASUREMENTS, Capability.COMMANDS, Capability.STATUS})
    url_forms = (
        "devicenet://INTERFACE/CHANNEL?mac=5",
        "devicenet://virtual/bus0?mac=5&dup_mac_wait=0.1",
        "devicenet://socketcan/can0?mac=5&period=1",
        "devicenet://socketcan/can0?mac=5&bitrate=500000&assemblies=extended",
        "devicenet://remote/127.0.0.1:54701?mac=5",
    )

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        from starterbus.transports.devicenet.transport import DeviceNetTransport

        return DeviceNetTransport(url, profile)

    def parse_settings(self, settings: Mapping[str, Any]) -> DeviceNetSettings:
        """``[transports.devicenet]``: mac_ids, input/output_assemblies ([basic, extended]), bitrates, identity."""
        return DeviceNetSettings.parse(settings)

    def check_settings(self, settings: Mapping[str, Any]) -> None:
        self.parse_settings(settings)

    # -- simulate ----------------------------------------------------------------------------------------------

    simulator_options = (
        PluginOption(
            "channel", flag="--devicenet", metavar="INTERFACE:CHANNEL",
            help="serve the starters as DeviceNet slaves on a python-can bus (e.g. virtual:bus0, socketcan:can0)",
        ),
        PluginOption(
            "mac", flag="--mac", type=int, multiple=True,
            help="DeviceNet MAC id (1-63) of each simulated starter, in --unit order; default: the --unit values",
        ),
        PluginOption(
            "assemblies", choices=("extended", "basic", "pro-type"), default="extended",
            help="assembly set of the polled connection: extended 101/102, basic 1/2, or pro-type "
            "(follow parameter p71 like the device)",
        ),
        PluginOption("bitrate", type=int, default=500000, choices=(125000, 250000, 500000), help="CAN bit rate"),
        PluginOption(
            "dup_mac_wait", type=float, default=1.0, metavar="SECONDS",
            help="wait of the duplicate MAC ID check (the specification says 1 s)",
        ),
        PluginOption(
            "bridge", metavar="[HOST:]PORT",
            help="also serve the bus to other processes of this machine through python-can-remote on a loopback "
            "address (connect with devicenet://remote/127.0.0.1:PORT?mac=N)",
        ),
    )  # fmt: skip

    def start_simulator(
        self, options: Mapping[str, object], starters: Mapping[int, SimulatedStarter]
    ) -> list[RunningSimulator]:
        values = resolve_options(self.simulator_options, options, "devicenet simulator")
        spec = values.text("channel")
        if not spec:
            if values.integers("mac") or values.text("bridge"):
                raise ConfigurationError("--mac and --devicenet-bridge need --devicenet INTERFACE:CHANNEL")
            return []
        from starterbus.core import LoopbackBridge, parse_bridge_address, parse_bus_spec
        from starterbus.transports.devicenet.codec.assemblies import AssemblySet
        from starterbus.transports.devicenet.simulator import DeviceNetSimulator

        for starter in starters.values():
            profile = starter.profile
            if not profile.supports(self.name):
                raise ConfigurationError(
                    f"{profile.display_name} has no DeviceNet interface (it speaks: {', '.join(profile.transports)})"
                )
        interface, channel = parse_bus_spec(spec, "--devicenet")
        macs = values.integers("mac") or list(starters) or [1]
        if len(macs) != len(starters):
            raise ConfigurationError(
                f"{len(macs)} --mac value(s) for {len(starters)} simulated starter(s): give one --mac per --unit "
                "(or omit --mac to use the --unit values as MAC ids)"
            )
        if len(set(macs)) != len(macs):
            raise ConfigurationError(f"--mac given twice with the same MAC id: {macs}")
        for mac, starter in zip(macs, starters.values(), strict=True):
            lo, hi = devicenet_settings(starter.profile).mac_ids
            if not lo <= mac <= hi:
                raise ConfigurationError(f"DeviceNet MAC id {mac} is outside {lo}..{hi}")
        choice = values.text("assemblies")
        assemblies = None if choice == "pro-type" else AssemblySet(choice or "extended")
        bridge = values.text("bridge")
        bridge_address = parse_bridge_address(bridge) if bridge else None
        simulator = DeviceNetSimulator(
            (interface, channel),
            bitrate=values.integer("bitrate") or 500000,
            dup_mac_wait=values.number("dup_mac_wait") or 0.0,
        )
        running: list[RunningSimulator] = [simulator]
        try:
            for mac, starter in zip(macs, starters.values(), strict=True):
                simulator.add_node(starter, mac, assemblies=assemblies)
            simulator.start()
            if bridge_address is not None:
                host, port = bridge_address
                label, client_url = "devicenet bridge", "devicenet://remote/{address}?mac=N"
                running.append(LoopbackBridge(interface, channel, host, port, label=label, client_url=client_url))
        except BaseException:
            for item in running:
                item.close()
            raise
        return running

    # -- decode ------------------------------------------------------------------------------------------------

    decoder_help = (
        "Each HEX argument is one CAN frame in candump syntax ID#DATA (e.g. 42E#004B03010300 3C5#2D0000000100); "
        "fragmented explicit messages are reassembled across the frames given."
    )

    def decode(self, frames: Sequence[str], options: Mapping[str, object], profile: Profile | None) -> list[Annotation]:
        from starterbus.transports.devicenet.decoder import annotate_frames

        resolve_options(self.decoder_options, options, "devicenet decoder")
        return annotate_frames(list(frames), profile)


PLUGIN = DeviceNetPlugin()
