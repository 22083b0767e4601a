"""How a long-running command (``serve``, ``opcua``) learns to stop: Ctrl-C, SIGTERM, its ``--duration``, or a
worker's fatal failure (:mod:`starterbus.core.supervision`), and the exit code that follows."""

from __future__ import annotations

import asyncio
import signal
import threading

from starterbus.core.supervision import Supervisor


def until_signalled(stop: asyncio.Event, duration: float | None, supervisor: Supervisor | None = None) -> list[int]:
    """Set ``stop`` on Ctrl-C, on SIGTERM, after ``duration`` s or when a worker of ``supervisor`` fails for good;
    the list returned gets SIGINT if that was it.

    The caller then shuts down cleanly and calls :func:`exit_code`.
    """
    loop = asyncio.get_running_loop()
    caught: list[int] = []

    def on(sig: int) -> None:
        if sig == signal.SIGINT:
            caught.append(sig)
        stop.set()

    if threading.current_thread() is threading.main_thread():  # signals reach only the main thread's loop
        for sig in (signal.SIGINT, signal.SIGTERM):
            loop.add_signal_handler(sig, on, sig)
    if duration is not None:
        loop.call_later(duration, stop.set)
    if supervisor is not None:

        def failed(_failure: object) -> None:  # any thread
            if not loop.is_closed():
                loop.call_soon_threadsafe(stop.set)

        supervisor.on_fatal(failed)
    return caught


def exit_code(interrupted: list[int], supervisor: Supervisor | None = None) -> int:
    """After the clean shutdown: a worker's failure raises (one line, exit 1); else 130 after Ctrl-C, 0 after
    SIGTERM or the duration."""
    if supervisor is not None:
        supervisor.check()
    return 130 if interrupted else 0
