"""The base of the tests' own transports: no connection to open or close, and every capability."""

from __future__ import annotations

from starterbus.core.transport import ALL_CAPABILITIES, Capability, Transport


class StubTransport(Transport):
    """Opening and closing do nothing; every capability is offered (override ``capabilities`` to offer fewer).
    A subclass gives its ``name`` and the hooks its test needs."""

    def _open(self) -> None:
        pass

    def _close(self) -> None:
        pass

    @property
    def capabilities(self) -> frozenset[Capability]:
        return ALL_CAPABILITIES
