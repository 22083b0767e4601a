"""The reader thread of a CAN bus without a descriptor (python-can's ``virtual``, ``remote``, some vendor
interfaces): it blocks in ``recv``, queues the frames and writes one wake byte to a pipe when the queue was
empty, so a burst of frames costs the loop one wake-up. The loop waits on :attr:`CanReader.fd`."""

from __future__ import annotations

import collections
import os
import threading
import time

import can

__all__ = ["READER_WAIT", "CanReader"]

READER_WAIT = 0.1  # s the thread blocks in recv before it looks whether it should stop


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
            if message is None:
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
