"""A DCMD the session accepted, run through the fleet's guarded path: the text of its outcome for ``Last
Command``, whether anything was sent, and whether the guarded path audited it already.

The guarded path audits every operation it sends, a state rule that refuses a command and an operation not
confirmed; the rest of the refusals (the fleet file's ``remote`` table, validation of writes, an unknown key, an
unsupported operation) and errors before or beside it are for the driver to audit (``audited`` False).
"""

from __future__ import annotations

from dataclasses import dataclass

from starterbus.aio import AsyncFleet, RemoteNotAllowed
from starterbus.core.errors import StateRuleError, UnknownPointError, UnsupportedOperationError, ValidationError
from starterbus.core.guarded import ConfirmationRefused, GuardedOperationError, Outcome
from starterbus.serve.actions import CommandRequest


def describe_outcomes(outcomes: list[Outcome]) -> str:
    parts = []
    for o in outcomes:
        if o.key is not None:
            shown = o.read_back.text() if o.read_back is not None else "?"
            parts.append(f"{o.key}: {o.result} (read back {shown})")
        else:
            reached = o.reached.state.value if o.reached is not None else "unknown"
            parts.append(f"{o.action}: {o.result} (reached {reached})")
    return "; ".join(parts)


@dataclass(frozen=True, slots=True)
class RunResult:
    text: str
    ok: bool
    failed: bool  # sent, but not as asked (False with ok False: refused, nothing sent)
    audited: bool  # by the guarded path


async def run_request(fleet: AsyncFleet, req: CommandRequest, actor: str) -> RunResult:
    """Run ``req`` as ``actor``; every exception becomes the outcome's text, never silent."""
    try:
        if req.command is not None:
            outcome = await fleet.remote_command(req.device, req.command, actor=actor)
            return RunResult(describe_outcomes([outcome]), outcome.ok, not outcome.ok, True)
        outcomes = await fleet.remote_write(req.device, req.writes, actor=actor)
        ok = all(o.ok for o in outcomes)
        return RunResult(describe_outcomes(outcomes), ok, not ok, True)
    except (
        RemoteNotAllowed, ValidationError, ConfirmationRefused, UnknownPointError, UnsupportedOperationError
    ) as exc:  # fmt: skip
        command_rule = req.command is not None and isinstance(exc, StateRuleError)
        return RunResult(str(exc), False, False, command_rule or isinstance(exc, ConfirmationRefused))
    except GuardedOperationError as exc:  # sent, but not as asked (not reached, read-back mismatch)
        return RunResult(f"{exc} [{describe_outcomes(exc.outcomes)}]", False, True, True)
    except Exception as exc:  # transport errors and anything unforeseen
        return RunResult(f"{type(exc).__name__}: {exc}", False, True, False)
