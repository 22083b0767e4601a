"""Scan scheduling of the DeviceNet master (sans-IO; a base of :class:`~.node.MasterNode`).

Each established slave is polled at its own interval, or at once while a reader or a command waits
(``urgent``), with at most ``WINDOW`` poll commands in flight. An answer is published only when no second
answer to the same poll came within the answer guard (``ScannerConfig.answer_guard``, 2 ms); the next poll
of that slave waits for that, so every answer can be told apart from the next poll's. Two answers to one poll
mark the link with a :class:`DuplicateResponderError` and withdraw its inputs until ``CLEAR_POLLS`` polls in
a row got one answer.
A poll without an answer by its deadline is missed; its answer may still come (frames queue in the host
under load), so the slave is not polled again until that answer came (it is taken as the missed poll's: no
other poll went out) or ``LATE_LIMIT`` passed; the next poll then tolerates one extra, earlier answer.
Timers: a FIFO of answer deadlines and confirmations (both a constant delay after the event, so in order)
and a heap of next poll times; no pass over every link per frame.
"""

from __future__ import annotations

import heapq
import math
from collections import deque

from starterbus.core import CanFrame
from starterbus.transports.devicenet.master.link import DuplicateResponderError, InputSample, MasterLink
from starterbus.transports.devicenet.master.sequence import ConnectionSequence

WINDOW = 8  # poll commands in flight at once
POLL_RESPONSE_TIMEOUT = 0.05  # seconds a poll command waits for its answer
LATE_LIMIT = 0.5  # seconds after a missed poll's deadline its answer may still arrive (then the next poll goes)
CLEAR_POLLS = 20  # polls in a row with one answer each that clear a duplicate responder


class PollScheduler(ConnectionSequence):
    """Polls, answers, confirmations and duplicate responders."""

    deadline: float
    cycles: int
    polls_sent: int
    _slow_at: float
    _ready: deque[MasterLink]
    _in_flight: int
    _confirming: deque[MasterLink]
    _deadlines: deque[tuple[float, MasterLink]]
    _due: list[tuple[float, int, MasterLink]]
    _sequence: int

    def _wake(self, at: float) -> None:
        """Something the slow pass (explicit messaging, keep-alive, watchdogs, retries) must see at ``at``."""
        self._slow_at = min(self._slow_at, at)
        self.deadline = min(self.deadline, at)

    def _wake_fast(self, at: float) -> None:
        self.deadline = min(self.deadline, at)

    def _fast(self, now: float) -> None:
        """Confirm answers, count missed polls, queue the polls due."""
        confirming = self._confirming
        while confirming and confirming[0].confirm_at <= now:
            self._confirm(confirming.popleft(), now)
        deadlines = self._deadlines
        while deadlines and deadlines[0][0] <= now:
            at, link = deadlines.popleft()
            if link.awaiting and link.poll_deadline == at:
                link.awaiting = False
                link.misses += 1
                link.missed += 1
                link.quarantine_until = at + LATE_LIMIT  # its answer may still come: no next poll before
                self._in_flight -= 1
                self._schedule(link, now)
        due = self._due
        while due and due[0][0] <= now:
            _, _, link = heapq.heappop(due)
            if link.next_poll_at <= now and link.quarantine_until <= now:
                self._make_ready(link)

    # -- polling --------------------------------------------------------------------------------------------

    def _established(self, link: MasterLink, now: float) -> None:
        link.missed = link.tolerate = link.answers = 0
        link.quarantine_until = 0.0
        link.next_poll_at = now
        self._make_ready(link)
        self._wake(now)

    def _stop_polling(self, link: MasterLink) -> None:
        """Forget the link's poll in flight and its urgency (its polled connection goes away)."""
        if link.awaiting:
            link.awaiting = False
            self._in_flight -= 1
        link.pending = None
        link.urgent = 0

    @staticmethod
    def _idle(link: MasterLink) -> bool:
        return link.polling and not link.awaiting and not link.queued and link.pending is None

    def _make_ready(self, link: MasterLink) -> None:
        if self._idle(link):
            link.queued = True
            self._ready.append(link)

    def _schedule(self, link: MasterLink, now: float) -> None:
        """A poll of ``link`` finished (answered or missed): queue the next one now or at its time."""
        if now < link.quarantine_until:
            if self._idle(link):
                self._sequence += 1
                heapq.heappush(self._due, (link.quarantine_until, self._sequence, link))
                self._wake_fast(link.quarantine_until)
        elif link.urgent or link.interval <= 0 or link.next_poll_at <= now:
            link.next_poll_at = min(link.next_poll_at, now)
            self._make_ready(link)
        elif self._idle(link):
            self._sequence += 1
            heapq.heappush(self._due, (link.next_poll_at, self._sequence, link))
            self._wake_fast(link.next_poll_at)

    def _send_ready(self, now: float) -> None:
        ready = self._ready
        while ready and self._in_flight < WINDOW:
            link = ready.popleft()
            link.queued = False
            if not link.polling or link.awaiting or link.pending is not None:
                continue
            if now < link.quarantine_until:
                self._schedule(link, now)
                continue
            seq = link.output_seq
            if seq != link.built_seq:
                output = link.output()
                link.poll_data = output.encode()
                link.poll_frame = CanFrame(link.poll_frame.can_id, link.poll_data)
                link.built_seq = seq
                link.built_select = output.address
            link.sent_seq = link.built_seq
            link.sent_select = link.built_select
            link.awaiting = True
            link.answers = 0
            link.tolerate, link.missed = link.missed, 0
            link.poll_deadline = deadline = now + POLL_RESPONSE_TIMEOUT
            interval = link.interval
            # on the grid of its interval: the slaves with one interval are due together (one wake-up for all)
            link.next_poll_at = round((math.floor(now / interval + 1e-9) + 1) * interval, 9) if interval > 0 else now
            self._deadlines.append((deadline, link))
            self._wake_fast(deadline)
            self._in_flight += 1
            self.polls_sent += 1
            self._out.append(link.poll_frame)

    def _on_poll_response(self, link: MasterLink, data: bytes, now: float) -> None:
        link.answers += 1
        if link.answers > 1:
            if link.tolerate:
                self._late_answer_first(link, data, now)
            else:
                self._duplicate_answer(link, data, now)
            return
        if link.awaiting:
            link.awaiting = False
            self._in_flight -= 1
        elif link.missed and link.pending is None:
            # the missed poll's answer, late (host buffers under load); no poll went out since: it is its answer
            link.missed = 0
            link.quarantine_until = 0.0
            link.late += 1
        else:
            link.answers = 0  # unsolicited (before the first poll): no value
            return
        link.last_response_at = now
        previous = link.sample
        select = link.sent_select
        count = previous.select_count + 1 if previous is not None and previous.select == select else 1
        link.pending = InputSample(data, now, 0.0, select, count, link.sent_seq)
        link.last_answer = data
        guard = self.config.answer_guard
        if guard <= 0:
            self._confirm(link, now)
        else:
            link.confirm_at = now + guard
            self._confirming.append(link)
            self._wake_fast(link.confirm_at)
        self._send_ready(now)

    def _confirm(self, link: MasterLink, now: float) -> None:
        sample = link.pending
        link.pending = None
        if sample is not None and link.polling:
            self._publish(link, sample)
        self._schedule(link, now)

    def _publish(self, link: MasterLink, sample: InputSample) -> None:
        link.responses += 1
        self.cycles += 1
        if link.duplicate is not None:
            link.clean_polls += 1
            if link.clean_polls < CLEAR_POLLS:
                return
            link.duplicate = None
            link.note(sample.at, f"{CLEAR_POLLS} polls in a row with one answer: duplicate responder cleared")
        link.sample = sample
        link.acked_seq = sample.seq
        if link.urgent and sample.seq == link.output_seq:  # an answer to the latest outputs
            link.urgent -= 1

    def _late_answer_first(self, link: MasterLink, data: bytes, now: float) -> None:
        """The poll after a quarantine that ran out got one more answer: the earlier one was the missed poll's
        very late answer (frames stay in order), this one answers the current poll and replaces it."""
        link.tolerate -= 1
        link.late += 1
        link.last_answer = data
        if link.pending is not None:
            link.pending = link.pending._replace(data=data, at=now)
        elif link.sample is not None and link.sample.seq == link.sent_seq:
            link.sample = link.sample._replace(data=data, at=now)

    def _duplicate_answer(self, link: MasterLink, data: bytes, now: float) -> None:
        first = link.last_answer
        link.duplicates += 1
        link.clean_polls = 0
        link.pending = None  # still in the confirmation queue: _confirm schedules the next poll
        link.sample = None
        error = DuplicateResponderError(
            f"{link.describe()}: two answers to one poll command ({first.hex(' ').upper()} and "
            f"{data.hex(' ').upper()}): another node answers polls for MAC {link.mac} (misconfigured or rogue); "
            "its inputs are withheld"
        )
        if link.duplicate is None:
            link.note(now, str(error))
        link.duplicate = error
