"""Where the server reaches into asyncua (2.1.x, pinned ``>=2.1,<2.2`` in pyproject): the login precheck.

asyncua 2.1's ``UaProcessor._process_message`` serves ActivateSession without an await: it calls
``InternalSession.activate_session``, which calls ``InternalServer.decrypt_user_token`` and then the user manager's
synchronous ``get_user``, so a PBKDF2 there would stall the event loop. Relied upon, and exercised by
tests/opcua/test_logins.py (which fails if a login is verified on the loop):

- ``Server.start`` builds its ``BinaryServer`` inline; :class:`GuardedServer` repeats those few lines with
  :class:`_BinaryServer`, whose protocol (``OPCUAProtocol.connection_made``) gets a :class:`LoginProcessor`;
- ``UaProcessor.process_message(seqhdr, body)`` is awaited per request with the body as a ``Buffer`` (``copy()``
  peeks without consuming), ``self.session`` / ``iserver.lookup_external_session(auth_token)`` find the session,
  ``self.name`` is the peer address;
- ``InternalServer.decrypt_user_token(isession, token)`` returns (user name, password); it is replaced on the
  instance so that the synchronous path reuses the worker's result instead of decrypting again on the loop.
"""

from __future__ import annotations

import socket
from typing import Any

from asyncua import Server, ua
from asyncua.crypto import uacrypto
from asyncua.server.binary_server_asyncio import BinaryServer, OPCUAProtocol
from asyncua.server.internal_server import InternalServer
from asyncua.server.uaprocessor import UaProcessor
from asyncua.ua.ua_binary import nodeid_from_binary, struct_from_binary

from starterbus.opcua.logins import PRECHECK, LoginGuard, Precheck

_ACTIVATE = ua.NodeId(ua.ObjectIds.ActivateSessionRequest_Encoding_DefaultBinary)


class LoginProcessor(UaProcessor):
    """asyncua's processor, with a user-name token of ActivateSession checked in the worker before it runs."""

    def __init__(self, iserver: InternalServer, transport: Any, limits: Any, guard: LoginGuard) -> None:
        super().__init__(iserver, transport, limits)
        self.guard = guard

    async def process_message(self, seqhdr: Any, body: Any) -> Any:
        check = await self._precheck(body)
        if check is None:
            return await super().process_message(seqhdr, body)
        await self.guard.tarpit(check)
        token = PRECHECK.set(check)
        try:
            return await super().process_message(seqhdr, body)
        finally:
            PRECHECK.reset(token)

    async def _precheck(self, body: Any) -> Precheck | None:
        try:
            peek = body.copy()
            if nodeid_from_binary(peek) != _ACTIVATE:
                return None
            header = struct_from_binary(ua.RequestHeader, peek)
            params = struct_from_binary(ua.ActivateSessionParameters, peek)
        except Exception:  # asyncua parses it again and answers a malformed request itself
            return None
        token = params.UserIdentityToken
        if not isinstance(token, ua.UserNameIdentityToken) or token.UserName is None:
            return None  # anonymous or certificate: no password to check
        iserver = self.iserver
        session = self.session or iserver.lookup_external_session(header.AuthenticationToken)
        if session is None:
            return None  # asyncua refuses it: BadSessionIdInvalid
        address = str(self.name[0]) if isinstance(self.name, tuple) else str(self.name)

        def decrypt() -> tuple[str, str]:
            name, password = InternalServer.decrypt_user_token(iserver, session, token)
            return str(name), str(password)

        try:
            return await self.guard.precheck(address, str(token.UserName), decrypt)
        except Exception:  # a token that cannot be decrypted: asyncua fails it the same way (BadIdentityTokenInvalid)
            return None


class _Protocol(OPCUAProtocol):
    guard: LoginGuard
    processor: UaProcessor | None

    def connection_made(self, transport: Any) -> None:
        super().connection_made(transport)
        if self.processor is not None:  # accepted: replace asyncua's processor (it holds no state yet)
            processor = LoginProcessor(self.iserver, self.transport, self.limits, self.guard)
            processor.set_policies(self.policies)
            self.processor = processor


class _BinaryServer(BinaryServer):
    guard: LoginGuard

    def _make_protocol(self) -> OPCUAProtocol:
        protocol = _Protocol(
            iserver=self.iserver,
            policies=self._policies,
            clients=self.clients,
            closing_tasks=self.closing_tasks,
            limits=self.limits,
        )
        protocol.guard = self.guard
        return protocol


class GuardedServer(Server):
    """asyncua's Server whose connections check passwords through ``login_guard`` (see the module's notes)."""

    bserver: BinaryServer | None

    def __init__(self, login_guard: LoginGuard, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.login_guard = login_guard
        iserver = self.iserver

        def decrypt_user_token(isession: Any, token: ua.UserNameIdentityToken) -> tuple[str, str]:
            check = PRECHECK.get()
            if check is not None and check.username == token.UserName:
                return check.username, check.password or ""  # decided already (refused unchecked: no password)
            name, password = InternalServer.decrypt_user_token(iserver, isession, token)
            return str(name), str(password)

        setattr(iserver, "decrypt_user_token", decrypt_user_token)  # noqa: B010

    async def start(self) -> None:
        # asyncua 2.1's Server.start, with _BinaryServer in place of BinaryServer
        if self.iserver.certificate is not None:
            uacrypto.check_certificate(self.iserver.certificate, self._application_uri, socket.gethostname())
        await self._setup_server_nodes()
        await self.iserver.start()
        try:
            host, port = self._get_bind_socket_info()
            bserver = _BinaryServer(self.iserver, host, port, self.limits)
            bserver.guard = self.login_guard
            self.bserver = bserver
            bserver.set_policies(self._policies)
            await bserver.start()
        except Exception:
            await self.iserver.stop()
            raise

    async def stop(self) -> None:
        try:
            await super().stop()
        finally:
            self.login_guard.close()
