"""Failed-login throttling: moved to :mod:`starterbus.ops.throttle`, shared with the web dashboard."""

from __future__ import annotations

from starterbus.ops.throttle import Block, Failure, Throttle, ThrottlePolicy

__all__ = ["Block", "Failure", "Throttle", "ThrottlePolicy"]
