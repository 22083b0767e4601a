"""paho-mqtt's socket on the asyncio event loop (:class:`~starterbus.serve.driver.EdgeNodeDriver`'s half that
knows paho's external-loop hooks): the socket watched with ``add_reader``, a burst of publishes written by one
``loop_write`` in the next turn of the loop (the socket corked meanwhile), its writability watched
(``add_writer``) only while the kernel's send buffer is full, ``loop_misc`` once a second; QoS 0 publishes queued
as one packet of paho's a burst (:meth:`PahoOnLoop._publish`)."""

from __future__ import annotations

import asyncio
import functools
import socket
import struct
from typing import TYPE_CHECKING, Any

import paho.mqtt
import paho.mqtt.client as mqtt

from starterbus.core.supervision import Supervisor

if TYPE_CHECKING:
    from paho.mqtt.client import _OutPacket

__all__ = ["PahoOnLoop"]

_PUBLISH = 0x30  # MQTT 3.1.1 PUBLISH, QoS 0, not retained, not a duplicate (section 3.3.1)
_MAX_REMAINING = 268_435_455  # what a PUBLISH's remaining length can say (paho refuses a larger payload)
_BURST_BYTES = 65_536  # a burst's packet grows to about this; the next publish starts another


def _remaining_length(n: int) -> bytes:
    """MQTT's variable-length integer (section 2.2.3), as paho packs it."""
    out = bytearray()
    while True:
        n, digit = divmod(n, 128)
        out.append(digit | 0x80 if n else digit)
        if not n:
            return bytes(out)


def _topic_field(topic: str) -> bytes | None:
    """A PUBLISH's topic name as paho packs it (length, UTF-8), or None for one paho refuses (it raises then)."""
    name = topic.encode("utf-8")
    if not name or b"+" in name or b"#" in name or len(name) > 65535:
        return None
    return struct.pack("!H", len(name)) + name


def _current(client: mqtt.Client, sock: object) -> bool:
    """``sock`` is still the client's socket."""
    return client.socket() is sock


_CORK = getattr(socket, "TCP_CORK", None)  # Linux

#: what :meth:`PahoOnLoop._publish` uses of paho's private side; present in paho-mqtt 2.0-2.2
_QUEUE_PARTS = ("_out_packet", "_packet_queue", "_mid_generate", "_protocol")


def queue_known(client: mqtt.Client) -> bool:
    """Whether ``client``'s private queue is the one :meth:`PahoOnLoop._publish` knows (paho-mqtt 2.x, MQTT
    3.1.1): else every message goes through paho's own ``publish``, as it did before the bursts."""
    return (
        paho.mqtt.__version__.split(".", 1)[0] == "2"
        and all(hasattr(client, part) for part in _QUEUE_PARTS)
        and client._protocol == mqtt.MQTTv311
    )


def _set_tcp(sock: Any, option: int | None, on: bool) -> None:
    """Nothing where the option is unknown or the socket is not TCP."""
    if option is not None:
        try:
            sock.setsockopt(socket.IPPROTO_TCP, option, on)
        except (OSError, AttributeError):  # not a TCP socket
            pass


def _cork(sock: Any, on: bool) -> None:
    """Hold the segments of the packets paho sends one by one (``on``), then push them out together: a burst of
    publishes costs the kernel a few full segments through loopback or the network instead of one each (and the
    broker a few reads). The bytes and their order are paho's; only their split into TCP segments changes. The
    push at ``on=False`` is immediate only with ``TCP_NODELAY`` (set by ``_watch``): without it Nagle's rule
    would hold the last segment until the broker's (delayed) ACK of the one before, up to 40 ms."""
    _set_tcp(sock, _CORK, on)


class PahoOnLoop:
    """The paho client's socket on the running event loop (a base of the driver, which makes the client and wires
    paho's ``on_socket_*`` callbacks to these methods)."""

    _watched: dict[int, tuple[int, asyncio.Task[None]]]  # id(socket) -> (fileno, keepalive task)
    _flushing: set[int]  # id(socket): a _flush is scheduled
    _writers: set[int]  # id(socket): its writability is watched (a full send buffer)
    _burst: _OutPacket | None  # the packet of paho's queue that :meth:`_publish` adds to
    _known_queue: mqtt.Client | None = None  # the client whose private queue :func:`queue_known` found as expected
    _topics: dict[str, bytes | None]  # topic -> _topic_field(topic)

    def _supervisor(self) -> Supervisor:
        raise NotImplementedError

    def _publish(self, client: mqtt.Client, topic: str, payload: bytes) -> None:
        """``client.publish(topic, payload, qos=0, retain=False)``: the same PUBLISH packet (MQTT 3.1.1, and the same
        message id taken, so a later QoS 1 packet's id is as paho's), appended to the last packet of paho's queue
        when that is this burst's and not yet written whole (up to about 64 KiB), else queued as a new one. The
        stream paho writes is byte for byte what one ``publish`` per message queues, and a burst of publishes
        costs one packet of paho's (one ``send``, one "published") instead of one each: paho's publish and write
        were about 40 % of a sample's CPU. Not connected: dropped, as paho drops a QoS 0 message then. Uses paho's
        private queue (``_out_packet``, ``_packet_queue``, ``_mid_generate``), as paho-mqtt 2.0-2.2 have them:
        ``tests/serve/test_publish_burst.py`` compares the bytes with paho's own ``publish``; where that queue is
        not the one known here (:func:`queue_known`, checked once per client), paho's ``publish`` it is."""
        if client is not self._known_queue:
            if not queue_known(client):
                client.publish(topic, payload, qos=0, retain=False)
                return
            self._known_queue = client
        field = self._topics.get(topic)
        if field is None and topic not in self._topics:
            field = self._topics[topic] = _topic_field(topic)
        size = 0 if field is None else len(field) + len(payload)
        if field is None or size > _MAX_REMAINING:
            client.publish(topic, payload, qos=0, retain=False)  # paho raises
            return
        if client.socket() is None:
            return
        packet = b"%c%b%b%b" % (_PUBLISH, _remaining_length(size), field, payload)
        mid = client._mid_generate()
        queue = client._out_packet
        burst = self._burst
        if burst is not None and queue and queue[-1] is burst and len(burst["packet"]) < _BURST_BYTES:
            burst["packet"] += packet  # a bytearray: extended in place
            burst["to_process"] += len(packet)
            return
        client._packet_queue(_PUBLISH, bytearray(packet), mid, 0, mqtt.MQTTMessageInfo(mid))
        self._burst = queue[-1]

    def _watch(self, client: mqtt.Client, sock: Any) -> None:
        loop = asyncio.get_running_loop()

        def read() -> None:
            client.loop_read()
            while client.socket() is sock and getattr(sock, "pending", lambda: 0)():  # TLS: decrypted, buffered
                client.loop_read()

        fileno = sock.fileno()
        if fileno < 0:  # closed again before the loop got here
            return
        _set_tcp(sock, socket.TCP_NODELAY, True)  # every burst out at once (``_cork``)
        loop.add_reader(fileno, read)
        keepalive = self._supervisor().task("serve-keepalive", functools.partial(self._misc, client))
        self._watched[id(sock)] = (fileno, keepalive)

    def _unwatch(self, sock: Any) -> None:
        watched = self._watched.pop(id(sock), None)
        if watched is not None:
            fileno, task = watched
            loop = asyncio.get_running_loop()
            loop.remove_reader(fileno)
            loop.remove_writer(fileno)
            self._writers.discard(id(sock))
            task.cancel()

    def _want_write(self, client: mqtt.Client, sock: Any) -> None:
        """paho queued a packet on an idle socket: write it, and all queued with it in this turn of the loop, in
        the next turn (one ``loop_write`` for a burst of publishes). The socket's writability is watched only
        when the kernel took less than that (a full send buffer): paho unregisters it once all is written. Not
        watching it for every burst spares two ``epoll_ctl`` calls and a wake-up per burst."""
        if sock.fileno() >= 0 and id(sock) not in self._flushing:
            self._flushing.add(id(sock))
            asyncio.get_running_loop().call_soon(self._flush, client, sock)

    def _flush(self, client: mqtt.Client, sock: Any) -> None:
        self._flushing.discard(id(sock))
        if sock.fileno() < 0 or not _current(client, sock):  # closed (or another connection) meanwhile
            return
        _cork(sock, True)
        try:
            client.loop_write()
        finally:
            _cork(sock, False)  # pushes out what paho wrote, whatever happened
        if client.want_write() and _current(client, sock):  # paho still counts the socket as registered
            asyncio.get_running_loop().add_writer(sock, client.loop_write)
            self._writers.add(id(sock))

    def _unwatch_write(self, sock: Any) -> None:
        if id(sock) in self._writers:  # else nothing to undo (paho says so after every burst written)
            self._writers.discard(id(sock))
            if sock.fileno() >= 0:
                asyncio.get_running_loop().remove_writer(sock)

    @staticmethod
    async def _misc(client: mqtt.Client) -> None:
        """Keepalive pings and the detection of a silent broker, once a second."""
        while client.loop_misc() == mqtt.MQTT_ERR_SUCCESS:
            await asyncio.sleep(1.0)
