"""Entry point of the devicenet transport (placeholder until the transport lands)."""

from __future__ import annotations

from starterbus.core.errors import UnsupportedOperationError
from starterbus.core.profile import Profile
from starterbus.core.transport import Capability, Transport, TransportPlugin
from starterbus.core.url import DeviceUrl


class DeviceNetPlugin(TransportPlugin):
    name = "devicenet"
    summary = "devicenet (not implemented yet)"
    capabilities = frozenset(Capability)

    def open(self, url: DeviceUrl, profile: Profile) -> Transport:
        raise UnsupportedOperationError(f"the {self.name} transport is not implemented yet")


PLUGIN = DeviceNetPlugin()
