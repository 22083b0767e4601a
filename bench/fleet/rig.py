"""How the fleet bench's rig (the line emulators and the simulator process) is scheduled beside the poller it
measures (``rtu_scale.py``).

By default the rig runs as it asks: each emulator takes a real-time priority where it is granted
(``SCHED_FIFO``, as root), so that a line never pauses, and every process goes where the kernel puts it. The
emulators then share the poller's cores: each byte they pace takes a core from the poller at once when both are
busy, and they evict its caches. Two ways to take that share out, each applied to every thread of the rig once
it runs (the emulators ask for their priority at their start):

- ``batch``: the rig under ``SCHED_BATCH`` (its wake-ups preempt nobody, as a UART's would not; the lines then
  pause when the cores are busy);
- ``emulators_on``: every emulator thread kept on that one CPU, at the priority it was granted (the lines keep
  their pace, the poller has the other core, shared with the simulator process and the kernel's work).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

__all__ = ["AS_ASKED", "RigScheduling", "process_cpu", "threads"]


def process_cpu(pid: int) -> float:
    """CPU seconds (user + system) a process has used so far, from /proc/PID/stat (Linux)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def threads(pid: int) -> list[int]:
    """The thread ids of process ``pid`` now (Linux: /proc)."""
    return [int(tid) for tid in os.listdir(f"/proc/{pid}/task")]


@dataclass(frozen=True)
class RigScheduling:
    """``batch``: the rig under SCHED_BATCH; ``emulators_on``: the CPU every emulator thread is kept on (None: any)."""

    batch: bool = False
    emulators_on: int | None = None

    def check(self) -> None:
        """Refuse a CPU this process may not use (one line, before anything starts)."""
        if self.emulators_on is not None:
            allowed = sorted(os.sched_getaffinity(0))
            if self.emulators_on not in allowed:
                raise SystemExit(f"--emulators-on {self.emulators_on}: not one of this machine's CPUs {allowed}")

    def apply(self, simulator: int, emulators: Sequence[int]) -> None:
        """Schedule the running rig: the simulator process and the emulator processes, every thread of each."""
        if self.batch:
            for pid in (simulator, *emulators):
                for tid in threads(pid):
                    os.sched_setscheduler(tid, os.SCHED_BATCH, os.sched_param(0))
        if self.emulators_on is not None:
            for pid in emulators:
                for tid in threads(pid):
                    os.sched_setaffinity(tid, {self.emulators_on})

    def describe(self, granted: Iterable[str]) -> str:
        """What the report says of the rig, given what each emulator says it was granted."""
        said = "SCHED_BATCH" if self.batch else ", ".join(sorted(set(granted)))
        return said if self.emulators_on is None else f"{said}; emulators on CPU {self.emulators_on}"


#: the rig as it asks to run (the default)
AS_ASKED = RigScheduling()
