"""The DeviceNet master on its bus: a :class:`MasterEngine` on the process's :class:`CanDriver` of that bus, run
by the process's scheduler (docs/engine.md, step 5). No thread of its own and no lock.

The protocol (duplicate MAC ID check, connection sequence, keep-alive, fragmentation, scan scheduling, the
communication fault and duplicate responders) lives in :mod:`~starterbus.transports.devicenet.master.node`, the
tickets callers wait on in :mod:`~starterbus.transports.devicenet.master.engine`. Each method of
:class:`Scanner` submits one ticket and waits for it: while no other thread runs the loop, the caller runs it
(a CLI ``status`` starts no thread but python-can's reader where the bus has no descriptor).

A master with a polled I/O connection (``LinkConfig.io``, or :meth:`Scanner.take_control`) must poll whether or
not anyone waits: the slave's watchdog stops the motor 4 x EPR after the last poll. From then until it closes,
the scanner keeps the loop's own thread running (``keep_running``). A master that only monitors runs its timers
whenever a caller leads (or the loop's thread runs, in a fleet or a service): a submission first runs what is
due, so a call after a quiet spell sees the present state.
"""

from __future__ import annotations

import functools
import random
import threading
import time
from collections.abc import Callable, Generator
from typing import Any, TypeVar

import can

from starterbus.core import (
    CanDriver,
    StarterbusError,
    Ticket,
    ToEngine,
    TransportError,
    keep_running,
    let_go,
    process_scheduler,
    run_steps,
    wait_ticket,
)
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest, ExplicitResponse
from starterbus.transports.devicenet.master.engine import MasterEngine
from starterbus.transports.devicenet.master.link import (
    InputSample,
    LinkConfig,
    MasterLink,
    ScannerConfig,
    ScannerState,
)
from starterbus.transports.devicenet.master.node import MasterNode
from starterbus.transports.devicenet.master.requests import (
    Acked,
    Attach,
    Begin,
    Detach,
    Expedite,
    Explicit,
    FreshInput,
    MasterRequest,
    Online,
    Outputs,
    ReleaseControl,
    Reset,
    TakeControl,
    Until,
)

__all__ = ["CAN_FILTERS", "VIRTUAL_HINT", "Scanner", "SlaveLink"]

SlaveLink = MasterLink
T = TypeVar("T")
#: what a master told that its virtual channel has no peer in this process should use instead
VIRTUAL_HINT = (
    "from another process, serve the simulator through its loopback bridge (starterbus simulate ... "
    "--devicenet virtual:bus0 --devicenet-bridge 127.0.0.1:54701) and use devicenet://remote/127.0.0.1:54701?mac=N"
)
#: the outer bound of a wait beyond the ticket's own timeout: only a stalled loop gets there
STALL = 30.0
#: every identifier the master listens to, as three mask filters: poll responses (group 1 id 15), explicit
#: responses (group 2 id 3) and duplicate MAC ID checks (group 2 id 7); exact routing follows in the driver
CAN_FILTERS: list[can.typechecking.CanFilter] = [
    {"can_id": 0x3C0, "can_mask": 0x7C0, "extended": False},
    {"can_id": 0x403, "can_mask": 0x607, "extended": False},
    {"can_id": 0x407, "can_mask": 0x607, "extended": False},
]


class Scanner:
    """One DeviceNet master on one CAN bus. Thread-safe (every call is a ticket on the scheduler); shared by
    every Device on that bus in a process. ``bus``: a python-can bus the caller opened (and closes)."""

    def __init__(
        self, config: ScannerConfig, bus: can.BusABC | None = None, clock: Callable[[], float] | None = None
    ) -> None:
        self.config = config
        self.where = f"{config.interface}/{config.channel}"
        self.loop = process_scheduler()
        if clock is not None and clock is not self.loop.clock:
            raise TransportError(f"DeviceNet master on {self.where}: the scheduler's clock is the only clock")
        self.clock = self.loop.clock
        if bus is None:
            self.driver = CanDriver.acquire(
                config.interface, config.channel, self.loop, config.bitrate, needs_peer=VIRTUAL_HINT
            )
            self._shared = True
        else:
            self.driver = CanDriver(bus, self.where, self.loop, owns_bus=False)
            self.driver.call(lambda now: self.loop.add(self.driver), "add the bus")
            self._shared = False
        self.machine = MasterNode(config, random.getrandbits(32), self.where)
        self.engine = MasterEngine(self.machine)
        self._wrap = functools.partial(ToEngine, self.engine)
        self._kept = False
        self._closed = False
        self._close_lock = threading.Lock()
        self.started = time.monotonic()
        self._wall_offset = time.time() - self.clock()
        try:
            self.driver.call(lambda now: self.driver.add(self.engine, CAN_FILTERS), "add the master")
            self._run(Begin())
        except BaseException:
            self._give_back()
            raise

    # -- state --------------------------------------------------------------------------------------------------

    @property
    def state(self) -> ScannerState:
        return self.machine.state

    @property
    def fault(self) -> BaseException | None:
        return self.machine.fault

    @property
    def cycles(self) -> int:
        """Poll answers published so far (all links)."""
        return self.machine.cycles

    @property
    def polls_sent(self) -> int:
        return self.machine.polls_sent

    @property
    def links(self) -> dict[int, MasterLink]:
        return self.machine.links

    @property
    def received(self) -> int:
        """Frames read from the bus (past its filters; every engine's on a shared bus)."""
        return self.driver.received

    @property
    def dropped(self) -> int:
        """Of them, frames no engine on the bus wanted."""
        return self.driver.dropped

    @property
    def errors(self) -> Any:
        """Malformed frames and failures of the engines on the bus (the last 100)."""
        return self.driver.errors

    @property
    def io_cpu(self) -> float:
        """CPU seconds of the bus's I/O: the loop's own thread while it runs (all of it: the wait, the wake-ups,
        every driver it serves), else the driver's steps in whichever thread led; plus the bus's reader thread."""
        for thread in threading.enumerate():
            if thread.name == "starterbus-io" and thread.ident is not None:
                try:
                    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident)) + self.driver.reader_cpu
                except (OSError, AttributeError):
                    break
        return self.driver.io_cpu

    def wall_time(self, at: float) -> float:
        """Wall-clock time of a machine time (samples carry the machine's clock)."""
        return at + self._wall_offset

    def link_error(self, link: MasterLink) -> Exception | None:
        return self.machine.link_error(link)

    # -- tickets ------------------------------------------------------------------------------------------------

    def _run(self, request: MasterRequest) -> Ticket[MasterRequest, Any]:
        return wait_ticket(self.loop, self.driver, request, self._what(request), wrap=self._wrap, stall=STALL)

    def _outcome(self, request: MasterRequest) -> Any:
        return self._run(request).outcome()

    def drive(self, steps: Generator[MasterRequest, Any, T]) -> T:
        """Run a sequence of tickets written as a generator (it yields a request, is sent the ticket's result or
        thrown its error, and returns its own result): the blocking form of what a fleet's poll task runs."""
        return run_steps(self.loop, self.driver, steps, self._what, wrap=self._wrap, stall=STALL)

    def _what(self, request: MasterRequest) -> str:
        return f"DeviceNet master on {self.where}: {type(request).__name__}"

    def keep(self) -> None:
        """From now on the master polls unattended (a polled I/O connection): the loop's own thread runs."""
        if not self._kept:
            self._kept = True
            keep_running(self.loop)

    # -- user side ----------------------------------------------------------------------------------------------

    def attach(self, config: LinkConfig) -> MasterLink:
        if config.io:
            self.keep()
        link: MasterLink = self._outcome(Attach(config))
        return link

    def detach(self, link: MasterLink, release: bool = True) -> None:
        """Stop scanning a slave; release its connection set first if it is established."""
        error = self._outcome(Detach(link, release, self.config.timeout * 2))
        if error is not None:
            link.note(self.clock(), f"release on close failed: {error}")

    def request(
        self, link: MasterLink, request: ExplicitRequest, *, unconnected: bool = False, timeout: float | None = None
    ) -> ExplicitResponse:
        """Send an explicit request and wait for its (success) response."""
        wait = self.config.timeout * 4 if timeout is None else timeout
        response: ExplicitResponse = self._outcome(Explicit(link, request, unconnected, wait))
        return response

    def take_control(self, link: MasterLink, timeout: float) -> None:
        """Establish the polled I/O connection of a monitored slave (the outputs set before go out with its
        first poll); raises why it could not."""
        self.keep()
        self._outcome(TakeControl(link, timeout))

    def release_control(self, link: MasterLink) -> None:
        """Give the polled I/O connection back (monitoring over explicit messaging goes on)."""
        self._outcome(ReleaseControl(link, self.config.timeout * 2))

    def wait_for(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Until ``predicate`` holds (evaluated in the loop after every change); True if it did."""
        return bool(self._outcome(Until(predicate, timeout)))

    def fresh_input(self, link: MasterLink, max_age: float, timeout: float) -> InputSample | None:
        """The latest input sample once at most ``max_age`` old (polled at once if older); None at the timeout;
        raises the link's error (a communication fault, a duplicate responder)."""
        sample: InputSample | None = self._outcome(FreshInput(link, max_age, timeout))
        return sample

    def set_outputs(
        self,
        link: MasterLink,
        *,
        run: bool | None = None,
        reset: bool | None = None,
        select: int | None = None,
        polls: int = 1,
    ) -> int:
        """Change a slave's outputs (polled at once); returns the output sequence number to wait for."""
        seq: int = self._outcome(Outputs(link, run, reset, select, polls))
        return seq

    def expedite(self, link: MasterLink, polls: int = 1) -> None:
        """Poll ``link`` now (a reader wants fresh inputs)."""
        self._outcome(Expedite(link, polls))

    def wait_acked(self, link: MasterLink, seq: int, timeout: float) -> bool:
        """Whether a poll carrying output sequence ``seq`` was answered within ``timeout``."""
        return bool(self._outcome(Acked(link, seq, timeout)))

    def reset(self) -> None:
        """Leave the communication fault now (the duplicate MAC ID check runs again)."""
        self._outcome(Reset())

    def wait_online(self, timeout: float) -> None:
        self._outcome(Online(timeout))

    def close(self) -> None:
        for link in list(self.machine.links.values()):
            try:
                self.detach(link)
            except StarterbusError:
                pass
        self._halt()

    def abandon(self) -> None:
        """Stop at once without releasing anything (what a crashed or unplugged master leaves behind)."""
        self._halt()

    def _halt(self) -> None:
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        try:
            driver, engine = self.driver, self.engine

            def remove(now: float) -> None:
                driver.remove(engine, now)
                self.machine.close()

            driver.call(remove, "remove the master")
        finally:
            self._give_back()

    def _give_back(self) -> None:
        if self._kept:
            self._kept = False
            let_go(self.loop)
        if self._shared:
            self.driver.release()
        else:
            self.driver.close()

    def stats(self) -> dict[str, float]:
        elapsed = time.monotonic() - self.started
        machine = self.machine
        return {
            "cycles": machine.cycles,
            "polls": machine.polls_sent,
            "io_cpu_s": self.io_cpu,
            "elapsed_s": elapsed,
            "received": self.received,
            "dropped": self.dropped,
        }
