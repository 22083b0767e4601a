"""The plugin is written against starterbus's documented public API only (docs/plugins.md, "The public API")."""

from __future__ import annotations

import ast
from pathlib import Path

import starterbus_canopen

PUBLIC_MODULES = {"starterbus", "starterbus.core", "starterbus.core.settings_check", "starterbus.testing"}


def _starterbus_imports(path: Path) -> list[tuple[int, str]]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "starterbus":
            found.append((node.lineno, node.module))
        elif isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.split(".")[0] == "starterbus"]
    return found


def test_the_plugin_imports_only_public_starterbus_modules() -> None:
    package = Path(starterbus_canopen.__file__).parent
    sources = sorted(package.glob("*.py"))
    assert sources
    private = [
        f"{path.name}:{line} imports {module}"
        for path in sources
        for line, module in _starterbus_imports(path)
        if module not in PUBLIC_MODULES
    ]
    assert private == []


def test_the_check_sees_a_private_import(tmp_path: Path) -> None:
    source = tmp_path / "bad.py"
    source.write_text("from starterbus.core.canbus import check_peer\nimport starterbus.cli.main\n", encoding="utf-8")
    assert _starterbus_imports(source) == [(1, "starterbus.core.canbus"), (2, "starterbus.cli.main")]
