"""How a long-running command (``serve``, ``opcua``) learns to stop: Ctrl-C, SIGTERM or its ``--duration``."""

from __future__ import annotations

import asyncio
import signal
import threading


def until_signalled(stop: asyncio.Event, duration: float | None) -> list[int]:
    """Set ``stop`` on Ctrl-C, on SIGTERM or after ``duration`` s; the list returned gets SIGINT if that was it.

    The caller then shuts down cleanly and exits 130 after Ctrl-C (0 after SIGTERM or the duration).
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
    return caught
