"""Client certificates trusted on purpose: the PKI folders ``trusted/`` and ``rejected/`` (UaExpert, open62541,
Kepware convention).

An unknown client certificate is refused (``BadCertificateUntrusted``) and saved as DER to ``rejected/``, named
``<subject CN>_<SHA-1 thumbprint>.der``; an administrator trusts it by moving it to ``trusted/`` (read again at
the next session, no restart) or with ``starterbus opcua-trust --pki DIR NAME``. ``trusted/`` holds DER or PEM
files: a client's own certificate, or a CA certificate whose issued client certificates are then trusted.
A trusted certificate is also checked for its validity time and that its URI is the client's application URI.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from asyncua import ua
from asyncua.common.utils import ServiceError
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives import hashes
from cryptography.hazmat.primitives.serialization import Encoding

from starterbus.core.errors import ConfigurationError

log = logging.getLogger("starterbus.opcua.security")
TRUSTED, REJECTED = "trusted", "rejected"
MAX_REJECTED = 200  # certificates kept in rejected/ at most (a flood of new certificates must not fill the disk)


def thumbprint(cert: x509.Certificate) -> str:
    return cert.fingerprint(hashes.SHA1()).hex().upper()  # the OPC UA thumbprint is SHA-1


def common_name(cert: x509.Certificate) -> str:
    names = cert.subject.get_attributes_for_oid(x509.NameOID.COMMON_NAME)
    return str(names[0].value) if names else ""


def file_name(cert: x509.Certificate) -> str:
    cn = re.sub(r"[^A-Za-z0-9._-]+", "-", common_name(cert)).strip("-.") or "certificate"
    return f"{cn[:64]}_{thumbprint(cert)}.der"


def load_certificate(path: Path) -> x509.Certificate:
    data = path.read_bytes()
    try:
        if data.lstrip().startswith(b"-----BEGIN"):
            return x509.load_pem_x509_certificate(data)
        return x509.load_der_x509_certificate(data)
    except ValueError as exc:
        raise ConfigurationError(f"{path}: not a DER or PEM certificate: {exc}") from exc


@dataclass(frozen=True, slots=True)
class CertificateInfo:
    file: str
    subject: str
    uri: str
    thumbprint: str
    not_after: datetime


def describe(path: Path) -> CertificateInfo:
    cert = load_certificate(path)
    try:
        names = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        uris = names.get_values_for_type(x509.UniformResourceIdentifier)
    except x509.ExtensionNotFound:
        uris = []
    return CertificateInfo(
        path.name, common_name(cert), uris[0] if uris else "", thumbprint(cert), cert.not_valid_after_utc
    )


def certificates(folder: Path) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in (".der", ".pem", ".crt"))


class ClientTrust:
    """asyncua's certificate validator (called at CreateSession) over ``trusted/`` and ``rejected/``."""

    def __init__(self, trusted: Path, rejected: Path) -> None:
        self.trusted = trusted
        self.rejected = rejected
        self._seen: tuple[tuple[str, int, int], ...] | None = None
        self._thumbprints: set[str] = set()
        self._store: TrustStore | None = None  # only when trusted/ holds a CA certificate
        self._checks = CertificateValidator(
            CertificateValidatorOptions.TIME_RANGE
            | CertificateValidatorOptions.URI
            | CertificateValidatorOptions.PEER_CLIENT
        )  # key usage is left to the client's stack: asyncua's check also demands nonRepudiation

    def prepare(self) -> None:
        """Create the folders (mode 0700) before the server starts; a problem is one line."""
        for folder in (self.trusted, self.rejected):
            try:
                folder.mkdir(parents=True, exist_ok=True, mode=0o700)
            except OSError as exc:
                raise ConfigurationError(f"{folder}: cannot create the certificate folder: {exc}") from exc

    async def __call__(self, cert: x509.Certificate, app: ua.ApplicationDescription) -> None:
        await self._reload()
        if not self._is_trusted(cert):
            saved = self._save_rejected(cert)
            log.warning(
                "OPC UA client certificate refused: %r (URI %s, thumbprint %s) is not trusted%s",
                common_name(cert), app.ApplicationUri, thumbprint(cert),
                f"; saved as {saved}: move it to {self.trusted}/ to trust it" if saved else "",
            )  # fmt: skip
            raise ServiceError(ua.StatusCodes.BadCertificateUntrusted)
        await self._checks.validate(cert, app)

    def _is_trusted(self, cert: x509.Certificate) -> bool:
        if thumbprint(cert) in self._thumbprints:
            return True
        return self._store is not None and self._store.validate(cert)

    async def _reload(self) -> None:
        """Read ``trusted/`` again when its files changed (names, sizes or times)."""
        files = certificates(self.trusted)
        seen = tuple((p.name, p.stat().st_mtime_ns, p.stat().st_size) for p in files)
        if seen == self._seen:
            return
        thumbprints, cas = set(), False
        for path in files:
            try:
                cert = load_certificate(path)
            except (OSError, ConfigurationError) as exc:
                log.warning("OPC UA trusted certificate %s ignored: %s", path, exc)
                continue
            thumbprints.add(thumbprint(cert))
            try:
                cas = cas or cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
            except x509.ExtensionNotFound:
                pass
        store = None
        if cas:
            store = TrustStore([self.trusted], [])
            await store.load()
        self._thumbprints, self._store, self._seen = thumbprints, store, seen

    def _save_rejected(self, cert: x509.Certificate) -> Path | None:
        target = self.rejected / file_name(cert)
        if target.exists():
            return target
        if len(certificates(self.rejected)) >= MAX_REJECTED:
            return None
        try:
            self.rejected.mkdir(parents=True, exist_ok=True, mode=0o700)
            target.write_bytes(cert.public_bytes(Encoding.DER))
        except OSError as exc:
            log.warning("cannot save the refused client certificate to %s: %s", target, exc)
            return None
        return target


def trust(pki: Path, name: str) -> Path:
    """Move ``rejected/NAME`` (a file name, or the start of a thumbprint) to ``trusted/``; returns the new path."""
    rejected = certificates(pki / REJECTED)
    matches = [p for p in rejected if p.name == name]
    if not matches and len(name) >= 6:
        matches = [p for p in rejected if describe(p).thumbprint.startswith(name.upper())]
    if len(matches) != 1:
        known = ", ".join(p.name for p in rejected) or "none"
        what = "no" if not matches else "more than one"
        raise ConfigurationError(f"{pki / REJECTED}: {what} rejected certificate {name!r} (rejected: {known})")
    target = pki / TRUSTED / matches[0].name
    try:
        target.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        matches[0].replace(target)
    except OSError as exc:
        raise ConfigurationError(f"cannot move {matches[0]} to {target}: {exc}") from exc
    return target
