"""Plugin discovery through entry points, loaded lazily.

Groups:

- ``starterbus.transports``: a :class:`TransportPlugin` instance (or a class to instantiate without arguments);
- ``starterbus.profiles``: a :class:`Profile`, a path / ``importlib.resources`` file of a profile TOML, or a
  callable returning either;
- ``starterbus.address_spaces``: an :class:`~starterbus.core.address_space.AddressSpace` (or a class);
- ``starterbus.overlays``: named ``MODEL.NAME``, an overlay adding address spaces to the model ``MODEL``
  (a path / resource of its TOML, its parsed mapping, or a callable returning one: ``core/profile_overlay.py``).

Built-ins are registered in ``pyproject.toml`` exactly like a third-party distribution would register its own.
A plugin that fails to import is reported with its error and does not affect the others; two entry points
with one name in one group is an error, never a silent override.
"""

from __future__ import annotations

import logging
import sys
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Generic, TypeVar

from starterbus.core.address_space import AddressSpace, forget
from starterbus.core.errors import PluginError, ProfileError, StarterbusError
from starterbus.core.profile import Profile, build_profile, load_profile_file
from starterbus.core.textinput import decode_text, read_text_file
from starterbus.core.transport import TransportPlugin

if TYPE_CHECKING:
    from importlib.metadata import EntryPoint

TRANSPORT_GROUP = "starterbus.transports"
PROFILE_GROUP = "starterbus.profiles"
SPACE_GROUP = "starterbus.address_spaces"
OVERLAY_GROUP = "starterbus.overlays"

T = TypeVar("T")
_log = logging.getLogger("starterbus.registry")

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


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
        forget()


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


def _to_space(name: str, obj: object) -> AddressSpace:
    if isinstance(obj, type) and issubclass(obj, AddressSpace):
        obj = obj()
    if not isinstance(obj, AddressSpace):
        raise PluginError(f"entry point {name!r} gives {obj!r}, not an AddressSpace")
    if obj.name != name:
        raise PluginError(f"entry point {name!r} gives an address space that calls itself {obj.name!r}")
    return obj


def _read_toml(name: str, obj: object) -> tuple[object, str]:
    """A profile or overlay entry point's object: a Profile or mapping as is, a file read and parsed as TOML."""
    if callable(obj) and not isinstance(obj, (Profile, Path)) and not _is_resource(obj):
        obj = obj()
    if isinstance(obj, (Profile, Mapping)):
        return obj, name
    if isinstance(obj, (Path, str)):
        source = str(obj)
        text = read_text_file(obj, "profile", error=lambda where, detail: ProfileError(where, "(file)", detail))
    elif _is_resource(obj):
        source = str(obj)
        text = decode_text(obj.read_bytes(), source, "profile")  # type: ignore[attr-defined]
    else:
        raise PluginError(f"entry point {name!r} gives {obj!r}, not a profile or a path to one")
    try:
        return tomllib.loads(text), source
    except tomllib.TOMLDecodeError as exc:
        raise ProfileError(source, "(toml)", str(exc)) from exc


def _to_profile(name: str, obj: object) -> Profile:
    data, source = _read_toml(name, obj)
    profile = data if isinstance(data, Profile) else build_profile(data, source)  # type: ignore[arg-type]
    if profile.name != name:
        raise PluginError(f"profile entry point {name!r} loads a profile named {profile.name!r}")
    return _with_overlays(profile)


def _identity(name: str, obj: object) -> object:
    return obj


transports: Registry[TransportPlugin] = Registry(TRANSPORT_GROUP, _to_transport)
profiles: Registry[Profile] = Registry(PROFILE_GROUP, _to_profile)
address_spaces: Registry[AddressSpace] = Registry(SPACE_GROUP, _to_space)
overlays: Registry[object] = Registry(OVERLAY_GROUP, _identity)
#: overlay entry name -> why it was left out of its model (the model loads without it)
overlay_errors: dict[str, str] = {}


def _with_overlays(profile: Profile) -> Profile:
    """The model with every overlay registered for it (``MODEL.NAME``); a broken overlay is left out, logged and
    kept in :data:`overlay_errors`: one plugin's mistake does not take the model from everyone."""
    from starterbus.core.profile_overlay import apply_overlay

    for entry_name in overlays.names():
        if entry_name.partition(".")[0] != profile.name:
            continue
        try:
            data, source = _read_toml(entry_name, overlays.get(entry_name))
            if not isinstance(data, Mapping):
                raise PluginError(f"overlay {entry_name!r} gives {data!r}, not an overlay table")
            profile = apply_overlay(profile, data, f"overlay {entry_name} ({source})")
        except Exception as exc:
            overlay_errors[entry_name] = f"{type(exc).__name__}: {exc}"
            _log.warning("overlay %s left out of %s: %s", entry_name, profile.name, exc)
    return profile


def get_transport(name: str) -> TransportPlugin:
    return transports.get(name)


def get_profile(name_or_path: str) -> Profile:
    """A profile by model name, or from a TOML file path (ending in .toml) for ad-hoc models."""
    if name_or_path.endswith(".toml"):
        return load_profile_file(name_or_path)
    return profiles.get(name_or_path.lower())


__all__ = [
    "OVERLAY_GROUP",
    "PROFILE_GROUP",
    "SPACE_GROUP",
    "TRANSPORT_GROUP",
    "PluginEntry",
    "Registry",
    "StarterbusError",
    "address_spaces",
    "get_profile",
    "get_transport",
    "profiles",
    "transports",
]
