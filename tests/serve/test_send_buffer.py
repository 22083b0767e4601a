"""A burst of publishes larger than the socket's send buffer: the driver writes what the kernel takes, watches the
socket's writability for the rest, and every message arrives once, whole and in order (the births of 1500
devices, about 6 MB, to a broker that stops reading for a while)."""

from __future__ import annotations

import asyncio
import socket
import threading
from typing import cast

from starterbus.aio import AsyncFleet
from starterbus.fleet.config import DeviceConfig
from starterbus.serve.actions import SessionOptions
from starterbus.serve.broker import BrokerOptions
from starterbus.serve.driver import EdgeNodeDriver
from starterbus.serve.metrics import Aliases, device_metrics, node_metrics
from starterbus.serve.schema import Payload
from starterbus.serve.session import EdgeSession
from starterbus.testing import wait_until
from starterbus.tests.serve.one_round import PROFILE, OneRound

DEVICES = 1500


class SlowBroker:
    """Just enough of an MQTT broker: CONNACK, SUBACK, PUBACK, PINGRESP; reads nothing after the SUBACK until
    ``reading`` is set; records the topic and payload of every PUBLISH."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a small window: the sender keeps it
        self.port = self.listener.getsockname()[1]
        self.reading = threading.Event()
        self.published: list[tuple[str, bytes]] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        conn, _ = self.listener.accept()
        with conn:
            buf = bytearray()
            subscribed = False
            while True:
                if subscribed and not self.reading.is_set():
                    self.reading.wait(30)
                data = conn.recv(65536)
                if not data:
                    return
                buf += data
                while (packet := _take_packet(buf)) is not None:
                    kind, body = packet
                    if kind == 0x10:
                        conn.sendall(b"\x20\x02\x00\x00")
                    elif kind == 0x82:  # SUBSCRIBE: one granted QoS 1 per topic filter
                        filters, i = 0, 2
                        while i < len(body):
                            i += 2 + int.from_bytes(body[i : i + 2], "big") + 1
                            filters += 1
                        conn.sendall(bytes([0x90, 2 + filters]) + bytes(body[:2]) + b"\x01" * filters)
                        subscribed = True
                    elif kind >> 4 == 3:
                        n = int.from_bytes(body[:2], "big")
                        topic, rest = bytes(body[2 : 2 + n]).decode(), body[2 + n :]
                        if kind & 0x06:  # QoS 1: packet id, then PUBACK
                            conn.sendall(b"\x40\x02" + bytes(rest[:2]))
                            rest = rest[2:]
                        self.published.append((topic, bytes(rest)))
                    elif kind == 0xC0:
                        conn.sendall(b"\xd0\x00")
                    elif kind == 0xE0:
                        return


def _take_packet(buf: bytearray) -> tuple[int, bytearray] | None:
    """One whole MQTT packet off the front of ``buf`` (its first byte, its body), or None if it is not all there."""
    length, shift, i = 0, 0, 1
    while True:
        if i >= len(buf):
            return None
        length |= (buf[i] & 0x7F) << shift
        shift += 7
        i += 1
        if not buf[i - 1] & 0x80:
            break
    if len(buf) < i + length:
        return None
    kind, body = buf[0], buf[i : i + length]
    del buf[: i + length]
    return kind, body


def test_a_burst_larger_than_the_send_buffer_arrives_whole_and_in_order() -> None:
    configs = [
        DeviceConfig(f"d{i:04d}", "l1", "jjr5000", "synthetic", i, 1.0, ("phase_a_current",), ())
        for i in range(DEVICES)
    ]
    aliases = Aliases()
    node = node_metrics(aliases)
    session = EdgeSession(
        SessionOptions("g", "n"), node, {c.name: device_metrics(c, PROFILE, aliases) for c in configs}
    )
    broker = SlowBroker()

    async def run() -> bool:
        driver = EdgeNodeDriver(cast(AsyncFleet, OneRound(configs)), session, BrokerOptions("127.0.0.1", broker.port))
        stop = asyncio.Event()
        task = asyncio.create_task(driver.run(stop))
        watched = await asyncio.to_thread(wait_until, lambda: bool(driver._writers), 30.0)
        broker.reading.set()
        births = lambda: sum(t.split("/")[2] == "DBIRTH" for t, _ in broker.published) == DEVICES  # noqa: E731
        await asyncio.to_thread(wait_until, births, 30.0)
        stop.set()
        await task
        return watched

    watched = asyncio.run(run())
    broker.reading.set()
    broker.thread.join(10)
    assert watched, "the kernel took the whole burst: the socket's writability was never watched"
    kinds = [(t.split("/")[2], t.split("/")[4] if t.count("/") == 4 else None) for t, _ in broker.published]
    assert kinds[: DEVICES + 1] == [("NBIRTH", None)] + [("DBIRTH", c.name) for c in configs]
    seqs = []
    for _topic, data in broker.published[: DEVICES + 1]:
        payload = Payload()
        payload.ParseFromString(data)
        seqs.append(payload.seq)
    assert seqs == [i % 256 for i in range(DEVICES + 1)]
    assert kinds[-1] == ("NDEATH", None)
