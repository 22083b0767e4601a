"""The transport contract's names in one place, where plugins written before :mod:`starterbus.core` exported them
import them from: the :class:`Transport` template (:mod:`starterbus.core.transport_template`), the plugin object
that opens it (:mod:`starterbus.core.plugin`) and what a poll gives (:mod:`starterbus.core.polling`).

New code imports these names from :mod:`starterbus.core`. This module sits above the plugin API (the plugin names
the transport it opens), so no module of the core below the plugin API imports it.
"""

from __future__ import annotations

from starterbus.core.plugin import Annotation, RunningSimulator, TransportPlugin
from starterbus.core.polling import PlannedRequest, PollResult, PollTask, TransportCounters
from starterbus.core.transport_template import (
    ALL_CAPABILITIES,
    CAPABILITY_HOOKS,
    TEMPLATE_METHODS,
    Capability,
    Transport,
)

__all__ = [
    "ALL_CAPABILITIES",
    "CAPABILITY_HOOKS",
    "TEMPLATE_METHODS",
    "Annotation",
    "Capability",
    "PlannedRequest",
    "PollResult",
    "PollTask",
    "RunningSimulator",
    "Transport",
    "TransportCounters",
    "TransportPlugin",
]
