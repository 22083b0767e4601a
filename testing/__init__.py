"""Test helpers shipped with starterbus for plugin authors: the transport conformance kit (needs pytest)."""

from starterbus.testing.conformance import ConformanceNotice, TransportConformance, wait_until

__all__ = ["ConformanceNotice", "TransportConformance", "wait_until"]
