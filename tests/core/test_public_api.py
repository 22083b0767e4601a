"""Every public name resolves: what the README and docs/plugins.md tell users to import exists."""

from __future__ import annotations

import importlib

import pytest


@pytest.mark.parametrize("module", ["starterbus", "starterbus.core", "starterbus.testing", "starterbus.aio"])
def test_every_public_name_resolves(module: str) -> None:
    mod = importlib.import_module(module)
    names = getattr(mod, "__all__", [n for n in dir(mod) if not n.startswith("_")])
    assert names
    for name in names:
        assert getattr(mod, name) is not None, name


def test_errors_all_derive_from_one_base() -> None:
    import starterbus

    for name in starterbus.__all__:
        value = getattr(starterbus, name)
        if isinstance(value, type) and issubclass(value, Exception):
            assert issubclass(value, starterbus.StarterbusError), name


def test_the_documented_plugin_api_resolves() -> None:
    """Every name the public-API table of docs/plugins.md lists is importable from the module it names."""
    import re
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "plugins.md").read_text(encoding="utf-8")
    section = text.split("## The public API", 1)[1]
    module = ""
    checked = 0
    for row in (line for line in section.splitlines() if line.startswith("| ") and "---" not in line):
        where, names = row.strip("|").split("|", 1)
        if where.strip() and where.strip() != "from":
            module = where.strip().strip("`")
        if not module:
            continue
        mod = importlib.import_module(module)
        for name in re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", names):
            if name[0].isupper() or name.islower() or name.isupper():
                assert getattr(mod, name, None) is not None, f"{module}.{name}"
                checked += 1
    assert checked > 40
