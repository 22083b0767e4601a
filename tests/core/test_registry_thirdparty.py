"""The plugin registry with real third-party distributions (dist-info + entry points on sys.path).

Each test builds an installed-looking distribution in a temporary directory and runs the real ``starterbus``
CLI in a subprocess with that directory on PYTHONPATH: no patching of the registry.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

from starterbus.core.registry import get_profile

PLUGIN_SOURCE = """
from pathlib import Path
from starterbus.core.errors import UnsupportedOperationError
from starterbus.core.transport import Capability, TransportPlugin


class LoopPlugin(TransportPlugin):
    name = "acme-loop"
    summary = "ACME test transport"
    capabilities = frozenset({Capability.STATUS})

    def open(self, url, profile):
        raise UnsupportedOperationError("acme-loop is a test plugin")


PLUGIN = LoopPlugin()
PROFILE = Path(__file__).with_name("acme9000.toml")
"""


def acme_profile_text() -> str:
    """A copy of the JJR5000 profile renamed, as a third party would ship it."""
    source = Path(get_profile("jjr5000").source).read_text(encoding="utf-8")
    return source.replace('name = "jjr5000"', 'name = "acme9000"', 1)


def test_third_party_profile_and_transport_show_up(tmp_path: Path, third_party: Any) -> None:
    third_party.make_dist(
        tmp_path,
        "acme_starterbus",
        "acme_starterbus",
        """
        [starterbus.transports]
        acme-loop = acme_starterbus:PLUGIN
        [starterbus.profiles]
        acme9000 = acme_starterbus:PROFILE
        """,
        {"__init__.py": PLUGIN_SOURCE, "acme9000.toml": acme_profile_text()},
    )
    models = third_party.run_cli("models", "--json", path=tmp_path)
    assert models.returncode == 0, models.stderr
    by_name = {m["name"]: m for m in json.loads(models.stdout)}
    assert set(by_name) >= {"jjr5000", "ssd1", "jjr8000", "acme9000"}
    assert by_name["acme9000"]["error"] is None
    assert by_name["acme9000"]["source"] == "acme_starterbus 1.0"

    listed = third_party.run_cli("transports", "--json", path=tmp_path)
    assert listed.returncode == 0, listed.stderr
    transports = {t["name"]: t for t in json.loads(listed.stdout)}
    assert set(transports) >= {"modbus-rtu", "profibus-pkw", "devicenet", "acme-loop"}
    assert transports["acme-loop"]["capabilities"] == ["status"]
    assert transports["acme-loop"]["error"] is None

    params = third_party.run_cli("params", "acme9000", "--json", path=tmp_path)
    assert params.returncode == 0, params.stderr
    assert json.loads(params.stdout)["model"] == "acme9000"


def test_broken_plugin_is_reported_and_others_still_load(tmp_path: Path, third_party: Any) -> None:
    third_party.make_dist(
        tmp_path,
        "broken_plugin",
        "broken_plugin",
        """
        [starterbus.transports]
        broken = broken_plugin:PLUGIN
        """,
        {"__init__.py": "import this_module_does_not_exist\n"},
    )
    listed = third_party.run_cli("transports", "--json", path=tmp_path)
    assert listed.returncode == 0, listed.stderr
    transports = {t["name"]: t for t in json.loads(listed.stdout)}
    assert "No module named 'this_module_does_not_exist'" in transports["broken"]["error"]
    assert transports["modbus-rtu"]["error"] is None
    # and using it says why, in one line
    used = third_party.run_cli("status", "broken://x", "--model", "jjr5000", path=tmp_path)
    assert used.returncode == 1
    assert "cannot load starterbus.transports plugin 'broken'" in used.stderr
    assert "this_module_does_not_exist" in used.stderr


def test_two_plugins_with_one_name_is_an_error_not_an_override(tmp_path: Path, third_party: Any) -> None:
    third_party.make_dist(
        tmp_path,
        "impostor",
        "impostor",
        """
        [starterbus.transports]
        modbus-rtu = impostor:PLUGIN
        [starterbus.profiles]
        jjr5000 = impostor:PROFILE
        """,
        {"__init__.py": PLUGIN_SOURCE.replace('"acme-loop"', '"modbus-rtu"'), "acme9000.toml": acme_profile_text()},
    )
    listed = third_party.run_cli("transports", "--json", path=tmp_path)
    transports = {t["name"]: t for t in json.loads(listed.stdout)}
    assert "2 plugins claim the name 'modbus-rtu'" in transports["modbus-rtu"]["error"]
    assert "impostor 1.0" in transports["modbus-rtu"]["error"]
    models = {m["name"]: m for m in json.loads(third_party.run_cli("models", "--json", path=tmp_path).stdout)}
    assert "2 plugins claim the name 'jjr5000'" in models["jjr5000"]["error"]
    assert models["ssd1"]["error"] is None
    used = third_party.run_cli("params", "jjr5000", path=tmp_path)
    assert used.returncode == 1
    assert "claim the name 'jjr5000'" in used.stderr


def test_plugins_load_lazily() -> None:
    """Loading a profile loads only the parsers of the address spaces it names (to check their settings): the
    Modbus register space, no transport at all."""
    code = (
        "import sys; from starterbus.core.registry import get_profile; get_profile('ssd1');"
        "print(sorted({m.split('.')[2] for m in sys.modules if m.startswith('starterbus.transports.')}),"
        " 'starterbus.spaces.modbus' in sys.modules, 'can' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert out.stdout.strip() == "[] True False"
