"""Reading a CAN bus without a descriptor (python-can's ``virtual``, ``remote``, some vendor interfaces).

:class:`CanReader`: a thread blocks in ``recv``, queues the frames and writes one wake byte to a pipe when the
queue was empty, so a burst of frames costs the loop one wake-up. The loop waits on :attr:`CanReader.fd` with
every other descriptor.

:class:`QueueWait`: python-can's ``virtual`` bus delivers into a ``queue.Queue`` of the bus; while the CAN driver
is the only driver of the loop with something to wait on, the loop waits on that queue itself (no thread, no pipe,
no ``select``: one thread hand-off less per frame), and a wake-up of the loop puts :data:`WAKE` in it. While the
loop waits there, another thread may use the driver itself (:attr:`QueueWait.gate`: a caller submitting its own
request in its own thread, without waking the loop).
"""

from __future__ import annotations

import collections
import os
import queue
import threading
import time
from typing import Any

import can

__all__ = ["READER_WAIT", "WAKE", "CanReader", "QueueWait"]

READER_WAIT = 0.1  # s the thread blocks in recv before it looks whether it should stop
#: what wakes a loop waiting on a virtual bus's queue: an extended error frame, which no filter of ours passes and
#: the driver drops; told apart from a frame by identity
WAKE = can.Message(arbitration_id=0x1FFFFFFF, is_extended_id=True, is_error_frame=True)


class QueueWait:
    """The loop's own wait on a virtual bus's receive queue (:meth:`block`), ended early by :meth:`interrupt`
    from any thread; the frames taken (:meth:`take`) are those the bus's ``recv`` would give, before its software
    filters (the driver's routing drops what no engine wants)."""

    def __init__(self, rx: queue.Queue[Any]) -> None:
        self._rx = rx
        self.pending: list[can.Message] = []
        #: held by whoever runs the loop, except while it waits in :meth:`block`: whoever takes it then may use
        #: the driver (the loop's wait ends only once it is given back)
        self.gate = threading.Lock()
        self.gate.acquire()
        #: when the wait under way ends at the latest (the loop's clock): a request given to the driver meanwhile
        #: whose deadline comes earlier must :meth:`interrupt` it
        self.until = 0.0

    @classmethod
    def of(cls, bus: can.BusABC) -> QueueWait | None:
        """The wait for ``bus`` if it is python-can's virtual bus (its queue where this python-can keeps it)."""
        try:
            from can.interfaces.virtual import VirtualBus
        except ImportError:  # pragma: no cover - python-can without the virtual interface
            return None
        rx = getattr(bus, "queue", None)
        if type(bus) is not VirtualBus or not isinstance(rx, queue.Queue):
            return None
        return cls(rx)

    def block(self, timeout: float, until: float = 0.0) -> bool:
        """Wait up to ``timeout`` s (until ``until`` on the loop's clock) for frames (or a :meth:`interrupt`), the
        :attr:`gate` open meanwhile; True: frames are pending."""
        rx, pending, gate = self._rx, self.pending, self.gate
        self.until = until
        gate.release()
        try:
            item = rx.get(timeout=timeout) if timeout > 0 else rx.get_nowait()
        except queue.Empty:
            return bool(pending)
        finally:
            gate.acquire()  # after whoever took it meanwhile is done with the driver
        if item is not WAKE:
            pending.append(item)
        if rx.queue:  # the rest of the burst at once, under the queue's own lock (the loop is its only reader)
            if rx.maxsize > 0:  # bounded: a writer may wait for room, get() tells it
                while rx.qsize():
                    item = rx.get_nowait()
                    if item is not WAKE:
                        pending.append(item)
            else:
                with rx.mutex:
                    rest = list(rx.queue)
                    rx.queue.clear()
                pending.extend(message for message in rest if message is not WAKE)
        return bool(pending)

    def interrupt(self) -> None:
        try:
            self._rx.put_nowait(WAKE)
        except queue.Full:  # a bounded queue that is full: the wait ends anyway
            pass

    def take(self) -> list[can.Message]:
        """The frames :meth:`block` took (those queued since wait for the next one)."""
        messages, self.pending = self.pending, []
        return messages


class CanReader:
    """One thread reading ``bus`` (named ``can-reader NAME``) until :meth:`close`."""

    def __init__(self, bus: can.BusABC, name: str, errors: collections.deque[str]) -> None:
        self.bus = bus
        self.errors = errors
        self._queue: collections.deque[can.Message] = collections.deque()
        self._lock = threading.Lock()
        self._wake_r, self._wake_w = os.pipe()
        os.set_blocking(self._wake_r, False)
        os.set_blocking(self._wake_w, False)
        self._stop = threading.Event()
        self._cpu = 0.0
        #: identifiers worth queuing (the driver's routes; None: every frame): a frame no engine wants is
        #: dropped here, without waking the loop (a flood of foreign traffic costs this thread only)
        self.wanted: frozenset[int] | None = None
        self.received = 0
        self.dropped = 0
        self.thread = threading.Thread(target=self._run, name=f"can-reader {name}", daemon=True)
        self.thread.start()

    @property
    def fd(self) -> int:
        """Readable once frames are queued."""
        return self._wake_r

    @property
    def queued(self) -> int:
        return len(self._queue)

    def take(self) -> list[can.Message]:
        """Every frame queued so far (the wake bytes read first: a frame queued after is woken for again)."""
        try:
            os.read(self._wake_r, 4096)  # one byte per wake-up the loop has not served: never this many
        except (BlockingIOError, OSError):
            pass
        with self._lock:
            messages = list(self._queue)
            self._queue.clear()
        return messages

    @property
    def cpu(self) -> float:
        """CPU seconds of the thread."""
        thread = self.thread
        if thread.is_alive() and thread.ident is not None:
            try:
                return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))
            except (OSError, AttributeError):  # not Linux: the thread's own sample
                pass
        return self._cpu

    def close(self) -> None:
        self._stop.set()
        if self.thread is not threading.current_thread():
            self.thread.join(2.0)
        os.close(self._wake_r)
        os.close(self._wake_w)

    def _run(self) -> None:
        bus, queue, lock, stop, wake = self.bus, self._queue, self._lock, self._stop, self._wake_w
        count = 0
        while not stop.is_set():
            try:
                message = bus.recv(READER_WAIT)
            except Exception as exc:  # a bus that went away: seen by the loop as no more frames
                if stop.is_set():
                    break
                self.errors.append(f"receive failed: {type(exc).__name__}: {exc}")
                stop.wait(READER_WAIT)
                continue
            if message is None or message is WAKE:  # WAKE: left by a loop that waited on the queue before
                self._cpu = time.thread_time()
                continue
            self.received += 1
            wanted = self.wanted
            if wanted is not None and message.arbitration_id not in wanted:
                self.dropped += 1
                continue
            with lock:
                first = not queue
                queue.append(message)
            count += 1
            if not count & 63:
                self._cpu = time.thread_time()
            if first:
                try:
                    os.write(wake, b"!")
                except (BlockingIOError, OSError):  # the pipe is full (the loop will read) or closed at exit
                    pass
        self._cpu = time.thread_time()
