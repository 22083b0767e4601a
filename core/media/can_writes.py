"""What a :class:`~starterbus.core.media.can.CanDriver` writes on its bus (in the loop): the engines' frames
(:meth:`BusWrites.write`: a refused frame logged and counted), one-off frames that must not fail quietly
(:meth:`BusWrites.send`: a refused frame raises), the periodic frames (:meth:`BusWrites.periodic`: the interface's
cyclic send where it has its own, else at the driver's deadlines), and the python-can messages kept for frames
sent again."""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import TypeVar

import can

from starterbus.core.canframe import CanFrame
from starterbus.core.errors import TransportError
from starterbus.core.media.can_engines import EngineSet
from starterbus.core.media.can_periodic import Periodic, kernel_periodic, to_message
from starterbus.core.media.can_reader import QueueWait

__all__ = ["MESSAGE_CACHE", "BusWrites"]

log = logging.getLogger("starterbus.core.media.can")  # the driver's logger

MESSAGE_CACHE = 512  # python-can messages kept for frames sent again (poll commands, heartbeats)

T = TypeVar("T")


class BusWrites(EngineSet):
    """The writing half of a :class:`~starterbus.core.media.can.CanDriver` (its attributes, set by its
    ``__init__``)."""

    bus: can.BusABC
    sent: int
    _periodics: list[Periodic]
    _messages: dict[CanFrame, can.Message]
    _queue: QueueWait | None

    def call(self, fn: Callable[[float], T], what: str) -> T:
        raise NotImplementedError  # the driver's (CanDriver.call)

    def periodic(self, frame: CanFrame, period: float, now: float) -> Periodic:
        """Send ``frame`` every ``period`` s from now on (the interface's cyclic send where it has its own,
        else at the driver's deadlines)."""
        task = Periodic(self, frame, period, now)
        if kernel_periodic(self.bus):
            task.task = self.bus.send_periodic(to_message(frame), period, store_task=False)
        else:
            self._periodics.append(task)
        return task

    def write(self, frames: Sequence[CanFrame]) -> None:
        """Write what the engines give (in the loop): a failed send is logged and counted in :attr:`errors`, the
        engine's own timeout then tells its caller (:meth:`send` raises instead)."""
        for frame in frames:
            try:
                self.bus.send(self._message(frame))
                self.sent += 1
            except can.CanError as exc:
                log.warning("CAN send %s on %s failed: %s", frame.text(), self.name, exc)
                self.errors.append(f"send {frame.text()} failed: {exc}")

    def send(self, frames: Sequence[CanFrame], what: str) -> None:
        """Write ``frames`` now, in this order, from outside the loop (a one-off frame that must not fail quietly:
        NMT start, a command's output words): a frame the bus refuses is a :class:`TransportError` naming it and
        ``what``, and the frames after it are not sent. The other engines on the bus that want them see them."""

        def send(now: float) -> None:
            for index, frame in enumerate(frames):
                try:
                    self.bus.send(self._message(frame))
                except can.CanError as exc:
                    self.errors.append(f"send {frame.text()} failed: {exc}")
                    unsent = f" ({len(frames) - index - 1} more not sent)" if index + 1 < len(frames) else ""
                    raise TransportError(
                        f"{what}: CAN frame {frame.text()} not sent on {self.name}: {exc}{unsent}"
                    ) from None
                self.sent += 1
                if self.engines:
                    self._loop_back(None, (frame,), now)

        self.call(send, what)

    def _message(self, frame: CanFrame) -> can.Message:
        messages = self._messages
        message = messages.get(frame)
        if message is None:
            message = to_message(frame)
            if self._queue is not None:  # python-can's virtual bus: bytes (see _queue in __init__)
                setattr(message, "data", frame.data)  # noqa: B010 (bytes where python-can declares a bytearray)
            if len(messages) >= MESSAGE_CACHE:
                messages.clear()
            messages[frame] = message
        return message

    def _send_periodics(self, now: float) -> None:
        for periodic in self._periodics:
            if now >= periodic.next_at:
                self.write((periodic.frame,))
                periodic.next_at += periodic.period
                if periodic.next_at <= now:  # late (a stalled loop): on the grid again, no burst of catch-ups
                    periodic.next_at = now + periodic.period
