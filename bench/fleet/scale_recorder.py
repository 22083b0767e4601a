"""The measured window of ``bench/fleet/scale.py``: the poller's sample sink that counts good samples per device
and takes a snapshot once every device reached a target, and the CPU of each thread of the process."""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass

from starterbus.fleet.poller import Sample


def thread_cpu() -> dict[str, float]:
    """CPU seconds per live Python thread name, from /proc/self/task/TID/schedstat (Linux; {} elsewhere)."""
    result: dict[str, float] = {}
    for thread in threading.enumerate():
        tid = thread.native_id
        if tid is None:
            continue
        try:
            with open(f"/proc/self/task/{tid}/schedstat", encoding="ascii") as f:
                result[thread.name] = int(f.read().split()[0]) / 1e9
        except (OSError, ValueError, IndexError):
            continue
    return result


def thread_group(name: str) -> str:
    """Which part of the benchmark a thread belongs to, by the names the package gives its threads."""
    if name.startswith("bus-rtu") or name.startswith(("bus-mux", "jobs-rtu")):  # one thread polls every RTU line
        return "rtu_workers"
    if name.startswith("bus-"):
        return "dnet_workers"
    if name.startswith(("devicenet-scanner", "can-reader")):  # since step 5 the master runs in starterbus-io
        return "scanners"
    if name.startswith("modbus-rtu"):
        return "rtu_sims"
    if name.startswith("devicenet-sim"):
        return "dnet_sims"
    return "other"


@dataclass
class Snapshot:
    wall: float
    cpu: float
    transactions: int
    bus_transactions: dict[str, int]  # FleetPoller transactions per bus
    samples: dict[str, int]  # good samples per device
    errors: int
    threads: dict[str, float]  # CPU seconds per thread name
    wire: dict[str, int]  # Modbus line -> RtuLine requests; DeviceNet bus -> scanner cycles


class Recorder:
    """The poller's sample sink: counts good samples per device and snapshots when every device reached a target."""

    def __init__(self, names: list[str], take: Callable[[], Snapshot]) -> None:
        self.index = {name: i for i, name in enumerate(names)}
        self.ok = [0] * len(names)
        self.errors = 0
        self.last_error: str | None = None
        self.take = take
        self.target: list[int] | None = None
        self.reached = 0
        self.snapshot: Snapshot | None = None
        self.done = threading.Event()
        self.lock = threading.Lock()  # samples (bus worker threads) against arm() (the main thread)

    def arm(self, more: int) -> None:
        """Wait for ``more`` good samples of every device from now (call with ``lock`` held)."""
        self.snapshot = None
        self.done.clear()
        self.target = [count + more for count in self.ok]
        self.reached = 0

    def __call__(self, sample: Sample) -> None:
        with self.lock:
            self._count(sample)

    def _count(self, sample: Sample) -> None:
        i = self.index[sample.device]
        if sample.error is not None:
            self.errors += 1
            self.last_error = f"{sample.device}: {sample.error}"
        if not sample.online or sample.error is not None:
            return
        self.ok[i] += 1
        target = self.target
        if target is not None and self.ok[i] == target[i]:
            self.reached += 1
            if self.reached == len(target):
                self.target = None
                self.snapshot = self.take()
                self.done.set()
