"""Sans-IO timing rules of one RTU line: when a request may start, and when an answer may be delivered.

An RTU answer carries no request id, so timing and length are the only proof that it answers the request just
sent. :class:`LineGuard` holds the rules; the line driver (``line.py``) does the I/O, reads the clock and feeds
the guard the times (monotonic seconds) and the bytes it saw:

1. **Silence before every request.** The next request starts only when the line has been silent for the silent
   interval (3.5 characters) since the last byte, and input is discarded just before the send: bytes found
   then are stray (rule 2). Input found empty less than one character time before the send (the silence
   after the last answer, when the next request follows at once) counts as discarded.
2. **Quarantine after any fault.** After a timeout, a bad frame (CRC, wrong unit, function, byte count or
   length), garbage or a suspect answer, the line must stay silent for the quarantine (at least the response
   timeout) before the next request: long enough that a late answer to the failed request can no longer
   arrive. Any byte seen meanwhile starts the quarantine again. Stray bytes on a healthy line do the same.
3. **Exact length, then silence.** An answer ends at its predicted length; bytes that follow it within the
   silent interval make it suspect: it is dropped (a failed attempt, rule 2), never delivered.
4. **Not faster than the wire.** On a real serial port an answer cannot be complete sooner after the request
   started than the wire time of request and answer at the configured baud rate (fewest bits a character
   can take, less 5 % for a fast UART clock): such bytes were on their way before the request, so they are
   dropped. A pty or a TCP connection carries no such timing, so there the rule is off.
5. **A line seen repeating an answer is quarantined after answers too.** An answer already delivered, seen
   again where none was asked for (in stray bytes after a success, in bytes trailing an answer, as a frame
   dropped for beating the wire), or an answer followed by itself, shows a slave that repeats answers: a
   repeat arriving while a later request gets no answer of its own would be taken for that answer. From then
   on every delivered answer is followed by :data:`REPEAT_HOLD` quarantines (from its last byte; any byte
   restarts it, a repeat seen in it renews the rule), until :data:`CLEAN_ANSWERS` answers in a row came with no
   stray byte and no failure.
6. **The first answer after a fault is quarantined too.** A late answer to a failed request that comes after
   the quarantine is taken for the next request's answer, and that request's own answer then follows it:
   the first answer delivered after a failure or stray bytes is followed by the quarantine in force, so such
   an answer is a stray there (and, with the bytes of the answer just delivered, a repeat: rule 5) instead of
   the answer to the request after it.

Nothing here reads a clock or does I/O; the tests drive it with explicit times.
"""

from __future__ import annotations

from collections import deque

from starterbus.core import DecodeError

#: a slave's UART clock may run a few per cent fast: answers up to 5 % quicker than nominal are accepted
WIRE_TOLERANCE = 0.95
#: rule 5: how many of the last delivered answers a repeat is recognised among
REMEMBERED_ANSWERS = 64
#: rule 5: how many stray bytes (since the last request) a repeated answer is looked for in
STRAY_MEMORY = 512
#: rule 5: a line seen repeating an answer is quarantined after every answer until this many in a row were clean
CLEAN_ANSWERS = 100
#: rule 5: that quarantine, in quarantines: repeats were measured up to 1.5 timeouts after their answer
REPEAT_HOLD = 1.5


def hex_bytes(data: bytes, limit: int = 16) -> str:
    text = data[:limit].hex(" ").upper()
    return text + (" ..." if len(data) > limit else "")


class LineGuard:
    """The timing state of one line. The driver calls, per attempt: :meth:`send_wait` (waiting, and passing
    bytes seen meanwhile to :meth:`stray`), :meth:`sent`, then :meth:`answer_complete`, a wait until
    :attr:`trail_until` for :meth:`trailing` bytes, and :meth:`delivered`; or :meth:`failed`."""

    __slots__ = (
        "answers", "checked_at", "clean", "fresh", "healthy", "hold", "last_stray", "min_char_time", "quarantines",
        "quiet_at", "repeat_hold", "repeated", "repeats", "silence", "started", "stray_bytes", "stray_seen",
        "stray_tail", "trail_until",
    )  # fmt: skip

    def __init__(self, silence: float, min_char_time: float = 0.0, fresh: float = 0.0) -> None:
        """``silence``: the silent interval; ``min_char_time``: the shortest time a character can take on the
        wire (0 turns the wire-time rule off: pty, TCP); ``fresh``: for how long input found empty counts as
        discarded (one character time)."""
        self.silence = silence
        self.fresh = fresh
        self.checked_at = -1e300  # when the input was last found empty
        self.min_char_time = min_char_time * WIRE_TOLERANCE
        self.quiet_at = 0.0  # the next request may start at this time
        self.hold = 0.0  # the quarantine in force (0: the line is healthy)
        self.started = 0.0  # when the current request started (no later than its first byte was written)
        self.trail_until = 0.0  # the end of the silence that must follow the current answer
        self.stray_bytes = 0
        self.quarantines = 0
        self.last_stray = b""
        # rule 5
        self.answers: deque[bytes] = deque(maxlen=REMEMBERED_ANSWERS)  # the last answers delivered
        self.healthy = False  # the last attempt delivered its answer (no answer is owed to anyone)
        self.stray_tail = b""  # stray bytes since the last request, where a repeated answer is looked for
        self.repeated = False  # the attempt failing now showed a repeated answer (see failed)
        self.repeats = 0  # repeated answers seen
        self.repeat_hold = 0.0  # the quarantine after every answer while the line is suspect (0: it is not)
        self.clean = 0  # while suspect: answers in a row with no stray byte and no failure before them
        self.stray_seen = False  # stray bytes or a failure since the last answer

    @property
    def quarantined(self) -> bool:
        return self.hold > 0.0

    @property
    def suspect(self) -> bool:
        """A slave on the line was seen repeating an answer: every answer is followed by the quarantine."""
        return self.repeat_hold > 0.0

    # -- before a request ----------------------------------------------------------------------------------------

    def send_wait(self, now: float) -> float:
        """Seconds to wait before the next request may start (0 or less: it may start now)."""
        return self.quiet_at - now

    def found_empty(self, now: float) -> None:
        """The driver waited until ``now`` and no byte came."""
        self.checked_at = now

    def send_now(self, now: float) -> bool:
        """The usual case in one call: True (and the request counts as started at ``now``) if it may start now
        without waiting or discarding input; False: the driver waits (:meth:`send_wait`) and discards."""
        if self.quiet_at <= now and now - self.checked_at <= self.fresh:
            self.started = now
            return True
        return False

    def must_discard(self, now: float) -> bool:
        """True unless the input was found empty within the last :attr:`fresh` seconds."""
        return now - self.checked_at > self.fresh

    def stray(self, data: bytes, now: float, quarantine: float) -> None:
        """Bytes that answer no request (seen while waiting to send, or found when input is discarded): the line
        is quarantined, counted from ``now``, for ``quarantine`` or the longer quarantine already in force."""
        hold = max(self.hold, quarantine)
        self.hold = hold
        self.quiet_at = now + hold
        self.stray_bytes += len(data)
        self.last_stray = (self.last_stray + data)[-16:]
        self.stray_seen = True
        if self.healthy:  # no answer is owed after a success: an answer seen again is a repeat
            tail = (self.stray_tail + data)[-STRAY_MEMORY:]
            if self._holds_an_answer(tail):
                self.repeat_seen(quarantine)
                tail = b""
            self.stray_tail = tail

    def _holds_an_answer(self, data: bytes) -> bool:
        return any(answer in data for answer in set(self.answers))

    def repeat_seen(self, quarantine: float) -> None:
        """A delivered answer was seen again: quarantine the line after every answer from now on (rule 5)."""
        self.repeats += 1
        self.repeat_hold = max(self.repeat_hold, REPEAT_HOLD * quarantine)
        self.clean = 0
        self.stray_seen = False

    # -- one attempt ---------------------------------------------------------------------------------------------

    def sent(self, started: float) -> None:
        """The request is being written; ``started`` is no later than its first byte."""
        self.started = started
        self.stray_tail = b""

    def broadcast_sent(self, written: float, wire: float, turnaround: float) -> None:
        """A broadcast gets no answer: the slaves get ``turnaround`` (at least the silence) once it is on the wire."""
        self.quiet_at = written + wire + max(turnaround, self.silence)

    def answer_complete(self, request_length: int, answer: bytes, at: float) -> DecodeError | None:
        """The answer's last byte was read at ``at``. None if it may answer the request (the driver then waits
        until :attr:`trail_until` for bytes that follow it), else the error that drops it."""
        if self.min_char_time:
            least = (request_length + len(answer)) * self.min_char_time
            took = at - self.started
            if took < least:
                # on its way before the request: if it is an answer delivered before, it is a repeat
                self.repeated = self.healthy and answer in self.answers
                return DecodeError(
                    f"answer complete {took * 1000:.2f} ms after the request started, sooner than request and "
                    f"answer take on the wire ({least * 1000:.2f} ms): it was sent before the request, not "
                    "delivered",
                    answer,
                    "timing",
                )
        self.trail_until = at + self.silence
        return None

    def trailing(self, answer: bytes, extra: bytes) -> DecodeError:
        """Bytes followed the answer within the silent interval: the error that drops it (then :meth:`failed`)."""
        self.repeated = answer in extra or (self.healthy and self._holds_an_answer(extra))
        return DecodeError(
            f"answer followed by more bytes within the silent interval ({hex_bytes(extra)}): suspect, not delivered",
            answer + extra,
            "trailing",
        )

    def delivered(self, answer: bytes) -> None:
        """``answer`` was followed by silence until :attr:`trail_until`: the line is healthy again (or, while it
        is suspect of repeating answers, quarantined from the answer's last byte: rule 5)."""
        troubled, held = self.stray_seen, self.hold
        self.quiet_at = self.checked_at = self.trail_until
        self.hold = 0.0
        self.healthy = True
        self.answers.append(answer)
        if self.repeat_hold:
            self._quarantine_after_answer()
        elif troubled:  # rule 6: a late answer to what failed may still follow this one
            self.stray_seen = False
            self.hold = held
            self.quiet_at = self.trail_until - self.silence + held

    def _quarantine_after_answer(self) -> None:
        if self.stray_seen:
            self.stray_seen = False
            self.clean = 0
        else:
            self.clean += 1
            if self.clean >= CLEAN_ANSWERS:  # clean long enough: a healthy line again
                self.repeat_hold = 0.0
                return
        self.hold = self.repeat_hold
        self.quiet_at = self.trail_until - self.silence + self.repeat_hold

    def failed(self, now: float, quarantine: float) -> None:
        """The attempt failed at ``now`` (timeout, bad frame, suspect answer): quarantine the line."""
        hold = max(self.hold, quarantine)
        self.hold = hold
        self.quiet_at = max(self.quiet_at, now + hold)
        self.quarantines += 1
        if self.repeated:
            self.repeated = False
            self.repeat_seen(quarantine)
        self.stray_seen = True
        self.healthy = False
