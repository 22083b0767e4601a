"""The drivers of the media engines run on (docs/engine.md): the one loop body (:class:`Driver`), a byte stream
with a descriptor (:class:`StreamDriver`), a TCP client connection (:class:`TcpDriver`); ``waiter.py`` waits on
their descriptors. Protocol-neutral."""

from starterbus.core.media.driver import Driver, Stream, StreamDriver, step_error
from starterbus.core.media.resolve import address_of
from starterbus.core.media.tcp import TcpDriver, connect_failure, connect_timeout, start_connect

__all__ = [
    "Driver",
    "Stream",
    "StreamDriver",
    "TcpDriver",
    "address_of",
    "connect_failure",
    "connect_timeout",
    "start_connect",
    "step_error",
]
