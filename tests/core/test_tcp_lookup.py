"""Host names are looked up outside the I/O loop: in the opener's thread, or in a thread of their own after a
failed connect; the loop's connects take the kept address and never wait on a name server."""

from __future__ import annotations

import socket
import threading
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from starterbus.core.errors import TransportError
from starterbus.core.media import resolve
from starterbus.core.media.resolve import address_of, forget_addresses, kept_address
from starterbus.testing import wait_until
from starterbus.transports.modbus.codec.messages import ReadRequest, ReadResponse
from starterbus.transports.modbus.driver.tcp_line import MbapConnection
from starterbus.transports.modbus.master.exchange import Exchange, TransactionPolicy
from starterbus.transports.modbus.master.mbap import encode_adu

NAME = "gateway.plant.test"  # a name no name server knows: the test's stand-in answers for it
REAL = socket.getaddrinfo


class NameServer:
    """``socket.getaddrinfo`` for :data:`NAME`: answers with ``host`` (or raises ``error``), each call logged with
    its thread's name; while ``hold`` is clear, a call waits for it (a slow name server)."""

    def __init__(self, host: str = "127.0.0.1") -> None:
        self.host = host
        self.error: OSError | None = None
        self.calls: list[str] = []
        self.hold = threading.Event()
        self.hold.set()

    def __call__(self, host: str, port: Any, *args: Any, **kwargs: Any) -> Any:
        if host != NAME:
            return REAL(host, port, *args, **kwargs)
        self.calls.append(threading.current_thread().name)
        assert self.hold.wait(10), "the test never let the lookup go"
        if self.error is not None:
            raise self.error
        return REAL(self.host, port, *args, **kwargs)


@pytest.fixture
def names(monkeypatch: pytest.MonkeyPatch) -> Iterator[NameServer]:
    server = NameServer()
    monkeypatch.setattr(socket, "getaddrinfo", server)
    forget_addresses()
    yield server
    server.hold.set()
    assert wait_until(lambda: not resolve._looking, 5, 0.001)
    forget_addresses()


def serve_once(listener: socket.socket, answered: list[int]) -> Callable[[], None]:
    """Accept one connection, answer one FC03 read of one register with 7, close the connection."""

    def run() -> None:
        conn, _ = listener.accept()
        with conn:
            request = conn.recv(260)
            transaction, unit = int.from_bytes(request[:2], "big"), request[6]
            conn.sendall(encode_adu(transaction, unit, bytes((3, 2, 0, 7))))
            answered.append(transaction)

    return run


def test_the_name_is_looked_up_by_the_opener_never_by_the_loop(names: NameServer) -> None:
    with socket.create_server(("127.0.0.1", 0)) as listener:
        port = listener.getsockname()[1]
        answered: list[int] = []
        read = Exchange(ReadRequest(1, 0, 1), TransactionPolicy(timeout=2.0, retries=0), 0.0)
        server = threading.Thread(target=serve_once(listener, answered))
        server.start()
        connection = MbapConnection(NAME, port, 1, 2.0)
        try:
            assert names.calls == [threading.current_thread().name]
            assert connection.run(read) == ReadResponse(1, (7,))
            server.join(5)
            server = threading.Thread(target=serve_once(listener, answered))
            server.start()
            names.hold.clear()  # a name server that would hold anyone asking it now
            assert connection.run(read) == ReadResponse(1, (7,))  # the peer closed: made again at the kept address
            assert len(names.calls) == 1 and connection.connects == 2
            server.join(5)
        finally:
            names.hold.set()
            connection.close()


def test_the_loop_never_waits_on_a_slow_name_server(names: NameServer) -> None:
    names.hold.clear()
    with pytest.raises(OSError, match=f"looking up '{NAME}'"):
        kept_address(NAME, 502)  # at once: the lookup goes on in a thread of its own
    assert wait_until(lambda: names.calls == [f"starterbus-lookup {NAME}"], 5, 0.001)
    with pytest.raises(OSError, match="looking up"):
        kept_address(NAME, 502)  # still looking: no second lookup
    names.hold.set()
    assert wait_until(lambda: (NAME, 502) in resolve._kept, 5, 0.001)
    assert kept_address(NAME, 502)[3] == ("127.0.0.1", 502)
    assert len(names.calls) == 1


def test_a_failed_lookup_is_named_and_tried_again(names: NameServer) -> None:
    names.error = socket.gaierror(socket.EAI_NONAME, "Name or service not known")
    with pytest.raises(TransportError, match=f"cannot connect to gateway {NAME}:502: cannot look up '{NAME}'"):
        MbapConnection(NAME, 502, 1, 1.0)
    with pytest.raises(OSError, match="looking up"):
        kept_address(NAME, 502)
    assert wait_until(lambda: (NAME, 502) in resolve._failed and not resolve._looking, 5, 0.001)
    with pytest.raises(OSError, match="the last lookup: .*Name or service not known"):
        kept_address(NAME, 502)
    names.error = None  # the name server is back: the next connect's ask looks the name up again
    with pytest.raises(OSError, match="looking up"):
        kept_address(NAME, 502)
    assert wait_until(lambda: (NAME, 502) in resolve._kept, 5, 0.001)
    assert kept_address(NAME, 502)[3] == ("127.0.0.1", 502)


def test_after_a_failed_connect_the_name_is_looked_up_again(names: NameServer) -> None:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]  # closed again: nothing listens there
    assert address_of(NAME, port)[3] == ("127.0.0.1", port)
    connection = MbapConnection(NAME, port, 1, 1.0, connect=False)
    names.host = "127.0.0.2"  # the device server was given another address
    try:
        read = Exchange(ReadRequest(1, 0, 1), TransactionPolicy(timeout=1.0, retries=0), 0.0)
        with pytest.raises(TransportError, match=f"cannot connect to gateway {NAME}:{port}"):
            connection.run(read)
        assert wait_until(lambda: kept_address(NAME, port)[3] == ("127.0.0.2", port), 5, 0.001)
        assert names.calls[-1] == f"starterbus-lookup {NAME}"
    finally:
        connection.close()


def test_a_numeric_address_needs_no_name_server(names: NameServer) -> None:
    assert kept_address("127.0.0.1", 502)[3] == ("127.0.0.1", 502)
    assert address_of("::1", 502)[3][:2] == ("::1", 502)
    assert not names.calls and not resolve._kept
