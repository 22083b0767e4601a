"""The cycle driver of one station: its :class:`StationEngine` on a driver of a scheduler (a :class:`LocalDriver`,
or a gateway's ``StationDriver``; no thread of its own, no lock: docs/engine.md, step 6). Every exchange carries
the control word (PZD) and the PKW engine's words; PZD and PKW are independent, so a start or stop is never
delayed by a pending or stuck parameter task.

Two ways to run the cycles:

- ``cycle > 0``: an exchange every ``cycle`` seconds, as deadlines of the loop: continuously while the loop's own
  thread runs (a fleet or a service started it), else while a caller waits on the station (leader mode: a CLI
  command or a script drives the loop in its own thread for as long as it waits);
- ``cycle == 0``: exchanges back to back while a caller waits for something (on demand), none otherwise.

Which loop: a channel on a medium of the engine (a gateway: its Modbus TCP connection, ``gateway.py``) names its
loop, the process's scheduler, and gives the station's driver (:meth:`Channel.driver`); a channel that exchanges
in this process without blocking (:class:`SimChannel`) runs on the process's scheduler too, so a fleet multiplexes
both with every other medium. A channel that may block in its call (a third-party card) runs on a loop of its own
per channel type (:func:`loop_for`), so its calls never delay another medium's I/O; a link with a clock of its own
(a test's manual clock) gets a loop on that clock.

A command's control words are each held for ``hold`` exchanges and at least ``pulse`` seconds (so a reset pulse
reaches a slave behind a gateway whose own DP cycle is slower than ours); the last word stays in force.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Hashable, Sequence
from dataclasses import dataclass
from typing import TypeVar, cast

from starterbus.core import (
    SW_FAULT,
    SW_RUNNING,
    SW_STARTING,
    Driver,
    Scheduler,
    StarterbusError,
    TransportError,
    process_scheduler,
)
from starterbus.transports.profibus_pkw.codec.codes import Ppo
from starterbus.transports.profibus_pkw.codec.telegram import NO_TASK, PkwRequest
from starterbus.transports.profibus_pkw.driver.channels import Channel, channel_error
from starterbus.transports.profibus_pkw.driver.gateway import StationDriver
from starterbus.transports.profibus_pkw.master.handshake import PkwEngine, PkwJob
from starterbus.transports.profibus_pkw.master.station import (
    ControlWords,
    FreshInputs,
    PkwTask,
    StationEngine,
    StationRequest,
    StationTicket,
    output_words_of,
)

Clock = Callable[[], float]
T = TypeVar("T")

#: the outer bound of a wait beyond the requests' own time limits: only a stalled loop gets there
STALL = 30.0

_loops: dict[Hashable, Scheduler] = {}
_loops_lock = threading.Lock()


def loop_for(channel: Channel, clock: Clock) -> Scheduler:
    """The loop a link on ``channel`` runs on (see the module's text)."""
    own = channel.scheduler()
    if own is not None:
        return own
    if clock is time.monotonic and channel.in_process:
        return process_scheduler()
    if clock is not time.monotonic:
        return Scheduler(clock)  # a test's own clock: a loop of its own
    key = channel.loop_key()
    with _loops_lock:
        loop = _loops.get(key)
        if loop is None:
            loop = _loops[key] = Scheduler()
    return loop


@dataclass(frozen=True, slots=True)
class LinkStats:
    exchanges: int  # successful exchanges
    failures: int  # failed exchange attempts
    last_error: str | None


class CyclicLink:
    """Drives one DP slave through one :class:`Channel`. Thread-safe (only the loop's leader calls the engine)."""

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
        self._has_pkw = self.ppo.has_pkw
        self.engine = engine
        self.cycle = cycle
        self.hold = hold
        self.pulse = pulse
        self.clock = clock
        self.name = name
        where = channel.describe()

        def make_station(pkw: PkwEngine | None = None) -> StationEngine:
            fresh = pkw or PkwEngine(engine.errors, engine.limits)
            station = StationEngine(
                self.ppo, fresh, cycle=cycle, hold=hold, pulse=pulse, where=where, reply_within=channel.reply_within
            )
            if pkw is None:  # after a defect crashed the old engine: nothing of its state is trusted, and the word
                station.control = None  # in the output area is left as it is (never a word that could stop a run)
            return station

        first = [make_station(engine)]
        self._pkw_bound = first[0].pkw_budget + STALL  # the same for every station made here (the same limits)
        self._pkw_what = f"{name}: PKW task"
        self._loop = loop_for(channel, clock)
        self._driver = channel.driver(
            name or where, lambda: first.pop() if first else make_station(), self._loop.clock, channel_error
        )
        self._opened = False
        self._added = False

    @property
    def loop(self) -> Scheduler:
        """The loop the station runs on."""
        return self._loop

    @property
    def driver(self) -> Driver[StationEngine]:
        """The station's driver on that loop."""
        return self._driver

    def waits_on(self) -> tuple[int, float]:
        """The descriptor (-1: none) and the time a poller outside the loop waits for before its next turn: the
        station's deadline, and its gateway connection's descriptor and deadline when it has one."""
        driver = self._driver
        if isinstance(driver, StationDriver):
            medium = driver.gateway.connection.driver
            return medium.fd, min(driver.deadline, medium.deadline)
        return -1, driver.deadline

    @property
    def multiplexed(self) -> bool:
        """On the process's scheduler (a gateway, an in-process channel): a fleet polls it without a thread."""
        return self._loop is process_scheduler()

    @property
    def station(self) -> StationEngine:
        """The station's engine (a fresh one after a defect crashed the old)."""
        return self._driver.engine

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
        loop, driver = self._loop, self._driver

        def add(now: float) -> int | None:
            word = driver.engine.adopt(snap.outputs, snap.inputs)
            loop.add(driver)
            return word

        word = self._in_loop(add, "open")
        self._opened = self._added = True
        return word

    def _in_loop(self, fn: Callable[[float], T], what: str) -> T:
        """``fn(now)`` in the loop: at once when the caller can lead it, else queued and waited for."""
        loop = self._loop
        if loop.lead():
            try:
                return fn(loop.clock())
            finally:
                loop.release()
        return loop.wait(loop.call(fn), STALL, f"{self.name}: {what}")

    @property
    def last_inputs(self) -> tuple[int, ...] | None:
        """The input words of the last exchange (or of the snapshot taken on open)."""
        return self.station.last_in

    def fences_before(self, request: PkwRequest) -> list[PkwRequest]:
        """The fence reads the engine would send before ``request`` (:meth:`PkwEngine.fences_before`, asked in the
        loop): for a preview."""
        if not self._has_pkw or not self._added:
            return []
        return self._in_loop(lambda now: self.station.pkw.fences_before(request), "preview")

    def motor_running(self) -> bool:
        """From the last status word: starting or running, and no fault."""
        words = self.last_inputs
        if not words:
            return False
        zsw = words[2] if self.ppo is Ppo.PPO1 else words[0]
        return bool(zsw & (SW_STARTING | SW_RUNNING)) and not zsw & SW_FAULT

    def close(self) -> None:
        """Stop cycling; leave "no task" in the output area (best effort) and release the channel."""
        loop, driver = self._loop, self._driver
        try:
            if self._added:
                self._added = False

                def remove(now: float) -> None:
                    loop.remove(driver)
                    driver.engine.close(TransportError(f"{self.name or self.channel.describe()}: closed"), now)
                    driver.complete(now)

                self._in_loop(remove, "close")
            station = driver.engine
            if self._opened and station.last_ok and self.ppo is Ppo.PPO1:
                self.channel.exchange(output_words_of(self.ppo, NO_TASK, station.control))
        except Exception:
            pass
        finally:
            self._opened = False
            self.channel.close()

    @property
    def running(self) -> bool:
        """Cycling (``cycle > 0``) between open and close."""
        return self._added and self.cycle > 0

    # -- one exchange ---------------------------------------------------------------------------------------

    def _run(self, request: StationRequest, bound: float, what: str) -> StationTicket:
        if not self._added:
            raise TransportError(f"{self.name or self.channel.describe()}: the link is not open")
        (ticket,) = self._loop.run(self._driver, [request], bound + STALL, what)
        assert isinstance(ticket, StationTicket)
        return ticket

    def run_cycle(self) -> None:
        """One exchange (the next cycle's, with ``cycle > 0``); a channel failure is recorded, not raised."""
        try:
            self._run(FreshInputs(STALL), STALL, f"{self.name}: one exchange")
        except StarterbusError:
            pass

    # -- PZD -------------------------------------------------------------------------------------------------

    @property
    def control(self) -> int | None:
        """The control word this link puts in the output area; None while passive (see :meth:`open`)."""
        return self.station.control

    def send_control(self, words: Sequence[int], timeout: float = 2.0) -> None:
        """Send each word for ``hold`` exchanges (and ``pulse`` seconds); the last one stays in force."""
        if not words:
            return
        for word in words:
            if not 0 <= word <= 0xFFFF:
                raise ValueError(f"control word {word!r} is not 16 bits")
        budget = timeout + len(words) * (self.hold * self.cycle + self.pulse)
        self._run(ControlWords(tuple(words), timeout), budget, f"{self.name}: control words").outcome()

    def inputs(self, timeout: float = 2.0) -> tuple[int, ...]:
        """Input words from an exchange that started after this call (fresh status)."""
        ticket = self._run(FreshInputs(timeout), timeout, f"{self.name}: inputs")
        return cast("tuple[int, ...]", ticket.outcome())

    # -- PKW -------------------------------------------------------------------------------------------------

    def pkw(self, request: PkwRequest, what: str = "") -> PkwJob:
        """Run one PKW task to its end; returns the finished job or raises its error."""
        if not self._has_pkw:
            raise ValueError("PPO3 has no PKW area")
        if not self._added:  # _run's, inline (once per read)
            raise TransportError(f"{self.name or self.channel.describe()}: the link is not open")
        text = f"{self.name}: {what}" if what else self._pkw_what
        (ticket,) = self._loop.run(self._driver, [PkwTask(request, what)], self._pkw_bound, text)
        assert isinstance(ticket, StationTicket)
        job = ticket.job
        assert job is not None
        if job.error is not None:
            raise job.error
        if ticket.error is not None:  # cancelled or failed around the job (a closed link)
            raise ticket.error
        return job

    def stats(self) -> LinkStats:
        station = self.station
        error = station.last_error
        return LinkStats(station.exchanges, station.failures, str(error) if error else None)
