"""The ``devicenet`` transport (the core's contract): ``client`` (:class:`DeviceNetTransport`: status, commands,
measurements, the fleet's poll, identity) on ``link`` (its slave's link on the bus's scanner, and the steps its
reads are made of)."""

from starterbus.transports.devicenet.transport.client import DeviceNetTransport
from starterbus.transports.devicenet.transport.link import SCANNERS, ControlConflictError

__all__ = ["SCANNERS", "ControlConflictError", "DeviceNetTransport"]
