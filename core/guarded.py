"""The one guarded path for every write and command, whoever asks (CLI, fleet queue, broker, OPC UA, restore).

validate -> (state rule) -> confirm -> send -> read back -> audit the outcome -> report.

Nothing is sent before every value of a request is valid, every uncertain code is acknowledged and, for a
parameter the profile locks while the motor runs, the device is known to be stopped. The audit log records
what actually happened (``ok``, ``mismatch``, ``not reached``, ``error: ...``), never the intent. A command
reports the state the device reached, read back from it; a write reports the value read back.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from starterbus.core.audit import AuditLog
from starterbus.core.command_rules import check_command, reached
from starterbus.core.device_access import DeviceAccess
from starterbus.core.errors import StarterbusError, StateRuleError, ValidationError
from starterbus.core.model import PointDef, Value
from starterbus.core.status import Command, MotorState, Status
from starterbus.core.transport_template import Capability


class ConfirmationRefused(StarterbusError):
    """A write or command that moves a motor or changes a parameter was not confirmed; nothing was sent."""


class UncertainValueError(ValidationError):
    """A value whose raw code or scale the manual does not print, written without an acknowledgement."""


class GuardedOperationError(StarterbusError):
    """A write or command that was sent but did not end as asked; ``outcomes`` tells what happened to each."""

    def __init__(self, message: str, outcomes: Sequence[Outcome]) -> None:
        super().__init__(message)
        self.outcomes = list(outcomes)


class ReadBackMismatch(GuardedOperationError):
    """A written parameter reads back with another value."""


class CommandNotReached(GuardedOperationError):
    """A command was sent but the device did not reach the state it asks for within the time allowed."""


@dataclass(frozen=True, slots=True)
class PlannedWrite:
    """One validated write: the point, the raw code that will go on the wire, and why it may be uncertain."""

    point: PointDef
    raw: int
    uncertainty: str | None = None

    @property
    def value(self) -> Value:
        return Value.from_raw(self.point, self.raw)

    def text(self) -> str:
        return f"{self.point.key} = {self.value.text()} (raw {self.raw})"


@dataclass(frozen=True, slots=True)
class Proposal:
    """What a confirmation hook is asked to approve: the device, the action, the raw codes and the frames."""

    device: str
    action: str  # "write" or a command name
    writes: tuple[PlannedWrite, ...] = ()
    command: Command | None = None
    frames: tuple[str, ...] = ()

    def question(self) -> str:
        if self.command is not None:
            return f"{self.command.value} {self.device}?"
        return f"write {', '.join(w.text() for w in self.writes)} to {self.device}?"


Confirm = Callable[[Proposal], bool]


def always(_: Proposal) -> bool:
    """The confirmation of a program that calls the API: the call itself is the intent."""
    return True


@dataclass(slots=True)
class Outcome:
    """What happened to one write or one command; ``result`` is ``ok`` only if it was verified."""

    action: str
    device: str
    result: str = "not sent"
    error: str | None = None
    key: str | None = None
    address: str | None = None
    old: Value | None = None
    new: Value | None = None
    read_back: Value | None = None
    before: Status | None = None
    reached: Status | None = None
    overridden: str | None = None  # what a forced command went against (see core/command_checks.py)
    audit: dict[str, object] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.result == "ok"

    def as_json(self) -> dict[str, object]:
        out: dict[str, object] = {"action": self.action, "device": self.device, "result": self.result}
        if self.key is not None:
            out |= {
                "key": self.key,
                "address": self.address,
                "old": self.old.text() if self.old else None,
                "new": self.new.text() if self.new else None,
                "raw": self.new.raw if self.new else None,
                "read_back": self.read_back.text() if self.read_back else None,
            }
        if self.before is not None or self.reached is not None:
            out["before"] = self.before.state.value if self.before else None
            out["reached"] = self.reached.state.value if self.reached else None
            out["status"] = self.reached.as_json() if self.reached else None
        if self.overridden is not None:
            out["overridden"] = self.overridden
        out["error"] = self.error
        return out


_IDLE = frozenset({MotorState.READY, MotorState.STOPPED})


class Guard:
    """The guarded path of one :class:`~starterbus.core.device.Device` (``device.guard``)."""

    def __init__(
        self,
        device: DeviceAccess,
        *,
        audit: AuditLog | None = None,
        actor: str | None = None,
        confirm: Confirm = always,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        status_max_age: float = 0.5,
        command_timeout: float = 5.0,
        status_interval: float = 0.05,
    ) -> None:
        self.device = device
        self.audit = audit if audit is not None else AuditLog()
        self.actor = actor
        self.confirm = confirm
        self.clock = clock
        self.sleep = sleep
        self.status_max_age = status_max_age
        self.command_timeout = command_timeout
        self.status_interval = status_interval
        self._status: tuple[float, Status] | None = None
        #: the outcomes of the last write or command, also when it raised
        self.last_outcomes: list[Outcome] = []

    # -- state ----------------------------------------------------------------------------------------------

    def note_status(self, status: Status) -> None:
        """Remember a status just read (the poller feeds every poll here), so a state rule need not re-read."""
        self._status = (self.clock(), status)

    def fresh_status(self) -> Status:
        """The last status if younger than ``status_max_age``, else read now."""
        if self._status is not None and self.clock() - self._status[0] <= self.status_max_age:
            return self._status[1]
        return self.device.status()

    # -- writes ---------------------------------------------------------------------------------------------

    def plan_writes(
        self,
        values: Mapping[str, float | int | str] | Sequence[tuple[str | PointDef, float | int | str]],
        *,
        accept_uncertain: bool = False,
    ) -> list[PlannedWrite]:
        """Validate every value (range, enum, access, capability, certainty, state); sends nothing but a status read."""
        items = list(values.items()) if isinstance(values, Mapping) else list(values)
        planned = []
        for key, value in items:
            point, raw = self.device.validate_write(key, value)
            planned.append(PlannedWrite(point, raw, point.uncertainty(raw)))
        uncertain = [p.uncertainty for p in planned if p.uncertainty]
        if uncertain and not accept_uncertain:
            raise UncertainValueError(
                "; ".join(u for u in uncertain if u) + " (acknowledge with accept_uncertain=True / --accept-uncertain)"
            )
        self._check_state_rules(planned)
        return planned

    def _check_state_rules(self, planned: Sequence[PlannedWrite]) -> None:
        locked = [p.point.key for p in planned if p.point.key in self.device.profile.control.locked_while_running]
        if not locked:
            return
        what = ", ".join(locked)
        if Capability.STATUS not in self.device.capabilities:
            raise StateRuleError(
                f"{what}: may only be changed while the motor is stopped, and {self.device.transport.name} "
                "cannot read the status to prove it; nothing sent"
            )
        state = self.fresh_status().state
        if state not in _IDLE:
            raise StateRuleError(
                f"{what}: {self.device.profile.display_name} does not accept changes while the motor is "
                f"{state.value} (the profile locks {'it' if len(locked) == 1 else 'them'} while running); "
                "stop the motor first; nothing sent"
            )

    def write(
        self,
        values: Mapping[str, float | int | str] | Sequence[tuple[str | PointDef, float | int | str]],
        *,
        accept_uncertain: bool = False,
        actor: str | None = None,
    ) -> list[Outcome]:
        """Validate all, confirm, then write in order with a read-back each; stop at the first failure.

        Returns the outcomes (all ``ok``). A write the device refused or that got no answer re-raises its typed
        cause (``RemoteDeviceError``, ``TimeoutError``, ...); a read-back with another value raises
        :class:`ReadBackMismatch`; not confirmed raises :class:`ConfirmationRefused`. Either way every outcome
        is audited and kept in :attr:`last_outcomes`.
        """
        actor = actor or self.actor
        planned = self.plan_writes(values, accept_uncertain=accept_uncertain)
        frames = self._frames(lambda: [f for p in planned for f in self.device.transport.preview_write(p.point, p.raw)])
        proposal = Proposal(self.device.describe(), "write", tuple(planned), frames=frames)
        self._confirm(proposal, actor)
        can_read = Capability.READ_PARAMETERS in self.device.capabilities
        outcomes: list[Outcome] = []
        self.last_outcomes = outcomes
        failure: StarterbusError | None = None
        for index, plan in enumerate(planned):
            outcome = Outcome(
                "write", self.device.describe(), key=plan.point.key, address=plan.point.address, new=plan.value
            )
            outcomes.append(outcome)
            try:
                outcome.old = self.device.read_value(plan.point) if can_read else None
                self.device.send_write(plan.point, plan.raw)
                outcome.result = "sent, not verified (this path cannot read parameters)"
                if can_read:
                    outcome.read_back = self.device.read_value(plan.point)
                    outcome.result = "ok" if outcome.read_back.raw == plan.raw else "mismatch"
            except StarterbusError as exc:
                outcome.result, outcome.error, failure = "failed", str(exc), exc
            self._record(outcome, actor, uncertainty=plan.uncertainty)
            if outcome.result == "mismatch":
                back = outcome.read_back.text() if outcome.read_back else "?"
                self._skip(planned[index + 1 :], outcomes)
                raise ReadBackMismatch(
                    f"{plan.point.key}: wrote {plan.value.text()} but read back {back} from {self.device.describe()}",
                    outcomes,
                )
            if failure is not None:
                self._skip(planned[index + 1 :], outcomes)
                raise failure  # the typed cause (RemoteDeviceError, TimeoutError, ...); outcomes in last_outcomes
        return outcomes

    def _skip(self, rest: Sequence[PlannedWrite], outcomes: list[Outcome]) -> None:
        for plan in rest:
            outcomes.append(
                Outcome(
                    "write",
                    self.device.describe(),
                    "not sent (an earlier write failed)",
                    key=plan.point.key,
                    address=plan.point.address,
                    new=plan.value,
                )
            )

    # -- commands -------------------------------------------------------------------------------------------

    def command(
        self, command: Command, *, timeout: float | None = None, actor: str | None = None, force: bool = False
    ) -> Outcome:
        """Check who controls the starter and its state, confirm, send, then read the status until the command's
        state is reached (or ``timeout`` passes).

        Returns the outcome (``ok``, with ``reached``); raises :class:`CommandNotReached` (with the outcome)
        when the state was not reached or the device tripped, :class:`ConfirmationRefused` when not confirmed,
        :class:`~starterbus.core.errors.ControlSourceError` when the starter is controlled from elsewhere
        (unless ``force``) and :class:`StateRuleError` for a start on a faulted starter; nothing sent then.
        """
        self.device.check_command(command)
        self.last_outcomes = []
        actor = actor or self.actor
        can_verify = Capability.STATUS in self.device.capabilities
        status = self.fresh_status() if can_verify else None
        try:
            overridden = check_command(self.device, command, status, force=force)
        except StateRuleError as exc:  # refused before anything was sent: audited as such
            ident = self._identity(actor)
            self.audit.append(**ident, action="command", command=command.value, result=f"refused: {exc}")
            raise
        frames = self._frames(lambda: self.device.transport.preview_command(command))
        self._confirm(Proposal(self.device.describe(), command.value, command=command, frames=frames), actor)
        outcome = Outcome(command.value, self.device.describe(), overridden=overridden)
        self.last_outcomes = [outcome]
        failure: StarterbusError | None = None
        try:
            outcome.before = self.device.status() if can_verify else None
            again = check_command(self.device, command, outcome.before, force=force, read_source=False)
            outcome.overridden = outcome.overridden or again  # the state may have changed while confirming
            self.device.send_command(command)
            outcome.result = "sent, not verified (this path cannot read the status)"
            if can_verify:
                self._await(command, outcome, self.command_timeout if timeout is None else timeout)
        except StarterbusError as exc:
            outcome.result, outcome.error, failure = "failed", str(exc), exc
            if isinstance(exc, StateRuleError):
                outcome.result = "refused"
        self._record(outcome, actor)
        if failure is not None:
            raise failure
        if outcome.result != "ok" and can_verify:
            raise CommandNotReached(f"{command.value}: {outcome.error}", [outcome])
        return outcome

    def _await(self, command: Command, outcome: Outcome, timeout: float) -> None:
        deadline = self.clock() + timeout
        while True:
            status = self.device.status()
            outcome.reached = status
            verdict = reached(command, status)
            if verdict is None:
                outcome.result = "sent, not verified (this path does not report it)"
                return
            if verdict:
                outcome.result = "ok"
                return
            if command is Command.START and status.fault:
                outcome.result = "not reached"
                outcome.error = f"the device tripped: fault {status.fault_code}: {status.fault_text}"
                return
            if self.clock() >= deadline:
                outcome.result = "not reached"
                outcome.error = (
                    f"{self.device.describe()} is still {status.state.value} {timeout:g} s after the command"
                    + (f" (fault {status.fault_code}: {status.fault_text})" if status.fault else "")
                )
                return
            self.sleep(self.status_interval)

    # -- shared steps ---------------------------------------------------------------------------------------

    def _frames(self, preview: Callable[[], list[str]]) -> tuple[str, ...]:
        try:
            return tuple(preview())
        except StarterbusError:  # a transport without previews: the confirmation shows the raw codes alone
            return ()

    def _confirm(self, proposal: Proposal, actor: str | None) -> None:
        if self.confirm(proposal):
            return
        self.audit.append(
            **self._identity(actor), action=proposal.action, what=proposal.question(), result="not confirmed"
        )
        raise ConfirmationRefused(f"{proposal.question().rstrip('?')}: not confirmed; nothing sent")

    def _identity(self, actor: str | None) -> dict[str, object]:
        ident: dict[str, object] = {"device": self.device.transport.url.text, "model": self.device.profile.name}
        if actor:
            ident["actor"] = actor
        return ident

    def _record(self, outcome: Outcome, actor: str | None, uncertainty: str | None = None) -> None:
        record = self._identity(actor)
        if outcome.key is not None:
            record |= {
                "action": "write",
                "key": outcome.key,
                "address": outcome.address,
                "old": outcome.old.text() if outcome.old else None,
                "new": outcome.new.text() if outcome.new else None,
                "raw": outcome.new.raw if outcome.new else None,
                "read_back": outcome.read_back.text() if outcome.read_back else None,
            }
            if uncertainty:
                record["acknowledged"] = uncertainty
        else:
            record |= {
                "action": "command",
                "command": outcome.action,
                "before": outcome.before.state.value if outcome.before else None,
                "reached": outcome.reached.state.value if outcome.reached else None,
            }
            if outcome.overridden is not None:
                record["overridden"] = outcome.overridden
        record["result"] = outcome.result if outcome.error is None else f"{outcome.result}: {outcome.error}"
        outcome.audit = self.audit.append(**record)
