"""The driver's QoS 0 publishes (``PahoOnLoop._publish``) put on the wire exactly what paho's own ``publish`` does,
while a burst of them is one packet of paho's queue: the byte streams a server receives are compared whole."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable

import paho.mqtt
import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from starterbus.serve.paho_loop import PahoOnLoop

Publish0 = Callable[[mqtt.Client, str, bytes], None]


def _paho(client: mqtt.Client, topic: str, payload: bytes) -> None:
    client.publish(topic, payload, qos=0, retain=False)


def _stream(publish0: Publish0, queued: list[int]) -> bytes:
    """Everything one client writes to a server: CONNECT, QoS 0 publishes of every length class of MQTT's
    remaining length, a SUBSCRIBE and a QoS 1 PUBLISH between them (their packet ids follow every publish's), a
    burst larger than one of the driver's packets, DISCONNECT. ``queued``: paho's queue length after each step."""
    server = socket.create_server(("127.0.0.1", 0))
    received = bytearray()

    def serve() -> None:
        conn, _ = server.accept()
        with conn:
            while chunk := conn.recv(65536):
                received.extend(chunk)

    reader = threading.Thread(target=serve)
    reader.start()
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="burst", protocol=mqtt.MQTTv311)
    client.on_socket_register_write = lambda *_: None  # written only by loop_write, as on the event loop
    client.connect("127.0.0.1", server.getsockname()[1], 60)
    steps: list[Callable[[], object]] = [
        *(lambda n=n: publish0(client, f"spBv1.0/g/DDATA/n/d{n}", bytes(range(n % 256)) * 3) for n in range(40)),
        lambda: publish0(client, "spBv1.0/g/DDATA/n/big", b"\x01" * 20_000),  # a 3-byte remaining length
        lambda: publish0(client, "spBv1.0/g/NDATA/n", b""),
        lambda: client.subscribe("spBv1.0/g/NCMD/n", qos=1),
        lambda: publish0(client, "spBv1.0/g/DDATA/n/d1", b"after the subscribe"),
        lambda: client.publish("spBv1.0/g/NDEATH/n", b"qos 1", qos=1),
        *(lambda n=n: publish0(client, "spBv1.0/g/DDATA/n/x", bytes([n]) * 9000) for n in range(12)),
        client.loop_write,
        lambda: publish0(client, "spBv1.0/g/DDATA/n/d2", b"next burst"),
        client.loop_write,
    ]
    for step in steps:
        step()
        queued.append(len(client._out_packet))
    client.disconnect()
    while client.socket() is not None:
        client.loop_write()
    publish0(client, "spBv1.0/g/DDATA/n/d3", b"not connected: dropped")
    reader.join(10)
    server.close()
    return bytes(received)


def test_the_driver_writes_what_paho_publish_writes_in_fewer_packets() -> None:
    driver = PahoOnLoop()
    driver._burst, driver._topics = None, {}
    queued_paho: list[int] = []
    queued_driver: list[int] = []
    expected = _stream(_paho, queued_paho)
    got = _stream(driver._publish, queued_driver)
    assert len(expected) > 130_000 and expected.startswith(b"\x10")  # CONNECT first
    assert got == expected
    assert max(queued_paho) == 58  # CONNECT, 40 + 2 publishes, SUBSCRIBE, 1, 1, 12
    assert queued_driver[41] == 2  # CONNECT and one packet for the 42 publishes
    assert max(queued_driver) <= 10  # the 9 kB publishes: a packet each about 64 kB


@pytest.mark.parametrize("version", ["3.0.0", "1.6.1"])
def test_a_paho_whose_queue_is_not_known_gets_every_message_through_its_own_publish(
    monkeypatch: pytest.MonkeyPatch, version: str
) -> None:
    monkeypatch.setattr(paho.mqtt, "__version__", version)
    driver = PahoOnLoop()
    driver._burst, driver._topics = None, {}
    queued_paho: list[int] = []
    queued_driver: list[int] = []
    assert _stream(_paho, queued_paho) == _stream(driver._publish, queued_driver)
    assert queued_driver == queued_paho  # a packet of paho's queue per message, as its publish makes them


def test_a_topic_paho_refuses_is_still_refused() -> None:
    driver = PahoOnLoop()
    driver._burst, driver._topics = None, {}
    client = mqtt.Client(CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv311)
    for topic in ("spBv1.0/g/DDATA/n/+", "spBv1.0/g/DDATA/n/#", ""):
        try:
            driver._publish(client, topic, b"x")
        except ValueError:
            continue
        raise AssertionError(f"{topic!r} was published")
