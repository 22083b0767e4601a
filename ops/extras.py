"""The optional parts of starterbus (pip extras), checked before a command opens or sends anything.

``pip install .`` leaves out what only some commands need: matplotlib (``[plot]``: ``record``'s PNG and
``plot``) and asyncua (``[opcua]``: ``opcua``, ``opcua-user``). A command that needs one calls :func:`require`
first, so a missing part is one line naming the extra to install, never a traceback after the motor started.
"""

from __future__ import annotations

import importlib

from starterbus.core.errors import ConfigurationError

#: extra -> (the package it installs, the modules starterbus imports from it)
EXTRAS: dict[str, tuple[str, tuple[str, ...]]] = {
    "plot": ("matplotlib", ("matplotlib.figure", "matplotlib.patches")),
    "opcua": ("asyncua", ("asyncua",)),
}


class MissingExtraError(ConfigurationError):
    """An optional part is not installed (or does not import); ``extra`` names the pip extra that brings it."""

    def __init__(self, message: str, extra: str) -> None:
        super().__init__(message)
        self.extra = extra


def require(extra: str, what: str) -> None:
    """Raise :class:`MissingExtraError` unless the modules of ``extra`` import; ``what`` says who needs them."""
    package, modules = EXTRAS[extra]
    for module in modules:
        try:
            importlib.import_module(module)
        except ImportError as exc:
            raise MissingExtraError(
                f"{what} needs {package}, an optional part that does not import here ({exc}): "
                f'pip install "starterbus[{extra}]"',
                extra,
            ) from None
