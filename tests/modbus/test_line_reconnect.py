"""The I/O loop reconnects a broken TCP line (a serial device server, ``modbus-rtu+tcp``) without blocking: the
connection is made with ``connect_ex`` and looked at again until it is made or its time is over, so one device
server that does not answer cannot hold every other line of the loop (``socket.create_connection`` is never
called there)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pytest

from starterbus.core.device import open_device
from starterbus.core.errors import TransportError
from starterbus.core.media.resolve import forget_addresses
from starterbus.core.polling import run_task
from starterbus.core.scheduler import THREAD_NAME
from starterbus.tests.modbus.line_task_kit import Poll, values
from starterbus.tests.modbus.test_line_follow import line_of, served
from starterbus.transports.modbus.codec.frames import ReadRequest
from starterbus.transports.modbus.driver.rtu_driver import CONNECT_LOOK

if TYPE_CHECKING:
    from starterbus.tests.modbus.conftest import SimFactory

READ = ReadRequest(2, 0x0100, 1)


@pytest.fixture
def blocking_connects(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """The names of the threads that call ``socket.create_connection`` (a blocking connect) from now on."""
    names: list[str] = []
    connect = socket.create_connection

    def recording(*args: Any, **kwargs: Any) -> socket.socket:
        names.append(threading.current_thread().name)
        return connect(*args, **kwargs)

    monkeypatch.setattr(socket, "create_connection", recording)
    return names


def test_a_poll_reconnects_a_broken_tcp_line_without_a_blocking_connect(
    make_sim: SimFactory, blocking_connects: list[str]
) -> None:
    sim = make_sim("jjr5000", tcp=("127.0.0.1", 0))
    with open_device(sim.url(2), "jjr5000") as device:
        line = line_of(device.transport)
        old = line.link
        line.mark_broken()
        poll = Poll(line, READ)
        result = run_task(poll.task, time.monotonic)
        assert values(result, poll) == [(sim.starters[2].params["motor_rated_current"],)]
        assert line.link is not old and old.closed and not line.broken
    assert blocking_connects == [threading.current_thread().name], "only the device's open connected blocking"


@pytest.fixture
def silent_server() -> Iterator[tuple[int, socket.socket]]:
    """A listening port whose first connection is accepted (the device's open) and whose backlog is then full:
    a connection after it gets no answer to its SYN (the connect waits until its timeout)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(0)
    try:
        yield server.getsockname()[1], server
    finally:
        server.close()


def test_a_device_server_that_never_answers_fails_the_poll_after_its_timeout_without_holding_the_loop(
    silent_server: tuple[int, socket.socket], blocking_connects: list[str]
) -> None:
    port, server = silent_server
    with open_device(f"modbus-rtu+tcp://127.0.0.1:{port}?unit=2&timeout=0.5", "jjr5000") as device:
        accepted, _ = server.accept()
        filler = socket.create_connection(("127.0.0.1", port))  # the backlog is full from now on
        try:
            line = line_of(device.transport)
            line.mark_broken()
            poll = Poll(line, READ)
            now = time.monotonic()
            poll.task.advance(now)
            assert not poll.task.done and line.broken, "the connection is being made"
            assert poll.task.fd == -1 and poll.task.wake_at == pytest.approx(now + CONNECT_LOOK)
            with pytest.raises(TransportError, match=rf"cannot connect to 127.0.0.1:{port}: timed out"):
                run_task(poll.task, time.monotonic)
            assert line.broken and not line.lock.locked()
        finally:
            filler.close()
            accepted.close()
    assert blocking_connects == [threading.current_thread().name, threading.current_thread().name]


def test_the_loop_reconnects_for_a_blocking_caller_without_a_blocking_connect(
    make_sim: SimFactory, blocking_connects: list[str]
) -> None:
    sim = make_sim("jjr5000", tcp=("127.0.0.1", 0))
    with served(), open_device(sim.url(2), "jjr5000") as device:
        line = line_of(device.transport)
        line.mark_broken()
        value = device.read("current_limit")["current_limit"].raw
        assert value == sim.starters[2].params["current_limit"] and not line.broken
    assert THREAD_NAME not in blocking_connects


def test_a_line_named_by_host_name_is_looked_up_at_its_open_never_again_in_the_loop(
    make_sim: SimFactory, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``modbus-rtu+tcp://NAME:PORT``: the open looks NAME up (and keeps it); the poll's reconnect in the loop takes
    the kept address and asks no name server."""
    name, real = "device-server.plant.test", socket.getaddrinfo
    asked: list[str] = []

    def getaddrinfo(host: str, port: Any, *args: Any, **kwargs: Any) -> Any:
        if host == name:
            asked.append(threading.current_thread().name)
            host = "127.0.0.1"
        return real(host, port, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)
    forget_addresses()
    try:
        sim = make_sim("jjr5000", tcp=("127.0.0.1", 0))
        port = sim.url(2).split("://", 1)[1].split("?", 1)[0].rsplit(":", 1)[1]
        with open_device(f"modbus-rtu+tcp://{name}:{port}?unit=2", "jjr5000") as device:
            assert asked == [threading.current_thread().name]
            line = line_of(device.transport)
            line.mark_broken()
            poll = Poll(line, READ)
            result = run_task(poll.task, time.monotonic)
            assert values(result, poll) == [(sim.starters[2].params["motor_rated_current"],)]
            assert not line.broken and asked == [threading.current_thread().name]
    finally:
        forget_addresses()
