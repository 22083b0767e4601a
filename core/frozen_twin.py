"""Building instances of frozen slotted dataclasses without their ``__init__`` (hot paths only).

A frozen dataclass's ``__init__`` sets each field through ``object.__setattr__``, a call per field. A *twin* is
a plain class with the same ``__slots__`` (the same memory layout): a hot path makes one, sets its fields with
ordinary assignments and then gives it the frozen class (``made.__class__ = cls``, allowed between classes of
the same layout). The result is an ordinary instance of ``cls``: its assignment raises, equality, hash, repr and
pickling are the dataclass's. A builder must set every field, in no particular order.
"""

from __future__ import annotations

from typing import Any

__all__ = ["twin"]


def twin(cls: type) -> type[Any]:
    """A plain class with ``cls``'s slots, whose instances may become ``cls`` instances (see above)."""
    slots = cls.__dict__.get("__slots__")
    if slots is None or "__dict__" in slots or "__weakref__" in slots:
        raise TypeError(f"{cls.__qualname__} has no plain __slots__ to mirror")
    if hasattr(cls, "__post_init__"):
        raise TypeError(f"{cls.__qualname__} has a __post_init__, which a twin would not run")
    made = type(f"_{cls.__name__}Twin", (), {"__slots__": tuple(slots), "__module__": cls.__module__})
    probe = made()
    probe.__class__ = cls  # raises TypeError now, at import, if the layouts differ
    return made
