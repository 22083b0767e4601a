"""Test helpers shipped with starterbus for plugin authors: the transport conformance kit (needs pytest)."""

import pytest

# the kit's assertions say what differed, as a test's own do
pytest.register_assert_rewrite(
    "starterbus.testing.conformance",
    "starterbus.testing.kit_base",
    "starterbus.testing.kit_faults",
    "starterbus.testing.kit_running",
)

from starterbus.testing.conformance import ConformanceNotice, TransportConformance  # noqa: E402
from starterbus.testing.faults import DeviceTap, Fault, FaultControl, FaultNotSupported  # noqa: E402
from starterbus.testing.waits import wait_until, wait_until_async  # noqa: E402

__all__ = [
    "ConformanceNotice", "DeviceTap", "Fault", "FaultControl", "FaultNotSupported", "TransportConformance",
    "wait_until", "wait_until_async",
]  # fmt: skip
