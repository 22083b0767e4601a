"""Waiting on many descriptors at once with a timeout to the microsecond (the scheduler's, and the fleet
multiplexer's), and the timer slack of a thread that waits so."""

from __future__ import annotations

import math
import select
from typing import Generic, TypeVar

__all__ = ["FD_SETSIZE", "Waiter", "precise_timers"]

D = TypeVar("D")

#: select() takes descriptors below this (glibc's FD_SETSIZE)
FD_SETSIZE = 1024
_PR_SET_TIMERSLACK = 29


def precise_timers() -> None:
    """Linux: 1 us timer slack for the calling thread instead of 50 us, so that a wait for a line's silent
    interval ends when the interval does. Best effort."""
    try:
        import ctypes

        ctypes.CDLL(None).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass


class Waiter(Generic[D]):
    """Waits until registered descriptors are ready, with a timeout to the microsecond: ``select`` (epoll
    counts whole milliseconds, which would stretch every silent interval by up to one), or ``poll`` (whole
    milliseconds too) while a descriptor is beyond ``select``'s limit. Neither keeps state in the kernel, so a
    line reopened under the same descriptor number is watched like the old one. A descriptor is watched for
    input, or with ``write=True`` for writability (a connection being made)."""

    def __init__(self) -> None:
        self._data: dict[int, D] = {}
        self._readers: dict[int, None] = {}  # ordered sets of the descriptors watched
        self._writers: dict[int, None] = {}
        self._lists: tuple[list[int], list[int]] | None = ([], [])  # select's sets, made again after a change
        self._poll: select.poll | None = None

    def register(self, fd: int, data: D, write: bool = False) -> None:
        """Watch ``fd`` with ``data`` (replacing what it was registered with)."""
        if fd in self._data:
            self.unregister(fd)
        self._data[fd] = data
        (self._writers if write else self._readers)[fd] = None
        self._lists = None
        if self._poll is not None:
            self._poll.register(fd, select.POLLOUT if write else select.POLLIN)
        elif fd >= FD_SETSIZE:
            self._poll = select.poll()
            for known in self._readers:
                self._poll.register(known, select.POLLIN)
            for known in self._writers:
                self._poll.register(known, select.POLLOUT)

    def watcher(self, fd: int) -> D | None:
        """The data ``fd`` is registered with (None: not registered)."""
        return self._data.get(fd)

    def unregister(self, fd: int) -> None:
        del self._data[fd]
        self._readers.pop(fd, None)
        self._writers.pop(fd, None)
        self._lists = None
        if self._poll is not None:
            self._poll.unregister(fd)
            if not self._data or max(self._data) < FD_SETSIZE:
                self._poll = None

    def wait(self, timeout: float) -> list[D]:
        """The data of the descriptors that are ready (or closed, or failed), after at most ``timeout`` s."""
        if self._poll is not None:
            return [self._data[fd] for fd, _ in self._poll.poll(math.ceil(timeout * 1000))]
        lists = self._lists
        if lists is None:  # (a line waiting for the rest of an answer leaves the set and comes back: often)
            lists = self._lists = (list(self._readers), list(self._writers))
        readers, writers = lists
        if not writers:
            return [self._data[fd] for fd in select.select(readers, (), (), timeout)[0]]
        readable, writable, _ = select.select(readers, writers, (), timeout)
        return [self._data[fd] for fd in (*readable, *writable)]

    def close(self) -> None:
        self._poll = None
