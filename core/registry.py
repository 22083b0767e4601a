"""Plugin discovery through entry points, loaded lazily.

Groups:

- ``starterbus.transports``: a :class:`TransportPlugin` instance (or a class to instantiate without arguments);
- ``starterbus.profiles``: a :class:`Profile`, a path / ``importlib.resources`` file of a profile TOML, or a
  callable returning either.

Built-ins are registered in ``pyproject.toml`` exactly like a third-party distribution would register its own.
A plugin that fails to import is reported with its error and does not affect the others; two entry points
with one name in one group is an error, never a silent override.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Generic, TypeVar

from starterbus.core.errors import PluginError, StarterbusError
from starterbus.core.profile import Profile, load_profile_file, load_profile_text
from starterbus.core.textinput import decode_text
from starterbus.core.transport import TransportPlugin

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

TRANSPORT_GROUP = "starterbus.transports"
PROFILE_GROUP = "starterbus.profiles"

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
    """Entry points of one group, by name; each loaded on first use and cached."""

    def __init__(self, group: str, convert: Callable[[str, object], T]) -> None:
        self.group = group
        self._convert = convert
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


def _to_transport(name: str, obj: object) -> TransportPlugin:
    if isinstance(obj, type) and issubclass(obj, TransportPlugin):
        obj = obj()
    if not isinstance(obj, TransportPlugin):
        raise PluginError(f"entry point {name!r} gives {obj!r}, not a TransportPlugin")
    if obj.name != name:
        raise PluginError(f"entry point {name!r} gives a plugin that calls itself {obj.name!r}")
    return obj


def _is_resource(obj: object) -> bool:
    """An ``importlib.resources`` file (a Traversable): read it, do not call it."""
    return hasattr(obj, "read_text") and hasattr(obj, "is_file")


def _to_profile(name: str, obj: object) -> Profile:
    if callable(obj) and not isinstance(obj, (Profile, Path)) and not _is_resource(obj):
        obj = obj()
    profile: Profile
    if isinstance(obj, Profile):
        profile = obj
    elif isinstance(obj, Path):
        profile = load_profile_file(obj)
    elif _is_resource(obj):
        data: bytes = obj.read_bytes()  # type: ignore[attr-defined]
        profile = load_profile_text(decode_text(data, str(obj), "profile"), str(obj))
    elif isinstance(obj, str):
        profile = load_profile_file(obj)
    else:
        raise PluginError(f"entry point {name!r} gives {obj!r}, not a profile or a path to one")
    if profile.name != name:
        raise PluginError(f"profile entry point {name!r} loads a profile named {profile.name!r}")
    return profile


transports: Registry[TransportPlugin] = Registry(TRANSPORT_GROUP, _to_transport)
profiles: Registry[Profile] = Registry(PROFILE_GROUP, _to_profile)


def get_transport(name: str) -> TransportPlugin:
    return transports.get(name)


def get_profile(name_or_path: str) -> Profile:
    """A profile by model name, or from a TOML file path (ending in .toml) for ad-hoc models."""
    if name_or_path.endswith(".toml"):
        return load_profile_file(name_or_path)
    return profiles.get(name_or_path.lower())


__all__ = [
    "PROFILE_GROUP",
    "TRANSPORT_GROUP",
    "PluginEntry",
    "Registry",
    "StarterbusError",
    "get_profile",
    "get_transport",
    "profiles",
    "transports",
]
