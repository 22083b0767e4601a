"""The wheel holds every package of the source tree: setuptools' package list is explicit (the repository root is
the package), so a new subpackage left out of it works in an editable install and is missing from a real one."""

from __future__ import annotations

import sys
from pathlib import Path

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parent.parent
NOT_SHIPPED = {"tests", "bench", "plugins", "docs", "build"}


def test_every_package_of_the_tree_is_in_the_wheel() -> None:
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]["packages"])
    found = {"starterbus"}
    for init in ROOT.rglob("__init__.py"):
        parts = init.parent.relative_to(ROOT).parts
        if (
            parts
            and parts[0] not in NOT_SHIPPED
            and not any(p.startswith(".") or p.endswith(".egg-info") for p in parts)
        ):
            found.add(".".join(("starterbus", *parts)))
    assert found - listed == set(), "packages missing from pyproject.toml's [tool.setuptools] packages"
    assert listed - found == set(), "packages listed in pyproject.toml that are not in the tree"
