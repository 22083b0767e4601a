"""What an edge session knows of one device (:class:`~starterbus.serve.session.EdgeSession` keeps one each, its
host commands in :mod:`starterbus.serve.session_commands` read them)."""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Final

from starterbus.serve.metrics import MetricSet, Scalar


class _Unreported(enum.Enum):
    UNREPORTED = 0


UNREPORTED: Final = _Unreported.UNREPORTED  # ``reported.get(name, UNREPORTED)``: never published in this session


@dataclass(slots=True)
class DeviceState:
    """What the session knows of one device: its metrics, last values and what it published of them."""

    name: str
    metrics: MetricSet
    online: bool = False
    born: bool = False
    current: dict[str, tuple[Scalar | None, int]] = field(default_factory=dict)  # name -> (value, ms)
    reported: dict[str, Scalar | None] = field(default_factory=dict)
    last_full: float = 0.0
    refused: int = 0
    commands: int = 0  # outcomes published (Device Control/Command Count)
    seen: bool = False  # polled at least once (answered or not)
    fresh: set[str] = field(default_factory=set)  # polled metrics read in the last good poll
    quality: dict[str, int] = field(default_factory=dict)  # the Quality last published per metric
