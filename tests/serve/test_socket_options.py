"""paho's socket once the driver has written a burst: TCP_NODELAY set and the cork taken off, so that a burst
leaves at once instead of waiting, by Nagle's rule, for the broker's delayed ACK of the one before (up to 40 ms)."""

from __future__ import annotations

import asyncio
import socket
from typing import cast

import pytest

from starterbus.aio import AsyncFleet
from starterbus.fleet.config import DeviceConfig
from starterbus.serve.actions import SessionOptions
from starterbus.serve.broker import BrokerOptions
from starterbus.serve.driver import EdgeNodeDriver
from starterbus.serve.embedded import Mosquitto
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.session import EdgeSession
from starterbus.testing import wait_until
from starterbus.tests.serve.one_round import PROFILE, OneRound


@pytest.mark.skipif(not hasattr(socket, "TCP_CORK"), reason="TCP_CORK is Linux's")
def test_the_socket_is_not_left_corked_and_has_nodelay(broker: Mosquitto) -> None:
    configs = [DeviceConfig(f"d{i}", "l1", "jjr5000", "synthetic", i, 1.0, ("phase_a_current",), ()) for i in range(5)]
    aliases = Aliases()
    devices = {c.name: device_metrics(c, PROFILE, aliases) for c in configs}
    session = EdgeSession(SessionOptions("g", "n"), node_metrics(aliases), devices)

    async def run() -> tuple[int, int]:
        driver = EdgeNodeDriver(cast(AsyncFleet, OneRound(configs)), session, BrokerOptions("127.0.0.1", broker.port))
        stop = asyncio.Event()
        task = asyncio.create_task(driver.run(stop))
        born = lambda: session.born and session.published >= 1 + len(configs)  # noqa: E731
        assert await asyncio.to_thread(wait_until, born, 15.0)
        client = driver._client
        assert client is not None
        await asyncio.to_thread(wait_until, lambda: not client.want_write(), 15.0)  # the births written
        sock = client.socket()
        assert isinstance(sock, socket.socket)
        options = (
            sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY),
            sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_CORK),
        )
        stop.set()
        await task
        return options

    nodelay, cork = asyncio.run(run())
    assert nodelay, "TCP_NODELAY not set: uncorking would leave the last segment to Nagle's rule"
    assert not cork, "the socket was left corked"
