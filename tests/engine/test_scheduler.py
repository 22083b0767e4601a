"""The scheduler and the stream driver with the toy engine over a socket pair: whoever waits drives (no thread
started), followers served through the inbox and handed the loop, a loop thread of its own, containment of a
broken engine, the outer bound, and blocking calls from inside the loop refused."""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterator
from concurrent.futures import Future
from typing import Any

import pytest

from starterbus.core.engine import Ticket, TicketState
from starterbus.core.errors import TimeoutError, TransportError
from starterbus.core.media import StreamDriver, TcpDriver
from starterbus.core.scheduler import Scheduler, SchedulerReentryError
from starterbus.tests.engine.toy import ToyEngine, ToyPeer

Driver = StreamDriver[ToyEngine]


class Peer:
    """The far end of a socket pair, in a thread: answers each request, except those ``held`` until released."""

    def __init__(self, sock: socket.socket, held: bytes = b"") -> None:
        self.sock, self.held = sock, held
        self.release = threading.Event()
        self.closing = False
        self.seen: list[bytes] = []
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self) -> None:
        toy, later = ToyPeer(), []
        while data := self.sock.recv(4096):
            for reply in toy.replies(data):
                self.seen.append(reply[2:])
                if reply[2:] == self.held.upper():
                    later.append(reply)
                else:
                    self.sock.sendall(reply)
            if later and self.release.wait(5) and not self.closing:
                self.sock.sendall(b"".join(later))
                later = []

    def close(self) -> None:
        self.closing = True
        self.release.set()
        self.sock.shutdown(socket.SHUT_RDWR)
        self.thread.join(5)
        self.sock.close()


@pytest.fixture
def scheduler() -> Iterator[Scheduler]:
    sched = Scheduler()
    yield sched
    sched.stop()


def driver_with_peer(sched: Scheduler, held: bytes = b"", **toy: Any) -> tuple[Driver, Peer]:
    ours, theirs = socket.socketpair()
    driver: Driver = StreamDriver("toy", lambda: ToyEngine(**toy), ours)
    sched.wait(sched.call(lambda now: sched.add(driver)), 5, "add")
    return driver, Peer(theirs, held)


def ask(sched: Scheduler, driver: Driver, request: bytes) -> Ticket[bytes, bytes]:
    ticket: Ticket[bytes, bytes] = sched.wait(sched.submit(driver, request), 5, f"ask {request!r}")
    return ticket


def test_the_waiting_caller_drives_the_loop_itself(scheduler: Scheduler) -> None:
    threads = {t.ident for t in threading.enumerate()}
    driver, peer = driver_with_peer(scheduler)
    try:
        assert ask(scheduler, driver, b"abc").outcome() == b"ABC"
        assert ask(scheduler, driver, b"def").outcome() == b"DEF"
        assert not scheduler.running and driver.pending == 0
        assert {t.ident for t in threading.enumerate()} - threads == {peer.thread.ident}  # the peer's only
    finally:
        peer.close()


def test_a_follower_is_served_by_the_leader_then_takes_over(scheduler: Scheduler) -> None:
    """``a`` leads; ``b`` is submitted from another thread meanwhile and held by the peer until ``a`` is done:
    the leader sent it (through the inbox and the wake pipe), and ``b``'s thread drives the loop to its end."""
    driver, peer = driver_with_peer(scheduler, held=b"b", outstanding=2, timeout=5.0)
    results: dict[str, Ticket[bytes, bytes]] = {}
    leading = threading.Event()

    def lead() -> None:
        future = scheduler.submit(driver, b"a")
        leading.set()
        results["a"] = scheduler.wait(future, 5, "a")

    first = threading.Thread(target=lead)
    try:
        first.start()
        assert leading.wait(5)
        second = threading.Thread(target=lambda: results.setdefault("b", ask(scheduler, driver, b"b")))
        second.start()
        first.join(5)
        assert results["a"].outcome() == b"A" and "b" not in results
        peer.release.set()
        second.join(5)
        assert results["b"].outcome() == b"B"
    finally:
        peer.release.set()
        peer.close()


def test_the_loop_s_own_thread_serves_followers_and_stops(scheduler: Scheduler) -> None:
    driver, peer = driver_with_peer(scheduler)
    try:
        scheduler.start()
        assert "starterbus-io" in {t.name for t in threading.enumerate()}
        assert ask(scheduler, driver, b"x").outcome() == b"X"
        scheduler.stop()
        assert not scheduler.running and "starterbus-io" not in {t.name for t in threading.enumerate()}
        assert ask(scheduler, driver, b"y").outcome() == b"Y"  # led by the caller again
    finally:
        peer.close()


class Broken(ToyEngine):
    def receive(self, data: bytes | None, now: float) -> None:
        raise RuntimeError("a bug")


def test_an_engine_that_raises_fails_its_own_tickets_only(scheduler: Scheduler) -> None:
    good, good_peer = driver_with_peer(scheduler)
    ours, theirs = socket.socketpair()
    bad: Driver = StreamDriver("bad", Broken, ours)
    scheduler.wait(scheduler.call(lambda now: scheduler.add(bad)), 5, "add")
    bad_peer = Peer(theirs)
    try:
        failed = ask(scheduler, bad, b"q")
        assert failed.state is TicketState.FAILED and isinstance(failed.error, TransportError)
        assert str(failed.error) == "bad: RuntimeError: a bug" and bad.crashes == 1
        assert ask(scheduler, good, b"ok").outcome() == b"OK"
    finally:
        good_peer.close()
        bad_peer.close()


def test_a_wait_past_its_outer_bound_names_the_stall(scheduler: Scheduler) -> None:
    never: Future[None] = Future()
    with pytest.raises(TimeoutError, match=r"poll of nothing: not done within 0.05 s: the I/O loop stalled"):
        scheduler.wait(never, 0.05, "poll of nothing")


def test_a_blocking_wait_from_inside_the_loop_is_refused(scheduler: Scheduler) -> None:
    inner = scheduler.call(lambda now: scheduler.wait(scheduler.call(lambda now: 1), 5, "read from a sink"))
    with pytest.raises(SchedulerReentryError, match="read from a sink: a blocking call from inside the I/O loop"):
        scheduler.wait(inner, 5, "outer")
    scheduler.start()
    inner = scheduler.call(lambda now: scheduler.wait(scheduler.call(lambda now: 1), 5, "status in a callback"))
    with pytest.raises(SchedulerReentryError, match="status in a callback"):
        scheduler.wait(inner, 5, "outer")


def test_a_lost_stream_fails_what_was_sent(scheduler: Scheduler) -> None:
    driver, peer = driver_with_peer(scheduler, held=b"z", timeout=5.0)
    future = scheduler.submit(driver, b"z")
    assert scheduler.wait(scheduler.call(lambda now: None), 5, "a turn") is None
    peer.close()  # with the request unanswered
    ticket = scheduler.wait(future, 5, "z")
    assert ticket.state is TicketState.FAILED and isinstance(ticket.error, TransportError)
    assert driver.stream is None


def test_a_tcp_connection_is_made_on_demand_and_backs_off_when_refused(scheduler: Scheduler) -> None:
    server = socket.create_server(("127.0.0.1", 0))
    host, port = server.getsockname()[:2]
    driver: TcpDriver[ToyEngine] = TcpDriver(host, port, ToyEngine, connect_timeout=2.0)
    scheduler.wait(scheduler.call(lambda now: scheduler.add(driver)), 5, "add")
    peers: list[Peer] = []
    accepting = threading.Thread(target=lambda: peers.append(Peer(server.accept()[0])))
    accepting.start()
    try:  # connected without blocking the loop, when the caller's wait drives it
        assert ask(scheduler, driver, b"hi").outcome() == b"HI" and driver.connects == 1
    finally:
        accepting.join(5)
        peers[0].close()
        server.close()
    refused = ask(scheduler, driver, b"again")  # the peer is gone: the loss is seen, a new connection refused
    assert refused.state is TicketState.FAILED and "cannot connect to 127.0.0.1" in str(refused.error)
    backing_off = ask(scheduler, driver, b"once more")
    assert "reconnecting in 0.1 s (cannot connect" in str(backing_off.error)
    scheduler.wait(scheduler.call(driver.close), 5, "close")
    assert "is closed" in str(ask(scheduler, driver, b"closed").error)


def test_threads_sharing_a_driver_each_get_their_own_answers(scheduler: Scheduler) -> None:
    """Four threads, no loop thread: leadership passes between them as their tickets end; every answer goes to
    the request it answers, and nobody waits for the outer bound."""
    driver, peer = driver_with_peer(scheduler, outstanding=3, timeout=5.0)
    wrong: list[tuple[bytes, bytes | None]] = []

    def work(name: str) -> None:
        for n in range(100):
            request = f"{name}{n}".encode()
            ticket = ask(scheduler, driver, request)
            if ticket.result != request.upper():
                wrong.append((request, ticket.result))

    workers = [threading.Thread(target=work, args=(name,)) for name in "abcd"]
    try:
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join(30)
        assert not any(w.is_alive() for w in workers) and not wrong and driver.pending == 0
    finally:
        peer.close()


def test_run_leads_and_withdraws_what_follows_a_failure(scheduler: Scheduler) -> None:
    """``run``: the caller leads without a future; ``a`` goes unanswered (timeout), so ``b``, queued behind it,
    is withdrawn in the step that failed ``a``, never sent; a's late answer is stale, the next run's are theirs."""
    driver, peer = driver_with_peer(scheduler, held=b"a", timeout=0.05, attempts=1)
    try:
        a, b = scheduler.run(driver, [b"a", b"b"], 5, "a then b")
        assert a.state is TicketState.FAILED and isinstance(a.error, TimeoutError)
        assert b.state is TicketState.CANCELLED and b.attempts == 0 and driver.pending == 0
        peer.release.set()  # the answer to a comes now, late: stale, before c's
        assert [t.outcome() for t in scheduler.run(driver, [b"c", b"d"], 5, "c, d")] == [b"C", b"D"]
        assert b"B" not in peer.seen and driver.engine.stale == 1 and not scheduler.running
    finally:
        peer.close()
