"""What a DP station is asked (docs/engine.md, step 6): the requests of :class:`~starterbus.transports.profibus_pkw.
master.station.StationEngine` (a PKW task, control words, fresh inputs), its ticket, the units of one exchange
and the output words of one. ``station.py`` re-exports these names."""

from __future__ import annotations

import math
from dataclasses import dataclass

from starterbus.core import EncodeError, Ticket
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.codec.telegram import PkwRequest
from starterbus.transports.profibus_pkw.master.job import PkwJob

__all__ = [
    "ControlWords",
    "DpIn",
    "DpOut",
    "FreshInputs",
    "PkwTask",
    "StationRequest",
    "StationTicket",
    "output_words_of",
]

#: a deadline that never comes
FOREVER = math.inf

#: one exchange out: its number and the output words (None: leave that word as it is, passive PZD)
DpOut = tuple[int, tuple[int | None, ...]]
#: one exchange in: the number of the exchange it answers and the input words
DpIn = tuple[int, tuple[int, ...]]


@dataclass(frozen=True, slots=True)
class PkwTask:
    request: PkwRequest
    what: str = ""


@dataclass(frozen=True, slots=True)
class ControlWords:
    words: tuple[int, ...]
    timeout: float = 2.0


@dataclass(frozen=True, slots=True)
class FreshInputs:
    timeout: float = 2.0


StationRequest = PkwTask | ControlWords | FreshInputs


@dataclass(eq=False, slots=True)
class StationTicket(Ticket[StationRequest, object]):
    """A station's ticket: ``job`` for a PKW task; ``give_up``: when it fails if nothing ended it before;
    ``after``: the exchanges started before it (fresh inputs come from a later one, and from one started more
    than ``stale_cycles`` exchanges and at least ``stale_time`` seconds after the request: ``fresh_after``,
    ``not_before``, the input then shows the slave at a moment after the request)."""

    job: PkwJob | None = None
    give_up: float = FOREVER
    after: int = 0
    fresh_after: int = 0
    not_before: float = 0.0


def output_words_of(ppo: Ppo, pkw: PkwRequest, stw: int | None) -> tuple[int | None, ...]:
    """The output words of one exchange; None = leave that word in the output area as it is (passive PZD)."""
    if (pkw.ind or pkw.pwe) and ppo is not Ppo.PPO1:
        raise EncodeError("PPO3 has no PKW area: parameter tasks need PPO1", field="ppo")
    if ppo is Ppo.PPO1:
        return (pkw.ind, pkw.pwe, stw, None if stw is None else 0)
    return (stw, None if stw is None else 0)
