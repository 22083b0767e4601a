"""Which PKW responses can still be stale, sans-IO: the bookkeeping behind the handshake's acceptance rule.

A response carries no sequence number, only a response code, INDL and PWE. A response seen now may be:

- the answer to an EARLIER task with the same INDL (a read or write of the parameter, or a measurement read:
  both data areas share INDL), because that task timed out while the slave was still working on it;
- an old input image that a gateway shows again (it lags, or replays an earlier image).

The rule (docs/profibus.md, "Stale answers") rests on two assumptions, each stated where it is used:

- **the slave is ordered**: it handles the master's outputs in the order they were sent, so once it has shown
  the answer to a later output it never shows an answer to an earlier one again;
- **the input is at most ``stale_cycles`` exchanges and ``stale_time`` seconds old**: the input read in
  exchange ``n`` is what the slave showed at some point no earlier than exchange ``n - stale_cycles`` and
  ``stale_time`` seconds before it (in any order: lag, jitter and replays within that window are all covered).

From these, an observation ``o`` is *fresh after* a mark ``m`` (:meth:`Freshness.fresh`) when it is more than
``stale_cycles`` exchanges and ``stale_time`` seconds later: it then shows the slave at a moment after the one
seen at ``m``. For every INDL the book keeps the last task sent with it (:class:`IndexRecord`): where its
answers became acceptable (``basis``), when the master stopped sending it (``ended``), and where its verified
answer was seen (``answered``; ``None``: an *orphan*, a task sent but never verifiably answered).

A new task on INDL ``i`` may start (:meth:`Freshness.proof`) at a "no response" observation ``o`` when either

1. a task sent after the last task on ``i`` was verifiably answered (an ordered slave has then left the old task
   behind); the basis is that answer; or
2. the last task on ``i`` was answered (in time or late) and ``o`` is fresh after that answer (the slave went on
   to a later "no task"); the basis is ``o``.

Its answer is then accepted only if fresh after the basis. An orphan on ``i`` satisfies neither until some other
task is verifiably answered (the handshake sends a *fence*: a read of another INDL) or its own late answer shows.

With ``verify_start`` the unknown past counts as an orphan on every INDL: up to ``inherited`` tasks that an
earlier session left on the slave may still be answered, on any INDL and with any value, so no answer can be
told from theirs by its content. Until the past is cleared nothing is attributed to a task (no proof, no late
answer); the session's first task waits for a *start chain*: ``inherited + 1`` fence reads, each on an INDL not
used before in the session and each answered fresh after the previous answer. Those answers are as many distinct
executions (their INDLs differ), in the slave's order; at most ``inherited`` are old, so one is ours, and every
later one, the last included, follows ours and is not old either. The last fence is its INDL's only task of the
session: the last answer is its own, a verified answer, and rule 1 then holds for every INDL.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from typing import NamedTuple

from starterbus.transports.profibus_pkw.codec.codes import ResponseCode, TaskCode
from starterbus.transports.profibus_pkw.codec.telegram import NO_TASK, PkwRequest, PkwResponse, hex_text


class Mark(NamedTuple):
    """One observation: the ``n``-th input fed to the engine (1-based), at time ``t``. (A named tuple: one is
    made per exchange, and a tuple is the cheapest to build.)"""

    n: int
    t: float


@dataclass(slots=True)
class IndexRecord:
    """The last task sent with one INDL."""

    request: PkwRequest
    basis: Mark  # its answers were acceptable from here (fresh after it)
    ended: Mark  # the master stopped sending it
    answered: Mark | None  # its verified answer was seen here; None: an orphan


def pkw_bytes(pkw: PkwRequest | PkwResponse) -> bytes:
    """The four PKW bytes (IND, PWE big-endian), as on the wire and in messages."""
    return bytes([(pkw.ind >> 8) & 0xFF, pkw.ind & 0xFF, (pkw.pwe >> 8) & 0xFF, pkw.pwe & 0xFF])


def answers(request: PkwRequest, response: PkwResponse) -> bool:
    """Can ``response`` be the slave's answer to ``request``? Every field that must echo the request is checked:
    INDL; response 2 ("no write permission") only to a write; response 1 to a write must echo the value written.
    """
    if response.ind & 0xFF != request.indl:
        return False
    code = (response.ind >> 8) & 0xFF
    write = request.task == TaskCode.WRITE_PARAMETER
    if code == ResponseCode.VALUE:
        return not write or response.pwe == request.pwe
    if code == ResponseCode.NO_WRITE_PERMISSION:
        return write
    return code == ResponseCode.CANNOT_EXECUTE


#: tasks an earlier session may have left for the slave to answer, unless the URL says otherwise: the one being
#: executed and the one a session that died before sending "no task" left in the output image
DEFAULT_INHERITED = 2


@dataclass(slots=True)
class Freshness:
    """The book of one slave's PKW exchanges. ``stale_cycles`` / ``stale_time``: how old an input may be."""

    stale_cycles: int = 0
    stale_time: float = 0.0
    records: dict[int, IndexRecord] = field(default_factory=dict)
    accepted: Mark | None = None  # the last verified answer (any INDL)
    accepted_indl: int | None = None
    start: Mark | None = None  # before the first exchange: what the slave did earlier is unknown
    verify_start: bool = False  # treat that unknown past as an orphan on every INDL
    inherited: int = DEFAULT_INHERITED  # how many tasks an earlier session may have left for the slave to answer
    chain: int = 0  # start-chain fences answered so far (while the past is unknown)

    @property
    def unknown(self) -> bool:
        """Can an answer still be an earlier session's (``verify_start`` and the start chain not complete)?"""
        return self.verify_start and self.accepted is None

    def begin(self, now: float) -> None:
        if self.start is None:
            self.start = Mark(0, now)

    def fresh(self, mark: Mark, obs: Mark) -> bool:
        """Does ``obs`` certainly show the slave later than the moment seen at ``mark``?"""
        if obs.n <= mark.n + self.stale_cycles:
            return False
        return self.stale_time <= 0 or obs.t - mark.t > self.stale_time

    def orphan(self, indl: int) -> IndexRecord | None:
        """The unanswered task that blocks INDL ``indl`` (rule 1 not yet met), if any; with ``verify_start``,
        before the first verified answer, a record of the unknown past (request "no task")."""
        if self.unknown:
            start = self.start or Mark(0, 0.0)
            return IndexRecord(NO_TASK, start, start, None)
        rec = self.records.get(indl)
        if rec is None or rec.answered is not None:
            return None
        if self.accepted is not None and self.accepted.n > rec.ended.n:
            return None
        return rec

    def proof(self, indl: int, obs: Mark, *, fence: bool = False) -> Mark | None:
        """The basis for a new task on ``indl`` if "no response" seen at ``obs`` may start it, else None.

        While the past is unknown only a ``fence`` of the start chain may start, on an INDL not used yet in the
        session (:meth:`fence_indl`), at a "no response" fresh after the start."""
        rec = self.records.get(indl)
        answered: Mark | None
        if self.unknown and (not fence or rec is not None):
            return None
        if rec is None:
            # Nothing sent on this INDL in this session: treated as answered at the start (an earlier session's
            # tasks are the start chain's business, see the module docstring).
            ended = answered = self.start or Mark(0, obs.t)
        else:
            ended, answered = rec.ended, rec.answered
        if self.accepted is not None and self.accepted.n > ended.n:
            return self.accepted  # rule 1
        if answered is not None and self.fresh(answered, obs):
            return obs  # rule 2
        return None

    def answered(self, request: PkwRequest, basis: Mark, obs: Mark) -> None:
        """A verified answer to ``request`` (value, or refusal 2/3) was seen at ``obs``."""
        indl = request.ind & 0xFF
        rec = self.records.get(indl)
        if rec is None:
            self.records[indl] = IndexRecord(request, basis, obs, obs)
        else:  # reused: one is updated per answer
            rec.request, rec.basis, rec.ended, rec.answered = request, basis, obs, obs
        self.accepted = obs
        self.accepted_indl = indl

    def why_blocked(self, indl: int) -> str | None:
        """Why INDL ``indl`` is quarantined, for a timeout message; None if it is not."""
        orphan = self.orphan(indl)
        if orphan is None:
            return None
        if orphan.request != NO_TASK:
            return f"an earlier task on it [{hex_text(pkw_bytes(orphan.request))}] got no verified answer"
        text = "nothing has been verifiably answered yet in this session "
        text += f"({self.chain} of {self.inherited + 1} start fence reads answered)"
        if self.fence_indl(indl) is None:
            text += "; every INDL has had a lost fence read: reopen the session"
        return text

    def fenced(self, request: PkwRequest, basis: Mark, obs: Mark) -> None:
        """A fence read's answer was seen at ``obs`` (fresh after ``basis``, echoing it). In the start chain
        all but the last may be an earlier session's answers: the fence stays unanswered, its INDL is not used
        again in the chain, and the next fence is sent on another one."""
        if self.unknown and self.chain < self.inherited:
            self.chain += 1
            self.unanswered(request, basis, obs)
        else:
            self.answered(request, basis, obs)

    def unanswered(self, request: PkwRequest, basis: Mark, ended: Mark) -> None:
        """``request`` was sent but ended without a verified answer (timeout, corrupt answer, broken channel)."""
        self.records[request.indl] = IndexRecord(request, basis, ended, None)

    def late(self, response: PkwResponse, obs: Mark) -> bool:
        """Note an answer that arrives after its task ended; True if it resolved an orphan."""
        if self.unknown:
            return False  # it may be an earlier session's answer
        rec = self.records.get(response.ind & 0xFF)
        if rec is None or rec.answered is not None or not self.fresh(rec.basis, obs):
            return False
        if not answers(rec.request, response):
            return False
        # Fresh after the orphan's basis, and no later task used this INDL: it is the orphan's own answer.
        rec.answered = obs
        return True

    def fence_indl(self, blocked: int, taken: Collection[int] = ()) -> int | None:
        """An INDL to read so that a verified answer lifts the block on ``blocked``: preferably the last one
        verifiably answered (a known address), else the next INDL not itself blocked. In the start chain: the
        next INDL not used yet in the session, nor in ``taken`` (a preview's fences before it; None: every one has
        had a lost fence read)."""
        if self.unknown:
            for step in range(1, 256):
                indl = (blocked + step) & 0xFF
                if indl not in self.records and indl not in taken:
                    return indl
            return None
        if self.accepted_indl is not None and self.accepted_indl != blocked and not self.orphan(self.accepted_indl):
            return self.accepted_indl
        for step in range(1, 256):
            indl = (blocked + step) & 0xFF
            if self.orphan(indl) is None:
                return indl
        return (blocked + 1) & 0xFF  # every INDL blocked: still a different one
