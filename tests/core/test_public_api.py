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
