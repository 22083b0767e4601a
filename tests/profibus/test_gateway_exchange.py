"""A station's DP exchange over a Modbus TCP gateway, on the I/O engine, against a gateway the test plays byte by
byte: transcripts of what goes on the wire (an FC16 per run of words to write, then the FC03/FC04 read), the
stations' turns on one connection, and the rules that keep a wrong value out (a late answer is stale, never the
inputs of a later exchange; the gateway's exception answers are typed errors naming it)."""

from __future__ import annotations

import socket
from collections.abc import Callable, Iterator
from concurrent.futures import Future
from typing import Any

import pytest

from starterbus.core.engine import TicketState
from starterbus.core.errors import RemoteDeviceError, TimeoutError, TransportError
from starterbus.core.scheduler import Scheduler
from starterbus.testing import wait_until
from starterbus.transports.modbus.driver.tcp_line import MbapConnection
from starterbus.transports.modbus.master.mbap import HEADER, HEADER_LENGTH, encode_adu
from starterbus.transports.profibus_pkw.codec.codes import Ppo, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import pkw_request
from starterbus.transports.profibus_pkw.driver.gateway import GatewayStation, StationDriver
from starterbus.transports.profibus_pkw.master.handshake import Limits, PkwEngine
from starterbus.transports.profibus_pkw.master.station import FreshInputs, PkwTask, StationEngine

TIMEOUT = 0.2  # the gateway connection's transaction timeout
Adu = tuple[int, int, bytes]  # transaction id, unit, PDU


def h(text: str) -> bytes:
    return bytes.fromhex(text)


class ScriptedGateway:
    """The test is the gateway: it reads each MBAP request the connection writes and answers as it is told."""

    def __init__(self) -> None:
        self.listener = socket.create_server(("127.0.0.1", 0))
        self.port: int = self.listener.getsockname()[1]
        self.conn: socket.socket | None = None
        self._buffer = b""

    def close(self) -> None:
        if self.conn is not None:
            self.conn.close()
        self.listener.close()

    def _take(self) -> Adu | None:
        buffer = self._buffer
        if len(buffer) < HEADER_LENGTH:
            return None
        transaction, _, length, unit = HEADER.unpack_from(buffer)
        end = HEADER_LENGTH - 1 + length
        if len(buffer) < end:
            return None
        self._buffer = buffer[end:]
        return transaction, unit, buffer[HEADER_LENGTH:end]

    def _read(self) -> None:
        if self.conn is None:
            self.listener.settimeout(0)
            try:
                self.conn, _ = self.listener.accept()
            except BlockingIOError:
                return
            self.conn.setblocking(False)
        try:
            self._buffer += self.conn.recv(4096)
        except BlockingIOError:
            pass

    def request(self, loop: Scheduler) -> Adu:
        """The next request the connection writes (the loop turned until it came)."""
        got: list[Adu] = []

        def came() -> bool:
            loop.try_turn()
            self._read()
            adu = self._take()
            if adu is not None:
                got.append(adu)
            return bool(got)

        assert wait_until(came, 5, 0.001), "the connection wrote nothing"
        return got[0]

    def nothing_more(self, loop: Scheduler) -> bool:
        for _ in range(3):
            loop.try_turn()
        self._read()
        return self._take() is None

    def answer(self, adu: Adu, pdu: bytes) -> None:
        assert self.conn is not None
        self.conn.sendall(encode_adu(adu[0], adu[1], pdu))


@pytest.fixture
def gateway() -> Iterator[ScriptedGateway]:
    peer = ScriptedGateway()
    yield peer
    peer.close()


@pytest.fixture
def loop() -> Scheduler:
    return Scheduler()  # a loop of the test's own: no other driver, turned by the test


def connect(port: int, loop: Scheduler) -> MbapConnection:
    """The gateway's connection on the test's loop, made on the first exchange (as a gateway channel makes it)."""
    return MbapConnection("127.0.0.1", port, 1, TIMEOUT, loop, connect=False)


def station(
    loop: Scheduler,
    connection: MbapConnection,
    ppo: Ppo = Ppo.PPO1,
    *,
    control: int | None = 0,
    out: int = 10,
    inp: int = 20,
    input_function: int = 3,
) -> StationDriver:
    gateway = GatewayStation(
        connection, ppo.words, out=out, inp=inp, unit=1, input_function=input_function, timeout=TIMEOUT
    )
    engine = StationEngine(ppo, PkwEngine(limits=Limits(timeout=2.0)), where="test station", reply_within=2.0)
    engine.control = control
    driver = StationDriver(f"station out={out}", lambda: engine, gateway)
    loop.wait(loop.call(lambda now: loop.add(driver)), 5, "add the station")
    return driver


def submit(loop: Scheduler, driver: StationDriver, request: object) -> Future[Any]:
    return loop.submit(driver, request)


def settle(loop: Scheduler, done: Callable[[], bool]) -> None:
    assert wait_until(lambda: loop.try_turn() and done(), 5, 0.001), "not done"


def test_an_exchange_writes_the_outputs_then_reads_the_inputs(gateway: ScriptedGateway, loop: Scheduler) -> None:
    connection = connect(gateway.port, loop)
    driver = station(loop, connection, control=0x0009)
    future = submit(loop, driver, FreshInputs(2.0))
    write = gateway.request(loop)
    assert write[1:] == (1, h("10 00 0A 00 04 08 00 00 00 00 00 09 00 00"))  # PKW no task, STW 0x0009, 0
    gateway.answer(write, h("10 00 0A 00 04"))
    read = gateway.request(loop)
    assert read[1:] == (1, h("03 00 14 00 04")) and read[0] != write[0]
    gateway.answer(read, h("03 08 00 00 00 00 09 00 03 C0"))
    settle(loop, future.done)
    ticket = future.result()
    assert ticket.state is TicketState.DONE and ticket.result == (0, 0, 0x0900, 0x03C0)
    assert gateway.nothing_more(loop)  # cycle 0: nothing is exchanged while nobody waits
    connection.close()


@pytest.mark.parametrize(("ppo", "pdus"), [(Ppo.PPO1, [h("10 00 0A 00 02 04 00 00 00 00")]), (Ppo.PPO3, [])])
def test_a_passive_station_leaves_the_control_word_alone(
    gateway: ScriptedGateway, loop: Scheduler, ppo: Ppo, pdus: list[bytes]
) -> None:
    """Passive on PZD (outputs not readable on open): only the PKW words are written (PPO3: nothing), then the
    inputs are read with FC04 when the map says so."""
    connection = connect(gateway.port, loop)
    driver = station(loop, connection, ppo, control=None, input_function=4)
    future = submit(loop, driver, FreshInputs(2.0))
    for pdu in pdus:
        write = gateway.request(loop)
        assert write[2] == pdu
        gateway.answer(write, pdu[:5])
    read = gateway.request(loop)
    assert read[2] == bytes((4, 0, 20, 0, ppo.words))
    gateway.answer(read, bytes((4, 2 * ppo.words)) + b"\x09\x00" * ppo.words)
    settle(loop, future.done)
    assert future.result().result == (0x0900,) * ppo.words
    connection.close()


def test_a_late_answer_is_stale_never_the_inputs_of_a_later_exchange(gateway: ScriptedGateway, loop: Scheduler) -> None:
    connection = connect(gateway.port, loop)
    driver = station(loop, connection, Ppo.PPO3, control=None)
    first = submit(loop, driver, FreshInputs(2.0))
    late = gateway.request(loop)
    settle(loop, first.done)  # not answered within the timeout: the exchange failed, naming the gateway
    error = first.result().error
    assert isinstance(error, TimeoutError) and f"gateway 127.0.0.1:{gateway.port}" in str(error)
    second = submit(loop, driver, FreshInputs(2.0))
    read = gateway.request(loop)
    assert read[0] != late[0]
    gateway.answer(late, h("03 04 DE AD BE EF"))  # the first read's answer, late: its id is forgotten
    gateway.answer(read, h("03 04 09 00 00 60"))
    settle(loop, second.done)
    assert second.result().result == (0x0900, 0x0060)
    assert connection.driver.engine.stale == 1
    assert driver.engine.exchanges == 1 and driver.engine.failures == 1
    connection.close()


def test_an_exception_answer_is_a_typed_error_naming_the_gateway(gateway: ScriptedGateway, loop: Scheduler) -> None:
    connection = connect(gateway.port, loop)
    driver = station(loop, connection, control=0)
    future = submit(loop, driver, FreshInputs(2.0))
    write = gateway.request(loop)
    gateway.answer(write, h("90 02"))  # illegal data address: the read is never sent
    settle(loop, future.done)
    error = future.result().error
    assert isinstance(error, RemoteDeviceError) and (error.protocol, error.code) == ("modbus-tcp", 2)
    text = str(error)
    assert "illegal data address" in text and f"gateway 127.0.0.1:{gateway.port}" in text and "FC16" in text
    assert gateway.nothing_more(loop)
    connection.close()


def test_stations_take_turns_on_one_connection(gateway: ScriptedGateway, loop: Scheduler) -> None:
    """Two stations' exchanges queued at once: one transaction on the wire at a time, each station's read right
    after its own write, and each gets its own inputs."""
    connection = connect(gateway.port, loop)
    a = station(loop, connection, control=1, out=0, inp=100)
    b = station(loop, connection, control=2, out=4, inp=104)
    task = PkwTask(pkw_request(TaskCode.READ_PARAMETER, 3))
    futures = [submit(loop, a, FreshInputs(2.0)), submit(loop, b, FreshInputs(2.0)), submit(loop, a, task)]
    seen = []
    for _ in range(4):
        adu = gateway.request(loop)
        seen.append(adu[2][:3])
        assert gateway.nothing_more(loop), "a second transaction before the first was answered"
        pdu = adu[2]
        if pdu[0] == 0x10:
            gateway.answer(adu, pdu[:5])
        else:
            station_b = pdu[2] == 104
            gateway.answer(adu, h("03 08 00 00 00 00") + (b"\x00\x0b" if station_b else b"\x00\x0a") + b"\x00\x00")
    assert seen == [h("10 00 00"), h("03 00 64"), h("10 00 04"), h("03 00 68")]
    settle(loop, lambda: futures[0].done() and futures[1].done())
    assert futures[0].result().result[2] == 0x0A and futures[1].result().result[2] == 0x0B
    connection.close()
    settle(loop, futures[2].done)  # the PKW task of a closed connection fails, typed
    assert isinstance(futures[2].result().error, TransportError)


def test_nobody_listening_fails_the_exchange_at_once(loop: Scheduler) -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # closed again: nothing listens there
    connection = connect(port, loop)
    driver = station(loop, connection)
    future = submit(loop, driver, FreshInputs(2.0))
    settle(loop, future.done)
    error = future.result().error
    assert isinstance(error, TransportError) and f"cannot connect to gateway 127.0.0.1:{port}" in str(error)
    connection.close()


def test_a_write_not_answered_fails_the_exchange_and_its_read_never_goes(
    gateway: ScriptedGateway, loop: Scheduler
) -> None:
    connection = connect(gateway.port, loop)
    driver = station(loop, connection, control=0)
    future = submit(loop, driver, FreshInputs(2.0))
    write = gateway.request(loop)
    settle(loop, future.done)
    error = future.result().error
    assert isinstance(error, TimeoutError), error
    text = str(error)
    assert f"gateway 127.0.0.1:{gateway.port}: no answer from unit 1" in text and f"(transaction {write[0]})" in text
    assert "retry_writes" not in text  # a modbus-tcp URL parameter: nothing a PKW URL has
    assert gateway.nothing_more(loop)
    connection.close()
