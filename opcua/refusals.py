"""starterbus errors of the guarded path -> OPC UA status codes (the reason text goes to Status.LastOperation)."""

from __future__ import annotations

from asyncua import ua

from starterbus.aio import RemoteNotAllowed
from starterbus.core.errors import (
    RemoteDeviceError,
    StarterbusError,
    StateRuleError,
    TimeoutError,
    TransportError,
    UnsupportedOperationError,
    ValidationError,
)
from starterbus.core.guarded import (
    CommandNotReached,
    ConfirmationRefused,
    ReadBackMismatch,
    UncertainValueError,
)

#: most specific first: StateRuleError and UncertainValueError are ValidationErrors, TimeoutError a TransportError
_CODES: tuple[tuple[type[StarterbusError], int], ...] = (
    (StateRuleError, ua.StatusCodes.BadInvalidState),
    (UncertainValueError, ua.StatusCodes.BadNotWritable),
    (ValidationError, ua.StatusCodes.BadOutOfRange),
    (CommandNotReached, ua.StatusCodes.BadInvalidState),
    (ReadBackMismatch, ua.StatusCodes.BadDeviceFailure),
    (ConfirmationRefused, ua.StatusCodes.BadUserAccessDenied),
    (UnsupportedOperationError, ua.StatusCodes.BadNotSupported),
    (RemoteDeviceError, ua.StatusCodes.BadDeviceFailure),
    (TimeoutError, ua.StatusCodes.BadTimeout),
    (TransportError, ua.StatusCodes.BadCommunicationError),
)


def status_code(exc: StarterbusError, *, write: bool) -> int:
    """The status code for a refused or failed write (``write=True``) or method call."""
    if isinstance(exc, RemoteNotAllowed):
        return int(ua.StatusCodes.BadNotWritable if write else ua.StatusCodes.BadNotExecutable)
    for kind, code in _CODES:
        if isinstance(exc, kind):
            return code
    return int(ua.StatusCodes.BadUnexpectedError)


def code_name(code: int) -> str:
    return str(ua.StatusCode(code).name)
