"""Resources that several devices share in one process: a serial line, a gateway connection, a CAN bus.

``SharedPool.acquire(key, factory)`` returns the one live resource for ``key`` (creating it on first use)
and counts users; ``release`` closes it when the last user is gone. Transports use it so that two devices
on one RS485 line, or two slaves behind one DeviceNet scanner, go through one object that serialises access.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Hashable
from typing import Generic, Protocol, TypeVar


class Closable(Protocol):
    def close(self) -> None: ...


R = TypeVar("R", bound=Closable)


class SharedPool(Generic[R]):
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._items: dict[Hashable, tuple[R, int]] = {}

    def acquire(self, key: Hashable, factory: Callable[[], R]) -> R:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                resource = factory()
                self._items[key] = (resource, 1)
                return resource
            resource, users = item
            self._items[key] = (resource, users + 1)
            return resource

    def release(self, key: Hashable) -> None:
        with self._lock:
            item = self._items.get(key)
            if item is None:
                return
            resource, users = item
            if users > 1:
                self._items[key] = (resource, users - 1)
                return
            del self._items[key]
        resource.close()

    def users(self, key: Hashable) -> int:
        with self._lock:
            item = self._items.get(key)
            return item[1] if item else 0
