"""The example device model shipped with the plugin (a ``starterbus.profiles`` entry point)."""

from importlib.resources import files

example_canopen_starter = files(__name__) / "example_canopen_starter.toml"
