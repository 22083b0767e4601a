"""The built-in device profiles (one TOML file per model), registered as ``starterbus.profiles`` entry points."""

from importlib.resources import files
from importlib.resources.abc import Traversable

_HERE = files(__name__)

jjr5000: Traversable = _HERE / "jjr5000.toml"
ssd1: Traversable = _HERE / "ssd1.toml"
jjr8000: Traversable = _HERE / "jjr8000.toml"
