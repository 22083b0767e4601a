"""The OPC UA server: a running :class:`~starterbus.aio.AsyncFleet` seen from OPC UA clients.

```python
async with AsyncFleet(load_fleet("fleet.toml")) as fleet:
    async with OpcUaServer(fleet, OpcUaSettings("opc.tcp://0.0.0.0:4840", pki_dir="opcua-pki", users=users)):
        await asyncio.Event().wait()
```

Every poll becomes DataValues with the poll's source timestamp (Bad codes while a device is offline).
Start/Stop/Reset and parameter writes go through ``AsyncFleet.remote_command`` / ``remote_write``: the fleet
file's ``remote`` table, then the guarded path (validated, audited as ``opcua:USER``, read back). A written
variable changes only when the read-back arrives. Refusals come back as status codes; the reason text is in the
device's ``Status.LastOperation`` and in the server log.
"""

from __future__ import annotations

import asyncio
import contextvars
import logging
import socket
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

from asyncua import ua
from asyncua.crypto.permission_rules import User, UserRole
from asyncua.server.address_space import AttributeService
from asyncua.server.internal_session import InternalSession

from starterbus.aio import AsyncFleet
from starterbus.core.errors import ConfigurationError, StarterbusError
from starterbus.core.status import Command
from starterbus.opcua import history
from starterbus.opcua.address_space import DeviceNodes, FleetNodes, PointNode, build_fleet
from starterbus.opcua.alarms import Alarms
from starterbus.opcua.certs import ensure_certificate
from starterbus.opcua.endpoint import listening, parse_endpoint
from starterbus.opcua.logins import LoginGuard, LoginPolicy
from starterbus.opcua.processor import GuardedServer
from starterbus.opcua.refusals import code_name, status_code
from starterbus.opcua.trust import REJECTED, TRUSTED, ClientTrust
from starterbus.opcua.users import Role, RoleRuleset, UserEntry, UserManager
from starterbus.opcua.values import initial_updates, point_updates, sample_updates, timestamp_now

NAMESPACE = "urn:starterbus:fleet"
log = logging.getLogger("starterbus.opcua")

#: the user of the session whose Call request is being served (asyncua does not pass it to method handlers)
_ADMIN = User(role=UserRole.Admin)  # asyncua's default for its own internal writes
_ANONYMOUS = User(role=UserRole.Anonymous)
_CALLER: contextvars.ContextVar[User | None] = contextvars.ContextVar("starterbus_opcua_caller", default=None)

#: the secure endpoints offered, strongest first (policy None only with allow_insecure)
SECURITY_POLICIES: tuple[tuple[str, str, ua.SecurityPolicyType], ...] = tuple(
    (name, mode, getattr(ua.SecurityPolicyType, f"{attr}_{mode}"))
    for name, attr in (
        ("Basic256Sha256", "Basic256Sha256"),
        ("Aes256_Sha256_RsaPss", "Aes256Sha256RsaPss"),
        ("Aes128_Sha256_RsaOaep", "Aes128Sha256RsaOaep"),
    )
    for mode in ("SignAndEncrypt", "Sign")
)


def security_names(allow_insecure: bool) -> list[str]:
    """The endpoints' security as clients see them: ``Basic256Sha256 SignAndEncrypt``, ..., ``None``."""
    return [f"{name} {mode}" for name, mode, _ in SECURITY_POLICIES] + (["None"] if allow_insecure else [])


@dataclass(frozen=True)
class OpcUaSettings:
    """How the server listens and whom it lets in.

    ``pki_dir`` holds the server certificate (generated there on first run unless ``certificate`` and
    ``private_key`` are given; its names: this host's and ``certificate_addresses``), ``trusted/`` (the client
    certificates trusted) and ``rejected/`` (the unknown ones refused, saved there). ``trusted_clients`` names
    another trusted folder; ``trust_any_client`` accepts every client certificate (trials only). Basic256Sha256,
    Aes256_Sha256_RsaPss and Aes128_Sha256_RsaOaep, Sign and SignAndEncrypt, are offered; None only with
    ``allow_insecure``. Anonymous sessions are refused unless ``anonymous`` (then they are read-only). ``history``:
    the SQLite history the recorder writes (``--record``), served by HistoryRead (:mod:`starterbus.opcua.history`).
    """

    endpoint: str = "opc.tcp://0.0.0.0:4840/starterbus"
    pki_dir: Path | str = "opcua-pki"
    users: Mapping[str, UserEntry] = field(default_factory=dict)
    anonymous: bool = False
    allow_insecure: bool = False
    certificate: Path | str | None = None
    private_key: Path | str | None = None
    trusted_clients: Path | str | None = None  # the trusted client certificates; None: PKI_DIR/trusted
    trust_any_client: bool = False  # accept any client certificate (trials only; logged)
    certificate_addresses: tuple[str, ...] = ()  # IP addresses (or names) a generated certificate names too
    application_uri: str = ""  # default urn:starterbus:HOSTNAME:opcua
    locale: str = "en"  # "en": English display names, Chinese descriptions; "zh": the other way round
    server_name: str = "starterbus OPC UA server"
    logins: LoginPolicy = field(default_factory=LoginPolicy)  # throttling and lockout of failed logins
    history: Path | str | None = None  # the recorder's SQLite history (--record): served by HistoryRead

    def check(self) -> None:
        """Refuse settings under which nobody could connect, before anything starts."""
        parse_endpoint(self.endpoint)
        if not self.users and not self.anonymous:
            raise ConfigurationError(
                "no OPC UA users and anonymous access off: nobody could connect (add a users file)"
            )
        if (self.certificate is None) != (self.private_key is None):
            raise ConfigurationError("give both the certificate and its private key, or neither")
        if self.locale not in ("en", "zh"):
            raise ConfigurationError(f"locale {self.locale!r}: use 'en' or 'zh'")

    def uri(self) -> str:
        return self.application_uri or f"urn:starterbus:{socket.gethostname()}:opcua"

    def trusted_folder(self) -> Path:
        return Path(self.trusted_clients) if self.trusted_clients is not None else Path(self.pki_dir) / TRUSTED

    def rejected_folder(self) -> Path:
        return Path(self.pki_dir) / REJECTED


class _Session(InternalSession):
    async def call(self, params: list[ua.CallMethodRequest]) -> list[ua.CallMethodResult]:
        token = _CALLER.set(self.user)
        try:
            results: list[ua.CallMethodResult] = await super().call(params)
            return results
        finally:
            _CALLER.reset(token)


class _GuardedAttributes(AttributeService):
    """Writes to our namespace: enabled parameters go to the guarded path; everything else there is read-only."""

    def __init__(self, base: AttributeService, owner: OpcUaServer) -> None:
        super().__init__(base._aspace)
        self.owner = owner

    async def write(self, params: ua.WriteParameters, user: User = _ADMIN) -> list[ua.StatusCode]:
        if user.role is UserRole.Admin:  # the server's own internal session (clients are never Admin here)
            admin: list[ua.StatusCode] = await super().write(params, user=user)
            return admin
        results: list[ua.StatusCode] = []
        for item in params.NodesToWrite:
            nodes = self.owner.nodes
            if nodes is not None and item.NodeId.NamespaceIndex == nodes.namespace_index:
                target = nodes.parameters.get(item.NodeId)
                if target is None or item.AttributeId != ua.AttributeIds.Value:
                    results.append(ua.StatusCode(ua.StatusCodes.BadNotWritable))
                else:
                    results.append(await self.owner.write_parameter(*target, item.Value, user))
                continue
            single = ua.WriteParameters(NodesToWrite=[item])
            results += await super().write(single, user=user)
        return results


class OpcUaServer:
    """``async with OpcUaServer(fleet, settings) as server:`` serves the fleet until the block ends."""

    def __init__(self, fleet: AsyncFleet, settings: OpcUaSettings) -> None:
        self.fleet = fleet
        self.settings = settings
        self.logins = LoginGuard(settings.users, settings.logins)
        self.users = UserManager(settings.users, anonymous=settings.anonymous, guard=self.logins)
        self.server = GuardedServer(self.logins, user_manager=self.users)
        self.server.iserver.bind_condition_methods = True  # ConditionRefresh replays the retained alarms
        self.alarms: Alarms | None = None
        self.nodes: FleetNodes | None = None
        self._pump: asyncio.Task[None] | None = None
        self.samples_served = 0

    @property
    def endpoint_url(self) -> str:
        """The endpoint URL with the port actually bound (useful with port 0)."""
        bound = self.server.bserver
        url = self.server.endpoint
        if bound is None:
            return str(url.geturl())
        host = url.hostname or "localhost"
        return str(url._replace(netloc=f"{host}:{bound.port}").geturl())

    async def __aenter__(self) -> OpcUaServer:
        await self.start()
        return self

    async def __aexit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        await self.stop()

    async def start(self) -> None:
        settings = self.settings
        settings.check()
        server = self.server
        await server.init()
        server.set_endpoint(settings.endpoint)
        server.set_server_name(settings.server_name)
        server.product_uri = "urn:starterbus"
        server.manufacturer_name = "starterbus"
        server.application_type = ua.ApplicationType.Server
        await server.set_application_uri(settings.uri())
        await self._load_certificate()
        if settings.trust_any_client:
            log.warning("OPC UA: any client certificate is accepted (trust any client): for trials only")
        else:
            trust = ClientTrust(settings.trusted_folder(), settings.rejected_folder())
            trust.prepare()
            server.set_certificate_validator(trust)
        policies = [policy for _, _, policy in SECURITY_POLICIES]
        if settings.allow_insecure:
            policies.append(ua.SecurityPolicyType.NoSecurity)
        server.set_security_policy(policies, permission_ruleset=RoleRuleset(self.users))
        tokens: list[type] = [ua.UserNameIdentityToken]
        if settings.anonymous:
            tokens.append(ua.AnonymousIdentityToken)
        server.set_identity_tokens(tokens)
        iserver = server.iserver
        iserver.attribute_service = _GuardedAttributes(iserver.attribute_service, self)
        setattr(iserver, "create_session", self._create_session)  # noqa: B010  (see _Session)
        idx = await server.register_namespace(NAMESPACE)
        self.nodes = await build_fleet(server, idx, self.fleet.config, self.call_method, locale=settings.locale)
        self.alarms = Alarms(server, idx, lambda: self._operator(_CALLER.get()), settings.locale)
        await self.alarms.build(self.nodes.devices)
        storage = None
        if settings.history is not None:
            storage = await history.enable(server, self.nodes, self.alarms, settings.history, settings.locale)
        await history.install(server, storage).init()  # without a history: every node BadHistoryOperationUnsupported
        now = time.time()
        for device in self.nodes.devices.values():
            await self._apply(initial_updates(device, now))
        with listening(*parse_endpoint(settings.endpoint)):
            await server.start()
        self._pump = self.fleet.supervisor.task("opcua-samples", self._serve_samples)  # fatal if it fails
        log.info("OPC UA server on %s (namespace %s)", self.endpoint_url, NAMESPACE)

    async def stop(self) -> None:
        """Stop serving; a failure of the sample pump (already told to the supervisor) is raised after."""
        failed: BaseException | None = None
        if self._pump is not None:
            self._pump.cancel()
            try:
                await self._pump
            except asyncio.CancelledError:
                pass
            except Exception as exc:
                failed = exc
            self._pump = None
        await self.server.stop()
        if failed is not None:
            raise failed

    def _create_session(self, name: str, user: User = _ANONYMOUS, external: bool = False) -> Any:
        iserver = self.server.iserver
        return _Session(iserver, iserver.aspace, iserver.subscription_service, name, user=user, external=external)

    async def _load_certificate(self) -> None:
        settings = self.settings
        if settings.certificate is not None and settings.private_key is not None:
            cert, key = Path(settings.certificate), Path(settings.private_key)
        else:
            host = parse_endpoint(settings.endpoint)[0]
            cert, key = ensure_certificate(
                settings.pki_dir, settings.uri(), addresses=(host, *settings.certificate_addresses)
            )
        try:
            await self.server.load_certificate(str(cert))
            await self.server.load_private_key(str(key))
        except (OSError, ValueError) as exc:
            raise ConfigurationError(f"cannot load the server certificate {cert} / key {key}: {exc}") from exc

    # -- values -------------------------------------------------------------------------------------------------

    async def _serve_samples(self) -> None:
        assert self.nodes is not None
        async for sample in self.fleet.samples():
            device = self.nodes.devices.get(sample.device)
            if device is None:
                continue
            try:
                await self._apply(sample_updates(device, sample, self.settings.locale))
                if self.alarms is not None:
                    await self.alarms.on_sample(device, sample)
            except Exception:  # one bad sample must not freeze every value at its last Good state
                log.exception("%s: cannot publish a poll", sample.device)
            self.samples_served += 1

    async def _apply(self, updates: list[tuple[ua.NodeId, ua.DataValue]]) -> None:
        for nodeid, value in updates:
            await self.server.write_attribute_value(nodeid, value)

    async def _note(self, device: DeviceNodes, text: str) -> None:
        log.info("%s: %s", device.config.name, text)
        variant = ua.Variant(text, ua.VariantType.String)
        await self.server.write_attribute_value(
            device.status["LastOperation"], ua.DataValue(variant, SourceTimestamp=timestamp_now())
        )

    # -- methods and writes -------------------------------------------------------------------------------------

    def _operator(self, user: User | None) -> str | None:
        """``opcua:NAME`` for an operator, else None."""
        if user is None or self.users.role(user) is not Role.OPERATOR:
            return None
        return f"opcua:{user.name}"

    async def call_method(self, device: DeviceNodes, command: Command) -> Any:
        user = _CALLER.get()
        actor = self._operator(user)
        who = actor or f"opcua:{user.name if user and user.name else 'anonymous'}"
        if actor is None:
            await self._note(device, f"{who} {command.value}: refused: BadUserAccessDenied: not an operator")
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        try:
            outcome = await self.fleet.remote_command(device.config.name, command, actor=actor)
        except StarterbusError as exc:
            code = status_code(exc, write=False)
            await self._note(device, f"{actor} {command.value}: refused: {code_name(code)}: {exc}")
            return ua.StatusCode(code)
        reached = outcome.reached.state.value if outcome.reached is not None else ""
        await self._note(device, f"{actor} {command.value}: {outcome.result}" + (f" ({reached})" if reached else ""))
        return [ua.Variant(reached, ua.VariantType.String)]

    async def write_parameter(
        self, device: DeviceNodes, point_node: PointNode, value: ua.DataValue, user: User
    ) -> ua.StatusCode:
        key = point_node.point.key
        actor = self._operator(user)
        if actor is None:
            return ua.StatusCode(ua.StatusCodes.BadUserAccessDenied)
        number = value.Value.Value if value.Value is not None else None
        if isinstance(number, bool) or not isinstance(number, (int, float)):
            await self._note(device, f"{actor} write {key}: refused: BadTypeMismatch: {number!r} is not a number")
            return ua.StatusCode(ua.StatusCodes.BadTypeMismatch)
        try:
            (outcome,) = await self.fleet.remote_write(device.config.name, {key: number}, actor=actor)
        except StarterbusError as exc:
            code = status_code(exc, write=True)
            await self._note(device, f"{actor} write {key} = {number}: refused: {code_name(code)}: {exc}")
            return ua.StatusCode(code)
        await self._note(device, f"{actor} write {key} = {number}: {outcome.result}")
        back = outcome.read_back
        if back is None:  # sent, but this path cannot read it back: the next poll shows it
            return ua.StatusCode(ua.StatusCodes.GoodCompletesAsynchronously)
        await self._apply(point_updates(point_node, back.raw, back.value, timestamp_now(), self.settings.locale))
        return ua.StatusCode()
