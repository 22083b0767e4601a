"""Whether a fleet's polling progresses, for supervisors: ``/readyz`` and systemd's watchdog (``Type=notify``).

Progress is a completed poll, answered or not: a bus whose devices are all offline still completes its probes,
so it progresses; a bus whose thread hangs (a blocked port, a bug) completes nothing. A bus is **stalled** when it
completed no poll for ``stall_after`` seconds (by default twice the longest of the devices' periods and the
fleet's ``max_backoff``, plus :data:`STALL_MARGIN` for one slow poll), unless the rounds asked for are done.

The service is **ready** once every device was polled once, while no bus is stalled and every extra check (a
broker connection, for ``serve``) passes. :class:`Watchdog` tells systemd: ``READY=1`` after the first round,
``WATCHDOG=1`` every half ``WatchdogSec`` only while no bus is stalled (so systemd restarts a hung service),
``STATUS=`` lines when the summary changes, ``STOPPING=1`` when the poller stops (:func:`notify_systemd`).
"""

from __future__ import annotations

import atexit
import math
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

from starterbus.fleet.config import FleetConfig
from starterbus.fleet.poller import FleetPoller
from starterbus.fleet.sdnotify import SystemdNotifier

#: seconds added to the stall limit for one slow poll (retries on a slow line, a DeviceNet connection wait)
STALL_MARGIN = 30.0
#: how often the watchdog thread looks at the poller when systemd asks for no faster pings, s
TICK = 0.5

#: an extra condition of readiness: None when it holds, else why not (one line)
Check = Callable[[], str | None]


def default_stall_after(config: FleetConfig) -> float:
    longest = max([d.period for d in config.devices] + [config.max_backoff])
    return 2.0 * longest + STALL_MARGIN


@dataclass(frozen=True, slots=True)
class Health:
    ready: bool
    reason: str  # "polling", or why not ready
    first_round: bool  # every device was polled once (answered or not)
    progressing: bool  # no bus is stalled
    stalled: tuple[str, ...]  # the stalled buses
    devices: int
    online: int

    def status_line(self) -> str:
        """What ``systemctl status`` shows (``STATUS=``): changes only when the state does."""
        if self.ready:
            return f"polling: {self.online} of {self.devices} devices online"
        return self.reason

    def as_json(self) -> dict[str, object]:
        return {
            "ready": self.ready,
            "reason": self.reason,
            "first_round": self.first_round,
            "progressing": self.progressing,
            "stalled": list(self.stalled),
            "devices": self.devices,
            "online": self.online,
        }


class PollHealth:
    """Looks at a :class:`FleetPoller` (any thread; thread-safe): progress per bus, readiness, data ages."""

    def __init__(
        self,
        poller: FleetPoller,
        *,
        stall_after: float | None = None,
        checks: Sequence[Check] = (),
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.poller = poller
        self.stall_after = default_stall_after(poller.config) if stall_after is None else stall_after
        self.checks = list(checks)
        self.clock = clock
        self._lock = threading.Lock()
        self._seen: dict[str, tuple[int, float]] = {}  # bus -> (polls completed, when that count was first seen)

    def check(self) -> Health:
        poller = self.poller
        with self._lock:
            now = self.clock()
            stalled = []
            for worker in poller.workers:
                polls = worker.stats.polls
                seen = self._seen.get(worker.bus.name)
                if seen is None or seen[0] != polls:
                    self._seen[worker.bus.name] = (polls, now)
                elif now - seen[1] > self.stall_after and not worker.finished:
                    stalled.append(worker.bus.name)
        runtimes = poller.runtimes()
        polled = sum(1 for r in runtimes if r.polls > 0)
        online = sum(1 for r in runtimes if r.online)
        first_round = polled == len(runtimes)
        reason = "polling"
        if poller.stopping.is_set():
            reason = "stopping"
        elif not first_round:
            reason = f"waiting for the first poll of every device ({polled} of {len(runtimes)} polled)"
        elif stalled:
            reason = f"stalled: no poll completed for {self.stall_after:g} s on bus {', '.join(stalled)}"
        else:
            for extra in self.checks:
                why = extra()
                if why is not None:
                    reason = why
                    break
        return Health(reason == "polling", reason, first_round, not stalled, tuple(stalled), len(runtimes), online)

    def ages(self) -> dict[str, float]:
        """Per device: seconds since its last good poll (``inf``: none yet)."""
        now = self.poller.clock()
        return {r.config.name: (now - r.last_ok) if r.last_ok is not None else math.inf for r in self.poller.runtimes()}


class Watchdog:
    """A thread telling systemd about ``health`` (nothing runs when ``$NOTIFY_SOCKET`` is unset)."""

    def __init__(self, health: PollHealth, notifier: SystemdNotifier, tick: float | None = None) -> None:
        self.health = health
        self.notifier = notifier
        self.ping_every = notifier.watchdog / 2 if notifier.watchdog else None
        self.tick = tick if tick is not None else min(TICK, self.ping_every or TICK)
        self.ready_sent = False
        self.pings = 0
        self.ticks = 0
        self._ticked = threading.Condition()
        self._stop = threading.Event()
        self._stopped = False
        self._thread = threading.Thread(target=self._run, name="systemd-notify", daemon=True)

    def start(self) -> Watchdog:
        if self.notifier.enabled:
            self._thread.start()
            atexit.register(self.stop)  # STOPPING=1 even when the process ends before the thread looks again
        return self

    def _run(self) -> None:
        last_ping = -math.inf
        status = ""
        while True:
            health = self.health.check()
            lines = []
            if not self.ready_sent and health.first_round:
                lines.append("READY=1")
                self.ready_sent = True
            now = time.monotonic()
            if self.ping_every is not None and health.progressing and now - last_ping >= self.ping_every:
                lines.append("WATCHDOG=1")
                last_ping = now
                self.pings += 1
            if health.status_line() != status:
                status = health.status_line()
                lines.append(f"STATUS={status}")
            if lines:
                self.notifier.notify(*lines)
            with self._ticked:
                self.ticks += 1
                self._ticked.notify_all()
            if self.health.poller.stopping.wait(self.tick) or self._stop.is_set():
                break
        self._stopping()

    def _stopping(self) -> None:
        with self._ticked:  # the thread and stop() may both get here: one STOPPING=1
            if self._stopped:
                return
            self._stopped = True
        self.notifier.notify("STOPPING=1", "STATUS=stopping")
        self.notifier.close()

    def wait_ticks(self, count: int, timeout: float) -> bool:
        """Wait until the thread has looked ``count`` more times (tests: an observable instead of a sleep)."""
        with self._ticked:
            target = self.ticks + count
            return self._ticked.wait_for(lambda: self.ticks >= target, timeout)

    def stop(self) -> None:
        """``STOPPING=1``: the service is shutting down (systemd then expects no more pings); also sent by the
        thread itself once the poller stops."""
        atexit.unregister(self.stop)
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join()
        self._stopping()

    def __enter__(self) -> Watchdog:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def notify_systemd(poller: FleetPoller, environ: Mapping[str, str] | None = None) -> Watchdog:
    """Tell systemd about ``poller`` from now until it stops, when systemd listens (``$NOTIFY_SOCKET``; else
    nothing runs): ``READY=1`` after the first round, ``WATCHDOG=1`` while its polls progress, ``STOPPING=1``."""
    return Watchdog(PollHealth(poller), SystemdNotifier.from_environment(environ)).start()
