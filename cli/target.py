"""Which device a command means: a URL with ``--model``, or a device name from a fleet file.

Every command that names a device resolves it here (:func:`resolve` for a ``URL|NAME`` argument,
:func:`lookup` for a name among other kinds of argument, :func:`recorded_name` for a history database).

The fleet file is ``--fleet FILE``, else ``$STARTERBUS_FLEET``, else ``fleet`` in the user's config file
(``$XDG_CONFIG_HOME/starterbus/config.toml``: ``fleet = "/etc/starterbus/plant.toml"``).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from starterbus.core.errors import ConfigurationError
from starterbus.core.textinput import read_text_file

if TYPE_CHECKING:
    from starterbus.fleet.config import DeviceConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

FLEET_ENV = "STARTERBUS_FLEET"


def config_file() -> Path:
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "starterbus" / "config.toml"


def default_fleet(explicit: str | None) -> str | None:
    """The fleet file to look device names up in, or None when none is configured."""
    if explicit:
        return explicit
    if os.environ.get(FLEET_ENV):
        return os.environ[FLEET_ENV]
    path = config_file()
    if not path.is_file():
        return None
    try:
        data = tomllib.loads(read_text_file(path, "configuration file"))
    except tomllib.TOMLDecodeError as exc:
        raise ConfigurationError(f"{path}: {exc}") from None
    fleet = data.get("fleet")
    if fleet is not None and not isinstance(fleet, str):
        raise ConfigurationError(f"{path}: fleet: {fleet!r} is not a file name")
    return fleet


def lookup(name: str, fleet_option: str | None, neither: str = "a device URL (scheme://...)") -> DeviceConfig:
    """Device ``name`` of the fleet file (``--fleet``, else the default); ``neither`` says what else ``name``
    is not, for the error when no fleet file is configured."""
    fleet_path = default_fleet(fleet_option)
    if fleet_path is None:
        raise ConfigurationError(
            f"{name!r} is neither {neither} nor a device name: no fleet file to look it up in "
            f"(give --fleet FILE, set ${FLEET_ENV}, or `fleet = ...` in {config_file()})"
        )
    from starterbus.fleet.config import load_fleet

    fleet = load_fleet(fleet_path)
    device = fleet.devices_by_name.get(name)
    if device is None:
        names = ", ".join(sorted(fleet.devices_by_name)) or "none"
        raise ConfigurationError(f"{fleet_path}: no device named {name!r} (devices: {names})")
    return device


def recorded_name(text: str, fleet_option: str | None) -> str:
    """The name a device has in a history database: a fleet device's URL becomes its name in the fleet file
    (``poll --record`` and ``record NAME`` record by name); a name, or a URL of no fleet device, stays."""
    fleet_path = default_fleet(fleet_option) if "://" in text else None
    if fleet_path is None:
        return text
    from starterbus.fleet.config import load_fleet

    return next((d.name for d in load_fleet(fleet_path).devices if d.url == text), text)


def resolve(args: argparse.Namespace) -> None:
    """Turn ``args.url`` (a URL or a device name) and ``args.model`` into a URL and a model, in place."""
    target: str = args.url
    if "://" in target:
        if not args.model:
            raise ConfigurationError(f"{target}: give --model with a URL (or use a device name from a fleet file)")
        return
    fleet_option = getattr(args, "fleet", None)
    device = lookup(target, fleet_option)
    if args.model and args.model != device.model:
        raise ConfigurationError(
            f"{target}: --model {args.model} disagrees with the fleet file "
            f"({default_fleet(fleet_option)}: model {device.model})"
        )
    args.url, args.model = device.url, device.model
    args.device_name = target
