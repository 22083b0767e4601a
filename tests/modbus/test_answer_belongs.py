"""An answer is only ever delivered to the request it belongs to (issue 11, item 1).

A scripted slave (``fault_peer.SequencePeer``) on a real pty, or behind a TCP listener, puts in every register
the number of the request it answers, and misbehaves on a random schedule: late answers (by a varying margin
after the master's deadline), answers twice, split, after garbage, with trailing bytes, bad CRC, another unit.
Whatever the schedule, every value the master returns comes from the last request it sent; faults may cost
errors, never a foreign value. Short timeouts keep thousands of reads within seconds.
"""

from __future__ import annotations

import os
import random
import socket
import sys
import threading
import tty
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from starterbus.core.device import open_device
from starterbus.core.errors import DecodeError, RemoteDeviceError, TimeoutError
from starterbus.tests.modbus.fault_peer import CHOICES, FAULTS, SequencePeer, Step
from starterbus.transports.modbus.client import ModbusRtuTransport

TIMEOUT = 0.005
QUARANTINE = 0.01
BAUD = 19200
PARAMS = f"unit=2&baudrate={BAUD}&timeout={TIMEOUT}&quarantine={QUARANTINE}"

schedules = st.lists(st.tuples(st.sampled_from(CHOICES), st.floats(0.0, 0.999)), min_size=1, max_size=40)
FEW = settings(max_examples=5, deadline=None, derandomize=True, database=None, suppress_health_check=list(HealthCheck))
MANY = settings(FEW, max_examples=14)


#: how a test reads ``count`` registers from ``address``: the transport's blocking read, or a poll task
Reader = Callable[[ModbusRtuTransport, int, int], tuple[int, ...]]


def blocking_read(transport: ModbusRtuTransport, address: int, count: int) -> tuple[int, ...]:
    return transport.read_registers(address, count)


@dataclass
class Tally:
    values: int = 0
    errors: dict[str, int] = field(default_factory=dict)


def read_and_check(
    transport: ModbusRtuTransport,
    peer: SequencePeer,
    reads: int,
    seed: int,
    counts: tuple[int, ...] = (2, 2, 2, 1, 4),
    read: Reader = blocking_read,
) -> Tally:
    """``reads`` FC03 of random address and count; every returned value must answer the last request sent."""
    rng = random.Random(seed)
    tally = Tally()
    line = transport.line
    peer.watch(line.link)
    for _ in range(reads):
        # mostly one shape, so that a stray answer would pass the length and byte count checks
        address, count = rng.randrange(0x1000), rng.choice(counts)
        try:
            values = read(transport, address, count)
        except (DecodeError, TimeoutError, RemoteDeviceError) as exc:
            name = type(exc).__name__
            tally.errors[name] = tally.errors.get(name, 0) + 1
            continue
        seq = line.requests - 1  # the master's own count: the frame it wrote last
        assert values == tuple((seq + k) & 0xFFFF for k in range(count)), (
            f"read {count} from 0x{address:04X} returned {values}, request #{seq} was the last one sent"
        )
        assert peer.requests[seq] == (address, count)
        tally.values += 1
    return tally


@contextmanager
def quick_thread_switches() -> Iterator[None]:
    """The peer is a thread of this process: let it have the GIL within 0.2 ms, not 5 ms, of asking."""
    before = sys.getswitchinterval()
    sys.setswitchinterval(0.0002)
    try:
        yield
    finally:
        sys.setswitchinterval(before)


@contextmanager
def pty_peer(schedule: list[Step], seed: int) -> Iterator[tuple[str, SequencePeer]]:
    master, slave = os.openpty()
    tty.setraw(slave)
    with quick_thread_switches():
        peer = SequencePeer(master, schedule, timeout=TIMEOUT, quarantine=QUARANTINE, baudrate=BAUD, seed=seed)
        try:
            yield os.ttyname(slave), peer.start()
        finally:
            peer.close()
        os.close(master)
        os.close(slave)


@contextmanager
def tcp_peer(schedule: list[Step], seed: int) -> Iterator[tuple[str, SequencePeer]]:
    """A local TCP listener; the peer serves the first connection."""
    server = socket.create_server(("127.0.0.1", 0))
    holder: dict[str, object] = {}
    peer = SequencePeer(-1, schedule, timeout=TIMEOUT, quarantine=QUARANTINE, baudrate=BAUD, seed=seed)

    def accept() -> None:
        conn, _ = server.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # pieces leave when written, as on a wire
        holder["conn"] = conn
        peer.fd = conn.fileno()
        peer.start()

    thread = threading.Thread(target=accept, daemon=True)
    thread.start()
    try:
        with quick_thread_switches():
            yield f"127.0.0.1:{server.getsockname()[1]}", peer
    finally:
        thread.join(timeout=5)
        if "conn" in holder:
            peer.close()
            holder["conn"].close()  # type: ignore[attr-defined]
        server.close()


@contextmanager
def rtu_transport(url: str) -> Iterator[ModbusRtuTransport]:
    with open_device(url, "jjr5000") as device:
        transport = device.transport
        assert isinstance(transport, ModbusRtuTransport)
        yield transport


def run(url: str, peer: SequencePeer, reads: int, seed: int, read: Reader = blocking_read) -> Tally:
    with rtu_transport(url) as transport:
        tally = read_and_check(transport, peer, reads, seed, read=read)
    assert tally.values + sum(tally.errors.values()) == reads
    if peer.sent_faults.get("ok") and peer.skipped == 0:
        assert tally.values, tally  # good answers are values (the checks above had something to check)
    return tally


@MANY
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_posix_fast_path_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with pty_peer(schedule, seed) as (path, peer):
        run(f"modbus-rtu://{path}?{PARAMS}&retries=1", peer, 80, seed)


@FEW
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_pyserial_path_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with pty_peer(schedule, seed) as (path, peer):
        run(f"modbus-rtu://{path}?{PARAMS}&io=pyserial&retries=1", peer, 60, seed)


@FEW
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_pyserial_socket_url_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with tcp_peer(schedule, seed) as (address, peer):
        run(f"modbus-rtu+socket://{address}?{PARAMS}&retries=1", peer, 60, seed)


@FEW
@given(schedule=schedules, seed=st.integers(0, 2**16))
def test_tcp_fast_path_never_returns_a_foreign_value(schedule: list[Step], seed: int) -> None:
    with tcp_peer(schedule, seed) as (address, peer):
        run(f"modbus-rtu+tcp://{address}?{PARAMS}&retries=1", peer, 60, seed)


def test_every_fault_in_turn_costs_errors_not_values() -> None:
    """Each fault after a good answer, in a fixed schedule: the good answers are values, the faults errors."""
    schedule: list[Step] = []
    for fault in FAULTS:
        schedule += [("ok", 0.0), (fault, 0.5), ("ok", 0.0)]
    with pty_peer(schedule, 1) as (path, peer):
        tally = run(f"modbus-rtu://{path}?{PARAMS}&retries=0", peer, len(schedule), 1)
    if peer.skipped == 0:
        # every fault but slow and split is one error (retries=0); good answers are values (a loaded machine
        # may turn one into a timeout, so no exact count)
        assert sum(tally.errors.values()) >= len(FAULTS) - 2 and tally.values, tally


def test_late_answers_by_every_margin_are_never_values() -> None:
    """Late answers from just after the deadline to nearly the end of the quarantine, each followed by good
    answers: none is ever taken for the next request's answer (all reads have the same shape)."""
    schedule: list[Step] = []
    for i in range(12):
        schedule += [("late" if i % 2 else "late_split", i / 12), ("ok", 0.0)]
    with pty_peer(schedule, 3) as (path, peer), rtu_transport(f"modbus-rtu://{path}?{PARAMS}&retries=0") as transport:
        tally = read_and_check(transport, peer, 2 * len(schedule), 3, (2,))
    if peer.skipped == 0:
        # a late answer is a timeout, or "truncated" when its first piece beat the master's own deadline check;
        # usually its quarantine costs the next read too, but a master held up by a loaded machine may get past
        # that window unharmed (seen once: 23 of 24), so only one error per late answer is certain
        late = sum(1 for kind, _ in schedule if kind != "ok")
        assert sum(tally.errors.values()) >= late and tally.values, tally


def test_one_late_answer_is_not_the_next_reads_value() -> None:
    """The bug measured in issue 11: after one late answer, the next read of another register got its values."""
    late_then_ok: list[Step] = [("late", 0.99), ("ok", 0.0)]
    with pty_peer(late_then_ok, 2) as (path, peer), rtu_transport(f"modbus-rtu://{path}?{PARAMS}&retries=0") as t:
        peer.watch(t.line.link)
        with pytest.raises(TimeoutError):
            t.read_registers(0x0100, 2)
        assert t.read_registers(0x0200, 2) == (1, 2)  # request #1's own answer
