"""The cycle driver of one station: every exchange carries the control word (PZD) and the PKW engine's words.

PZD and PKW are independent: the control word in force goes out on EVERY exchange whatever the PKW engine is
waiting for, so a start or stop is never delayed by a pending or stuck parameter task.

Two ways to run the cycles:

- ``cycle > 0``: a background thread exchanges every ``cycle`` seconds (like a DP master); callers wait for the
  exchanges they need.
- ``cycle == 0``: no thread; the calling thread runs exchanges back to back until what it waits for is there
  (on demand; useful for in-process simulation and benchmarks).

A command's control words are each held for ``hold`` exchanges and at least ``pulse`` seconds (so a reset pulse
reaches a slave behind a gateway whose own DP cycle is slower than ours); the last word stays in force.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from starterbus.core import CW_RESET, SW_FAULT, SW_RUNNING, SW_STARTING, EncodeError, StarterbusError, TimeoutError
from starterbus.transports.profibus_pkw.codec.codes import PROTOCOL, Ppo
from starterbus.transports.profibus_pkw.codec.telegram import (
    NO_TASK,
    PkwRequest,
    PkwResponse,
    Ppo1In,
    PzdIn,
    from_words,
)
from starterbus.transports.profibus_pkw.driver.channels import Channel, channel_error
from starterbus.transports.profibus_pkw.master.handshake import PkwEngine, PkwJob

Clock = Callable[[], float]


@dataclass(frozen=True, slots=True)
class LinkStats:
    exchanges: int  # successful exchanges
    failures: int  # failed exchange attempts
    last_error: str | None


class CyclicLink:
    """Drives one DP slave through one :class:`Channel`. Thread-safe."""

    def __init__(
        self,
        channel: Channel,
        engine: PkwEngine,
        *,
        cycle: float = 0.01,
        hold: int = 3,
        pulse: float = 0.0,
        clock: Clock = time.monotonic,
        name: str = "",
    ) -> None:
        if cycle < 0 or hold < 1 or pulse < 0:
            raise ValueError("cycle and pulse must be >= 0 and hold >= 1")
        self.channel = channel
        self.ppo: Ppo = channel.ppo
        self.engine = engine
        self.cycle = cycle
        self.hold = hold
        self.pulse = pulse
        self.clock = clock
        self.name = name
        self._cond = threading.Condition(threading.RLock())
        self._control: int | None = 0
        self._plan: deque[list[float]] = deque()  # [word, exchanges left, not before (time)]
        self._attempts = 0
        self._exchanges = 0
        self._failures = 0
        self._last_in: tuple[int, ...] | None = None
        self._last_error: StarterbusError | None = None
        self._last_ok = True
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._opened = False

    # -- lifecycle ------------------------------------------------------------------------------------------

    def open(self) -> int | None:
        """Read what is in force (without writing), adopt its control word, start cycling. Returns that word.

        If the channel cannot tell its output words (a gateway whose output and input areas share registers),
        the link stays PASSIVE on PZD: it leaves the control word in the output area as it is (the channel writes
        only the PKW words) until the first command. So a monitoring session never changes what another
        master, or a previous session, put there; ``None`` is returned.
        """
        try:
            snap = self.channel.snapshot()
        except Exception as exc:
            raise channel_error(exc) from exc
        with self._cond:
            self._last_in = snap.inputs
            if snap.outputs is not None:
                word = snap.outputs[2] if self.ppo is Ppo.PPO1 else snap.outputs[0]
                self._control = word & ~CW_RESET & 0xFFFF
            else:
                self._control = None
            self._opened = True
        if self.cycle > 0:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name=f"{PROTOCOL} cycle {self.name}", daemon=True)
            self._thread.start()
        return self._control

    @property
    def last_inputs(self) -> tuple[int, ...] | None:
        """The input words of the last exchange (or of the snapshot taken on open)."""
        with self._cond:
            return self._last_in

    def motor_running(self) -> bool:
        """From the last status word: starting or running, and no fault."""
        words = self.last_inputs
        if not words:
            return False
        zsw = words[2] if self.ppo is Ppo.PPO1 else words[0]
        return bool(zsw & (SW_STARTING | SW_RUNNING)) and not zsw & SW_FAULT

    def close(self) -> None:
        """Stop cycling; leave "no task" in the output area (best effort) and release the channel."""
        thread, self._thread = self._thread, None
        if thread is not None:
            self._stop.set()
            thread.join(timeout=max(1.0, 5 * self.cycle))
        try:
            with self._cond:
                if self._opened and self._last_ok and self.ppo is Ppo.PPO1:
                    self.channel.exchange(_outputs(self.ppo, NO_TASK, self._control))
        except Exception:
            pass
        finally:
            self._opened = False
            self.channel.close()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- one exchange ---------------------------------------------------------------------------------------

    def _run(self) -> None:
        next_at = self.clock()
        while not self._stop.is_set():
            self.run_cycle()
            next_at += self.cycle
            delay = next_at - self.clock()
            if delay < 0:  # overrun: do not try to catch up
                next_at = self.clock()
                delay = 0.0
            self._stop.wait(delay)

    def run_cycle(self) -> None:
        """One exchange: current control word + the PKW engine's words out, inputs to the engine."""
        with self._cond:
            now = self.clock()
            pkw = self.engine.output(now) if self.ppo is Ppo.PPO1 else NO_TASK
            stw = int(self._plan[0][0]) if self._plan else self._control
            self._attempts += 1
            try:
                words = self.channel.exchange(_outputs(self.ppo, pkw, stw))
                if self.ppo is Ppo.PPO1:  # count and range
                    from_words(Ppo1In, words)
                else:
                    from_words(PzdIn, words)
            except Exception as exc:
                error = channel_error(exc)
                self._failures += 1
                self._last_error = error
                self._last_ok = False
                self.engine.fail(error, self.clock())
                self._cond.notify_all()
                return
            now = self.clock()
            self._exchanges += 1
            self._last_in = words
            self._last_ok = True
            if self.ppo is Ppo.PPO1:
                self.engine.receive(PkwResponse(words[0], words[1]), now)
            if self._plan:
                step = self._plan[0]
                step[1] -= 1
                if step[1] <= 0 and now >= step[2]:
                    self._plan.popleft()
                    if self._plan:
                        self._plan[0][2] = now + self.pulse
            self._cond.notify_all()

    def _wait(self, done: Callable[[], bool], timeout: float) -> bool:
        """Wait until ``done()`` (evaluated under the lock); on demand mode runs the exchanges itself."""
        deadline = self.clock() + timeout
        if self.cycle > 0 and self.running:
            with self._cond:
                while not done():
                    left = deadline - self.clock()
                    if left <= 0:
                        return False
                    self._cond.wait(min(left, max(self.cycle, 0.001) * 4))
                return True
        while True:
            with self._cond:
                if done():
                    return True
                if self.clock() > deadline:
                    return False
                self.run_cycle()
                if self.cycle > 0:  # a closed link driven by hand still respects its cycle time
                    time.sleep(self.cycle)

    # -- PZD -------------------------------------------------------------------------------------------------

    @property
    def control(self) -> int | None:
        """The control word this link puts in the output area; None while passive (see :meth:`open`)."""
        return self._control

    def send_control(self, words: Sequence[int], timeout: float = 2.0) -> None:
        """Send each word for ``hold`` exchanges (and ``pulse`` seconds); the last one stays in force."""
        if not words:
            return
        for word in words:
            if not 0 <= word <= 0xFFFF:
                raise ValueError(f"control word {word!r} is not 16 bits")
        with self._cond:
            now = self.clock()
            self._plan.clear()  # a command still being sent is superseded (its caller returns)
            self._plan = deque([[float(w), float(self.hold), now + self.pulse] for w in words])
            self._control = words[-1]
            plan = self._plan
        budget = timeout + len(words) * (self.hold * self.cycle + self.pulse)
        if not self._wait(lambda: not plan, budget):
            with self._cond:
                error = self._last_error
            raise TimeoutError(
                f"{PROTOCOL}: control word(s) {', '.join(f'0x{w:04X}' for w in words)} not exchanged within "
                f"{budget:.2f} s" + (f" (last error: {error})" if error else "")
            )

    def inputs(self, timeout: float = 2.0) -> tuple[int, ...]:
        """Input words from an exchange that started after this call (fresh status)."""
        with self._cond:
            target = self._attempts + 1
        if not self._wait(lambda: self._attempts >= target, timeout):
            raise TimeoutError(f"{PROTOCOL}: no DP exchange within {timeout:.2f} s ({self.channel.describe()})")
        with self._cond:
            if not self._last_ok and self._last_error is not None:
                raise self._last_error
            assert self._last_in is not None
            return self._last_in

    # -- PKW -------------------------------------------------------------------------------------------------

    def pkw(self, request: PkwRequest, what: str = "") -> PkwJob:
        """Run one PKW task to its end; returns the finished job or raises its error."""
        if not self.ppo.has_pkw:
            raise ValueError("PPO3 has no PKW area")
        with self._cond:
            job = self.engine.submit(request, what)
        limits = self.engine.limits
        budget = limits.timeout + max(self.cycle, 0.001) * 4 + 1.0
        if not self._wait(lambda: job.done, budget):
            with self._cond:
                if not job.done:  # no exchange came back in time to apply the limits: the channel stalled
                    self.engine.cancel(
                        job,
                        TimeoutError(f"{PROTOCOL}: {job.describe()}: no DP exchange within {budget:.2f} s"),
                        self.clock(),
                    )
        if job.error is not None:
            raise job.error
        return job

    def stats(self) -> LinkStats:
        with self._cond:
            return LinkStats(self._exchanges, self._failures, str(self._last_error) if self._last_error else None)


def _outputs(ppo: Ppo, pkw: PkwRequest, stw: int | None) -> tuple[int | None, ...]:
    """The output words of one exchange; None = leave that word in the output area as it is (passive PZD)."""
    if (pkw.ind or pkw.pwe) and ppo is not Ppo.PPO1:
        raise EncodeError("PPO3 has no PKW area: parameter tasks need PPO1", field="ppo")
    if ppo is Ppo.PPO1:
        return (pkw.ind, pkw.pwe, stw, None if stw is None else 0)
    return (stw, None if stw is None else 0)
