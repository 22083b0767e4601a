"""Periodic CAN frames (:meth:`~starterbus.core.media.can.CanDriver.periodic`): python-can's ``send_periodic``
where the interface sends them itself (SocketCAN's broadcast manager, hardware), else the driver's own deadlines,
never a thread."""

from __future__ import annotations

from typing import Protocol

import can

from starterbus.core.canframe import CanFrame

__all__ = ["Periodic", "kernel_periodic", "to_message"]


class PeriodicOwner(Protocol):
    """The driver a :class:`Periodic` belongs to (its list of the periodics it sends itself)."""

    _periodics: list[Periodic]


class Periodic:
    """One frame sent every ``period`` s until :meth:`stop` (in the loop), by the interface or the driver."""

    def __init__(self, driver: PeriodicOwner, frame: CanFrame, period: float, now: float) -> None:
        self.driver, self.frame, self.period = driver, frame, period
        self.next_at = now
        self.task: can.broadcastmanager.CyclicSendTaskABC | None = None
        self.stopped = False

    def modify(self, frame: CanFrame) -> None:
        """Send ``frame`` from now on (same identifier)."""
        self.frame = frame
        if self.task is not None and isinstance(self.task, can.broadcastmanager.ModifiableCyclicTaskABC):
            self.task.modify_data(to_message(frame))

    def stop(self) -> None:
        if self.stopped:
            return
        self.stopped = True
        if self.task is not None:
            self.task.stop()
        self.driver._periodics = [p for p in self.driver._periodics if p is not self]


def to_message(frame: CanFrame) -> can.Message:
    return can.Message(arbitration_id=frame.can_id, data=frame.data, is_extended_id=False)


def kernel_periodic(bus: can.BusABC) -> bool:
    """Whether the interface sends periodic frames itself (not python-can's generic thread per task)."""
    own = getattr(type(bus), "_send_periodic_internal", None)
    return own is not None and own is not can.BusABC._send_periodic_internal
