"""What callers ask of the DeviceNet master, as tickets of :class:`~.engine.MasterEngine` (docs/engine.md).

Each request acts on the :class:`MasterNode` when submitted (``start``), says whether its ticket has ended
(``check``: evaluated after every frame, tick and submission while the ticket is open) and what it ends with at
its own timeout (``expire``). Like the machine, nothing here reads a clock, locks or does I/O.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from starterbus.core import StarterbusError, TimeoutError, TransportError
from starterbus.transports.devicenet.codec.explicit import ExplicitRequest
from starterbus.transports.devicenet.master.link import (
    InputSample,
    IoPhase,
    LinkConfig,
    LinkState,
    MasterLink,
    ScannerState,
    Transaction,
)
from starterbus.transports.devicenet.master.node import MasterNode

__all__ = [
    "Acked",
    "Attach",
    "Begin",
    "Detach",
    "Expedite",
    "Explicit",
    "FreshInput",
    "MasterRequest",
    "Online",
    "Outputs",
    "ReleaseControl",
    "Reset",
    "TakeControl",
    "Until",
]

NOW = 0.0  # a request that ends at its submission has no timeout


class MasterRequest:
    """What a caller asks of the master. ``start`` acts on the machine at submission; ``check`` says whether the
    ticket has ended (returns ``(True, result)``, or raises a StarterbusError: the ticket fails); ``expire`` at
    the timeout (returns the result or raises)."""

    timeout: float = NOW

    def start(self, node: MasterNode, now: float) -> None:
        """Act on the machine (at submission, in the loop)."""

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        return True, None

    def expire(self, node: MasterNode, now: float) -> object:
        raise TimeoutError(f"DeviceNet master on {node.where}: {self!r} not done within {self.timeout:g} s")


@dataclass(eq=False)
class Begin(MasterRequest):
    """Go on line: the duplicate MAC ID check starts (its end: :class:`Online`)."""

    def start(self, node: MasterNode, now: float) -> None:
        frames = node.start(now)  # (taken from node._out: put back after the call, not into the list it gave)
        node._out.extend(frames)


@dataclass(eq=False)
class Online(MasterRequest):
    """Ends once the duplicate MAC ID check is over: the master's state (on line, or why not)."""

    timeout: float

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        if node.state is ScannerState.CHECKING:
            return False, None
        if node.state is not ScannerState.ONLINE:
            raise _starterbus(node.not_online())
        return True, node.state

    def expire(self, node: MasterNode, now: float) -> object:
        raise TimeoutError(
            f"DeviceNet master on {node.where}: duplicate MAC ID check did not finish in {self.timeout:g} s"
        )


@dataclass(eq=False)
class Reset(MasterRequest):
    """Leave the communication fault now (the duplicate MAC ID check runs again)."""

    def start(self, node: MasterNode, now: float) -> None:
        frames = node.reset(now)
        node._out.extend(frames)


@dataclass(eq=False)
class Attach(MasterRequest):
    """Scan one more slave; the ticket's result is its :class:`MasterLink`."""

    config: LinkConfig
    link: MasterLink | None = None

    def start(self, node: MasterNode, now: float) -> None:
        self.link = node.attach(self.config, now)

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        return True, self.link


@dataclass(eq=False)
class Detach(MasterRequest):
    """Stop scanning a slave, after the Release of its connection set (when ``release`` and established) was
    answered or timed out; the result: the release's error, if any."""

    link: MasterLink
    release: bool
    timeout: float
    transaction: Transaction | None = None

    def start(self, node: MasterNode, now: float) -> None:
        if self.release:
            self.transaction = node.release(self.link, now)

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        if self.transaction is not None and not self.transaction.done:
            return False, None
        node.detach(self.link)
        return True, self.transaction.error if self.transaction is not None else None

    def expire(self, node: MasterNode, now: float) -> object:
        node.detach(self.link)
        return TimeoutError(f"no answer to the Release within {self.timeout:g} s")


@dataclass(eq=False)
class Explicit(MasterRequest):
    """One explicit request/response (a :class:`Transaction`); the result: the (success) response."""

    link: MasterLink
    request: ExplicitRequest
    unconnected: bool
    timeout: float
    transaction: Transaction | None = None

    def start(self, node: MasterNode, now: float) -> None:
        self.transaction = Transaction(self.request, self.unconnected)
        node.submit(self.link, self.transaction, now)

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        transaction = self.transaction
        assert transaction is not None
        if not transaction.done:
            return False, None
        if transaction.error is not None:
            raise _starterbus(transaction.error)
        return True, transaction.response

    def expire(self, node: MasterNode, now: float) -> object:
        what = self.request.describe()
        raise TimeoutError(f"{self.link.describe()}: no response to {what} within {self.timeout:g} s")


@dataclass(eq=False)
class Outputs(MasterRequest):
    """Change a slave's outputs (polled at once, ``polls`` times); with ``timeout`` 0 the ticket ends at once,
    else when a poll carrying them was answered (:class:`Acked`). The result: the output sequence number."""

    link: MasterLink
    run: bool | None = None
    reset: bool | None = None
    select: int | None = None
    polls: int = 1
    timeout: float = NOW
    seq: int = 0

    def start(self, node: MasterNode, now: float) -> None:
        link, polls = self.link, self.polls
        self.seq = node.set_outputs(link, now, run=self.run, reset=self.reset, select=self.select, polls=polls)

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        if self.timeout <= 0:
            return True, self.seq
        return _acked(node, self.link, self.seq)

    def expire(self, node: MasterNode, now: float) -> object:
        return False


@dataclass(eq=False)
class Acked(MasterRequest):
    """Ends True once a poll that carried output sequence ``seq`` was answered; False when the link closed or
    cannot deliver (the caller asks why), or at the timeout."""

    link: MasterLink
    seq: int
    timeout: float

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        return _acked(node, self.link, self.seq)

    def expire(self, node: MasterNode, now: float) -> object:
        return False


def _acked(node: MasterNode, link: MasterLink, seq: int) -> tuple[bool, object]:
    if link.acked_seq >= seq:
        return True, True
    if link.state is LinkState.CLOSED or node.link_error(link) is not None:
        return True, False
    return False, None


@dataclass(eq=False)
class Expedite(MasterRequest):
    """Poll a slave now, ``polls`` times (a reader wants fresh inputs); ends at once."""

    link: MasterLink
    polls: int = 1

    def start(self, node: MasterNode, now: float) -> None:
        node.expedite(self.link, now, self.polls)


@dataclass(eq=False)
class FreshInput(MasterRequest):
    """The latest input sample of a polled slave once it is at most ``max_age`` old (polled at once if it is
    not); None at the timeout. Fails with the link's error (a communication fault, a duplicate responder)."""

    link: MasterLink
    max_age: float
    timeout: float

    def _fresh(self, now: float) -> InputSample | None:
        link, sample = self.link, self.link.sample
        if link.established and sample is not None and now - sample.at <= self.max_age:
            return sample
        return None

    def start(self, node: MasterNode, now: float) -> None:
        if node.link_error(self.link) is None and self._fresh(now) is None:
            node.expedite(self.link, now)  # a slow scan never fails a read: poll now

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        sample = self._fresh(now)
        if sample is not None:
            return True, sample
        error = node.link_error(self.link)
        if error is not None:
            raise _starterbus(error)
        return False, None

    def expire(self, node: MasterNode, now: float) -> object:
        return None


@dataclass(eq=False)
class TakeControl(MasterRequest):
    """Establish the polled I/O connection of a monitored slave (the outputs set before go out with its first
    poll); fails with why it could not."""

    link: MasterLink
    timeout: float

    def start(self, node: MasterNode, now: float) -> None:
        node.take_control(self.link, now)

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        link = self.link
        if link.polling:
            return True, None
        refused = node.link_error(link)
        if link.io not in (IoPhase.HELD, IoPhase.NONE) and refused is None:
            return False, None
        error = refused or link.io_error or link.last_error
        raise _starterbus(error) if error is not None else self._late()

    def expire(self, node: MasterNode, now: float) -> object:
        raise self._late()

    def _late(self) -> TimeoutError:
        return TimeoutError(
            f"{self.link.describe()}: the polled I/O connection was not established within {self.timeout:g} s"
        )


@dataclass(eq=False)
class ReleaseControl(MasterRequest):
    """Give the polled I/O connection back (monitoring goes on); ends when the Release was answered."""

    link: MasterLink
    timeout: float
    transaction: Transaction | None = None

    def start(self, node: MasterNode, now: float) -> None:
        self.transaction = node.release_control(self.link, now)

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        return self.transaction is None or self.transaction.done, None

    def expire(self, node: MasterNode, now: float) -> object:
        return None


@dataclass(eq=False)
class Until(MasterRequest):
    """Ends True once ``predicate()`` holds (evaluated in the loop, after every change), False at the timeout."""

    predicate: Callable[[], bool]
    timeout: float

    def check(self, node: MasterNode, now: float) -> tuple[bool, object]:
        return (True, True) if self.predicate() else (False, None)

    def expire(self, node: MasterNode, now: float) -> object:
        return False


def _starterbus(error: BaseException) -> StarterbusError:
    if isinstance(error, StarterbusError):
        return error
    return TransportError(f"{type(error).__name__}: {error}")
