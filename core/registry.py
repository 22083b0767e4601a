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
with one name in one group is an error, never a silent override (:mod:`starterbus.core.entry_points`).

This module is the top of the core's plugin layers: the transports and address spaces registries live below the
profile loader (:mod:`starterbus.core.address_space`, which reads a profile's addresses with them), and this one
adds the profiles, which are built by that loader.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import cast

from starterbus.core.address_space import SPACE_GROUP, TRANSPORT_GROUP, address_spaces
from starterbus.core.address_space import transports as _installed_transports
from starterbus.core.entry_points import PluginEntry, Registry
from starterbus.core.errors import PluginError, ProfileError, StarterbusError
from starterbus.core.plugin import TransportPlugin
from starterbus.core.profile import Profile, build_profile, load_profile_file
from starterbus.core.profile_overlay import apply_overlay
from starterbus.core.textinput import decode_text, read_text_file

PROFILE_GROUP = "starterbus.profiles"
OVERLAY_GROUP = "starterbus.overlays"

_log = logging.getLogger("starterbus.registry")

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def _is_resource(obj: object) -> bool:
    """An ``importlib.resources`` file (a Traversable): read it, do not call it."""
    return hasattr(obj, "read_text") and hasattr(obj, "is_file")


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


#: the transport plugins: the registry the address spaces look plugins up in; everything it loads passed the plugin
#: API's check (``starterbus.core.plugin``), so it holds TransportPlugins
transports = cast("Registry[TransportPlugin]", _installed_transports)
profiles: Registry[Profile] = Registry(PROFILE_GROUP, _to_profile)
overlays: Registry[object] = Registry(OVERLAY_GROUP, _identity)
#: overlay entry name -> why it was left out of its model (the model loads without it)
overlay_errors: dict[str, str] = {}


def _with_overlays(profile: Profile) -> Profile:
    """The model with every overlay registered for it (``MODEL.NAME``); a broken overlay is left out, logged and
    kept in :data:`overlay_errors`: one plugin's mistake does not take the model from everyone."""
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
