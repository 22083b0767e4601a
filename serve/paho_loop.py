"""paho-mqtt's socket on the asyncio event loop (:class:`~starterbus.serve.driver.EdgeNodeDriver`'s half that
knows paho's external-loop hooks): the socket watched with ``add_reader``, a burst of publishes written by one
``loop_write`` in the next turn of the loop (the socket corked meanwhile), its writability watched
(``add_writer``) only while the kernel's send buffer is full, ``loop_misc`` once a second."""

from __future__ import annotations

import asyncio
import functools
import socket
from typing import Any

import paho.mqtt.client as mqtt

from starterbus.core.supervision import Supervisor

__all__ = ["PahoOnLoop"]


def _current(client: mqtt.Client, sock: object) -> bool:
    """``sock`` is still the client's socket."""
    return client.socket() is sock


_CORK = getattr(socket, "TCP_CORK", None)  # Linux


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

    def _supervisor(self) -> Supervisor:
        raise NotImplementedError

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
