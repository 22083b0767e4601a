"""The built-in device profiles (one TOML file per model), registered as ``starterbus.profiles`` entry points."""

from importlib.resources import files

_HERE = files(__name__)

jjr5000 = _HERE / "jjr5000.toml"
ssd1 = _HERE / "ssd1.toml"
jjr8000 = _HERE / "jjr8000.toml"
