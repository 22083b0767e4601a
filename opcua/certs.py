"""The server's application instance certificate: given, or generated on first run in a directory the user names."""

from __future__ import annotations

import os
import socket
from pathlib import Path

from asyncua.crypto import cert_gen
from asyncua.crypto.truststore import TrustStore
from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID

from starterbus.core.errors import ConfigurationError

CERT_NAME = "server_cert.der"
KEY_NAME = "server_key.pem"


def ensure_certificate(directory: str | Path, application_uri: str, host: str | None = None) -> tuple[Path, Path]:
    """Return (certificate DER, private key PEM) in ``directory``, generating a self-signed pair if missing.

    The key is written with mode 0600, the directory created with 0700. An existing pair is used as it is
    (replace both files to renew); its URI must equal ``application_uri`` or clients refuse the server.
    """
    folder = Path(directory)
    cert, key = folder / CERT_NAME, folder / KEY_NAME
    if cert.is_file() and key.is_file():
        check_uri(cert, application_uri)
        return cert, key
    if cert.exists() != key.exists():
        present = cert if cert.exists() else key
        raise ConfigurationError(f"{present} exists without its pair; remove it or add the other file")
    try:
        folder.mkdir(parents=True, exist_ok=True, mode=0o700)
        private_key = cert_gen.generate_private_key()
        host = host or socket.gethostname()
        certificate = cert_gen.generate_self_signed_app_certificate(
            private_key,
            "starterbus OPC UA server",
            {"organizationName": "starterbus"},
            [x509.UniformResourceIdentifier(application_uri), x509.DNSName(host)],
            extended=[ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH],
            days=3650,
        )
        fd = os.open(key, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(cert_gen.dump_private_key_as_pem(private_key))
        cert.write_bytes(certificate.public_bytes(Encoding.DER))
    except OSError as exc:
        raise ConfigurationError(f"{folder}: cannot store the server certificate: {exc}") from exc
    return cert, key


def check_uri(cert: Path, application_uri: str) -> None:
    try:
        certificate = x509.load_der_x509_certificate(cert.read_bytes())
    except (OSError, ValueError) as exc:
        raise ConfigurationError(f"{cert}: not a DER certificate: {exc}") from exc
    try:
        names = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        uris = names.get_values_for_type(x509.UniformResourceIdentifier)
    except x509.ExtensionNotFound:
        uris = []
    if application_uri not in uris:
        raise ConfigurationError(
            f"{cert}: its subject alternative name URI {uris or '(none)'} is not the server's application URI "
            f"{application_uri!r}; clients would refuse it (pass the certificate's URI or let one be generated)"
        )


async def client_validator(trusted: Path) -> CertificateValidator:
    """Accept only client certificates found in ``trusted`` (checked for validity time and application URI).

    asyncua's KEY_USAGE check also demands nonRepudiation, which common clients' certificates lack, so key usage
    is left to the client's own stack.
    """
    if not trusted.is_dir():
        raise ConfigurationError(f"{trusted}: no such directory of trusted client certificates")
    store = TrustStore([trusted], [])
    await store.load()
    options = (
        CertificateValidatorOptions.TIME_RANGE
        | CertificateValidatorOptions.URI
        | CertificateValidatorOptions.TRUSTED
        | CertificateValidatorOptions.PEER_CLIENT
    )
    return CertificateValidator(options, store)
