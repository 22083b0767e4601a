"""Entry-point groups, each a :class:`Registry` of named plugins loaded lazily.

The generic part of plugin discovery, below everything it discovers: the registries themselves live where their
kind is defined (address spaces and transports in :mod:`starterbus.core.address_space`, profiles and overlays in
:mod:`starterbus.core.registry`). A plugin that fails to import is reported with its error and does not affect the
others; two entry points with one name in one group is an error, never a silent override.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Generic, TypeVar

from starterbus.core.errors import PluginError

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

T = TypeVar("T")


@dataclass
class PluginEntry(Generic[T]):
    name: str
    group: str
    entry_points: list[EntryPoint]
    loaded: T | None = None
    error: str | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def distributions(self) -> list[str]:
        names = []
        for ep in self.entry_points:
            dist = ep.dist
            names.append(f"{dist.name} {dist.version}" if dist is not None else "?")
        return names

    @property
    def target(self) -> str:
        return ", ".join(ep.value for ep in self.entry_points)


class Registry(Generic[T]):
    """Entry points of one group, by name; each loaded on first use and cached.

    ``convert`` turns what an entry point gives into the plugin (or raises, naming why it is not one);
    ``on_reset`` runs after :meth:`reset` (to forget what was derived from the plugins).
    """

    def __init__(
        self, group: str, convert: Callable[[str, object], T], on_reset: Callable[[], None] | None = None
    ) -> None:
        self.group = group
        self._convert = convert
        self._on_reset = on_reset
        self._entries: dict[str, PluginEntry[T]] | None = None
        self._lock = threading.Lock()

    def _scan(self) -> dict[str, PluginEntry[T]]:
        with self._lock:
            if self._entries is None:
                from importlib.metadata import entry_points  # only when a command needs plugins: start-up

                entries: dict[str, PluginEntry[T]] = {}
                seen: set[tuple[str, str]] = set()
                for ep in entry_points(group=self.group):
                    # one distribution visible twice on sys.path is one plugin, not a clash
                    ident = (ep.name, ep.value)
                    if ident in seen:
                        continue
                    seen.add(ident)
                    entries.setdefault(ep.name, PluginEntry(ep.name, self.group, [])).entry_points.append(ep)
                for entry in entries.values():
                    if len(entry.entry_points) > 1:
                        entry.error = (
                            f"{len(entry.entry_points)} plugins claim the name {entry.name!r} in {self.group}: "
                            f"{entry.target} (from {', '.join(entry.distributions)}); uninstall one"
                        )
                self._entries = entries
            return self._entries

    def names(self) -> list[str]:
        return sorted(self._scan())

    def entries(self) -> list[PluginEntry[T]]:
        return [self._scan()[n] for n in self.names()]

    def get(self, name: str) -> T:
        entries = self._scan()
        entry = entries.get(name)
        if entry is None:
            known = ", ".join(sorted(entries)) or "none installed"
            raise PluginError(f"no {self.group} plugin named {name!r} (installed: {known})")
        return self._load(entry)

    def _load(self, entry: PluginEntry[T]) -> T:
        with entry._lock:
            if entry.loaded is not None:
                return entry.loaded
            if entry.error is None:
                try:
                    obj = entry.entry_points[0].load()
                    entry.loaded = self._convert(entry.name, obj)
                except Exception as exc:
                    detail = f"{type(exc).__name__}: {exc}"
                    entry.error = f"cannot load {self.group} plugin {entry.name!r} ({entry.target}): {detail}"
            if entry.loaded is None:
                raise PluginError(entry.error)
            return entry.loaded

    def load_all(self) -> list[PluginEntry[T]]:
        """Try to load every plugin (for listings); failures stay in ``entry.error``."""
        entries = self.entries()
        for entry in entries:
            try:
                self._load(entry)
            except PluginError:
                pass
        return entries

    def reset(self) -> None:
        """Forget what was scanned (after installing a distribution at run time)."""
        with self._lock:
            self._entries = None
        if self._on_reset is not None:
            self._on_reset()


__all__ = ["PluginEntry", "Registry"]
