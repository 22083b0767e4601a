"""The rules of a command: what is checked before its first frame (who controls the starter, its state), and
what shows it took effect (:func:`reached`).

A soft starter takes its start/stop commands from the place its operator chose (the control-source parameter:
terminals, keypad, the bus, or the bus beside one of them), and its status tells whether the bus has control
(status word bit 14, or the network-control bit of an assembly). Before ``start``, ``stop`` or ``reset``:

1. **The control-source parameter**, where the profile names one (``[control] source_key``) and the transport
   can read it: a code not among ``source_bus_codes`` means the starter takes start/stop only from its
   terminals or keypad. Refused: the command would be ignored, or fight the local operator.
2. **The status**: a motor starting, running or stopping while the bus-control bit is off was set going by the
   terminals, the keypad or another master (a master's own command carries the bus-control bit). Refused:
   a stop would take a motor from whoever runs it. The bit alone, on a stopped starter, means nothing: no
   master has commanded it yet, and the transport takes bus control with the command itself.
3. **A start on a faulted starter** is refused, override or not: it cannot take effect, and it would leave the
   run command set for whenever the fault is reset. Reset first.

1 and 2 raise :class:`~starterbus.core.errors.ControlSourceError` unless ``force`` (CLI ``--force``), which
the audit record then notes. Taking and releasing bus control are the explicit hand-over: never refused here.
"""

from __future__ import annotations

from collections.abc import Mapping

from starterbus.core.device_access import DeviceAccess
from starterbus.core.errors import (
    ControlSourceError,
    Refusal,
    RemoteDeviceError,
    StarterbusError,
    StateRuleError,
    UnsupportedOperationError,
)
from starterbus.core.status import Command, MotorState, Status
from starterbus.core.transport_template import Capability

#: the states in which a motor is being driven by whoever holds its control
_MOVING = frozenset({MotorState.STARTING, MotorState.RUNNING, MotorState.STOPPING})
_HAND_OVER = frozenset({Command.TAKE_BUS_CONTROL, Command.RELEASE_BUS_CONTROL})
OVERRIDE_HINT = "override (CLI --force, API force=True; never from remote callers) only if that control lets go"


def source_parameter(device: DeviceAccess) -> str | None:
    """Why the control-source parameter keeps the bus out (None: it lets the bus command, or cannot be read)."""
    traits = device.profile.control
    if not traits.source_key or Capability.READ_PARAMETERS not in device.capabilities:
        return None
    point = device.profile.point(traits.source_key)
    try:
        value = device.read_value(point)
    except UnsupportedOperationError:  # this path has no address for it (said before anything was sent)
        return None
    except RemoteDeviceError as exc:
        if exc.reason is Refusal.NOT_AVAILABLE:  # the device has no such parameter: the status alone tells
            return None
        raise
    if value.raw in traits.source_bus_codes:
        return None
    return (
        f"its {point.key} ({point.address}) is {value.text()}: it takes start/stop commands from there, not from "
        "the bus"
    )


def status_says_elsewhere(status: Status | None) -> str | None:
    """Why the status shows a motor driven from elsewhere (None: it does not)."""
    if status is None or status.bus_control is not False or status.state not in _MOVING:
        return None
    return (
        f"the motor is {status.state.value} and the status says its commands do not come from the bus (bus-control "
        "bit off): it was set going from the terminals, the keypad or another master"
    )


def check_command(
    device: DeviceAccess, command: Command, status: Status | None, *, force: bool = False, read_source: bool = True
) -> str | None:
    """Raise unless ``command`` may go to ``device`` now (``status``: its present status, None if unknown).

    Returns the reason ``force`` overrode (for the audit record), else None. ``read_source`` False skips the
    parameter (a second check right before sending, on the status just read).
    """
    if command in _HAND_OVER:
        return None
    if command is Command.START and status is not None and status.fault:
        raise StateRuleError(
            f"start {device.describe()}: it is faulted (fault {status.fault_code}: {status.fault_text}); reset the "
            "fault first (a start now cannot take effect and would leave the run command set); nothing sent"
        )
    try:
        reason = (source_parameter(device) if read_source else None) or status_says_elsewhere(status)
    except StarterbusError as exc:
        if not force:
            raise
        return f"who controls it not checked ({exc})"
    if reason is None or force:
        return reason
    raise ControlSourceError(
        f"{command.value} {device.describe()}: refused, the starter is controlled from elsewhere: {reason}; "
        f"{OVERRIDE_HINT}; nothing sent",
        reason,
    )


#: the states that show a command took effect
_TARGETS: Mapping[Command, frozenset[MotorState]] = {
    Command.START: frozenset({MotorState.STARTING, MotorState.RUNNING}),
    Command.SOFT_STOP: frozenset({MotorState.STOPPING, MotorState.READY, MotorState.STOPPED}),
}


def reached(command: Command, status: Status) -> bool | None:
    """Whether ``status`` shows ``command`` took effect; None when this path cannot tell."""
    if command in _TARGETS:
        return status.state in _TARGETS[command]
    if command is Command.FAULT_RESET:
        return not status.fault
    if status.bus_control is None:
        return None
    return status.bus_control is (command is Command.TAKE_BUS_CONTROL)
