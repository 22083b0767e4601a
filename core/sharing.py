"""Resources that several devices share in one process: a serial line, a gateway connection, a CAN bus.

``SharedPool.acquire(key, factory)`` returns the one live resource for ``key`` (creating it on first use)
and counts users; ``release`` closes it when the last user is gone. Transports use it so that two devices
on one RS485 line, or two slaves behind one DeviceNet scanner, go through one object that serialises access.
Every pool registers itself: :func:`leases` counts the resources held in the whole process, which is how the
conformance kit checks that closing a transport gave back what opening it took.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Callable, Hashable
from typing import Any, Generic, Protocol, TypeVar


class Closable(Protocol):
    def close(self) -> None: ...


R = TypeVar("R", bound=Closable)


class SharedPool(Generic[R]):
    def __init__(self, name: str = "") -> None:
        self.name = name  #: what the pool holds, for messages ("acme-loop lines")
        self._lock = threading.Lock()
        self._items: dict[Hashable, tuple[R, int]] = {}
        _POOLS.add(self)

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

    def leases(self) -> dict[Hashable, int]:
        """Key -> users of every live resource of this pool."""
        with self._lock:
            return {key: users for key, (_, users) in self._items.items()}


_POOLS: weakref.WeakSet[SharedPool[Any]] = weakref.WeakSet()


def leases() -> dict[str, int]:
    """``"POOL KEY"`` -> users, over every pool of the process (a serial port, a gateway, a CAN bus...)."""
    out: dict[str, int] = {}
    for pool in list(_POOLS):
        out.update({f"{pool.name or 'pool'} {key!r}": users for key, users in pool.leases().items()})
    return out
