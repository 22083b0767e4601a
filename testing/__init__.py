"""Test helpers shipped with starterbus for plugin authors: the transport conformance kit (needs pytest)."""

from starterbus.testing.conformance import TransportConformance, wait_until

__all__ = ["TransportConformance", "wait_until"]
