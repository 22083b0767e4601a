"""The layering rule (docs/architecture.md) holds, and its check fails on an arrow that points up or closes a circle:
``lint-imports`` with the contracts of pyproject.toml, on the tree and on a copy of the package with one bad import."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOT_THE_PACKAGE = (
    *("tests", "bench", "docs", "plugins", "examples", "build"),
    *("assets", "*.egg-info", ".*", "__pycache__"),
)


def lint_imports(cwd: Path, pythonpath: Path | None = None) -> subprocess.CompletedProcess[str]:
    script = Path(sys.executable).with_name("lint-imports")
    command = str(script) if script.exists() else shutil.which("lint-imports")
    if command is None:
        pytest.fail("lint-imports is not installed (the test extra: pip install '.[test]')")
    env = dict(os.environ)
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(pythonpath), env.get("PYTHONPATH")]))
    return subprocess.run(
        [command, "--no-cache"], cwd=cwd, env=env, capture_output=True, text=True, timeout=120, check=False
    )


@pytest.fixture
def copy(tmp_path: Path) -> Path:
    """The package's modules under tmp_path/starterbus and the contracts beside them (the copy is imported first)."""
    shutil.copytree(ROOT, tmp_path / "starterbus", ignore=shutil.ignore_patterns(*NOT_THE_PACKAGE))
    shutil.copy(ROOT / "pyproject.toml", tmp_path / "pyproject.toml")
    return tmp_path


def append(module: Path, line: str) -> None:
    module.write_text(module.read_text(encoding="utf-8") + f"\n{line}\n", encoding="utf-8")


def test_the_tree_keeps_every_contract() -> None:
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "0 broken" in result.stdout


def test_the_copy_keeps_them_too(copy: Path) -> None:
    """The copy is what the tests below break: unbroken, it passes (so their failures are their import's)."""
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 0, result.stdout + result.stderr


def test_core_importing_the_cli_breaks_the_layers(copy: Path) -> None:
    append(copy / "starterbus" / "core" / "status.py", "import starterbus.cli  # noqa")
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 1, result.stdout
    assert "starterbus.core.status -> starterbus.cli" in result.stdout
    assert "layers: cli > serve" in result.stdout and "BROKEN" in result.stdout


def test_a_late_import_that_closes_a_circle_breaks_the_acyclic_contract(copy: Path) -> None:
    """fleet/sample.py importing the poller (which imports it), inside a function: still a circle."""
    late = "def _late() -> None:\n    import starterbus.fleet.poller  # noqa"
    append(copy / "starterbus" / "fleet" / "sample.py", late)
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 1, result.stdout
    assert "No cycles are allowed in starterbus.fleet" in result.stdout


def test_a_type_only_import_that_reties_the_core_knot_breaks_the_core_layers(copy: Path) -> None:
    """core/status.py naming the profile under TYPE_CHECKING (it names a StatusModel instead): the core's own
    layers and the acyclic contract both break, with no exception left to hide it."""
    append(copy / "starterbus" / "core" / "status.py", "if TYPE_CHECKING:\n    import starterbus.core.profile  # noqa")
    status = copy / "starterbus" / "core" / "status.py"
    status.write_text(
        status.read_text(encoding="utf-8").replace("from typing import ", "from typing import TYPE_CHECKING, ", 1)
    )
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 1, result.stdout
    said = " ".join(result.stdout.split())
    assert "starterbus.core.status -> starterbus.core.profile" in said
    assert "status > model > address_space > entry_points BROKEN" in said
    assert "No cycles are allowed in starterbus.core" in said


def test_a_transport_importing_a_core_module_breaks_the_public_core_contract(copy: Path) -> None:
    """A built-in transport imports the public starterbus.core only, as a plugin must: the offender is named, with
    its line."""
    url = copy / "starterbus" / "transports" / "devicenet" / "url.py"
    line = len(url.read_text(encoding="utf-8").splitlines()) + 2
    append(url, "from starterbus.core.errors import DecodeError  # noqa")
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 1, result.stdout
    said = " ".join(result.stdout.split())  # lint-imports wraps its lines
    assert f"starterbus.transports.devicenet.url -> starterbus.core.errors (l.{line})" in said
    assert "import the public starterbus.core, none of its modules BROKEN" in said


def test_a_codec_importing_its_transport_breaks_the_protocol_layout(copy: Path) -> None:
    append(
        copy / "starterbus" / "transports" / "profibus_pkw" / "codec" / "codes.py",
        "import starterbus.transports.profibus_pkw.transport  # noqa",
    )
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 1, result.stdout
    said = " ".join(result.stdout.split())
    assert "profibus_pkw.codec is not allowed to import starterbus.transports.profibus_pkw.transport" in said
    assert "starterbus.transports.profibus_pkw.codec.codes -> starterbus.transports.profibus_pkw.transport" in said


def test_a_module_outside_the_layout_breaks_it(copy: Path) -> None:
    """Every module of a protocol package is one of the parts of docs/architecture.md (the contract is exhaustive)."""
    (copy / "starterbus" / "transports" / "devicenet" / "helpers.py").write_text(
        '"""Odds and ends."""\n', encoding="utf-8"
    )
    result = lint_imports(copy, pythonpath=copy)
    assert result.returncode == 1, result.stdout
    said = " ".join(result.stdout.split())
    assert "The following modules are not listed as layers: - starterbus.transports.devicenet.helpers" in said
