"""The server's application instance certificate: given, or generated on first run in a directory the user names.

A generated certificate names the application URI and the host: its DNS names (host name, fully qualified name,
``localhost``) and the IP addresses given (the endpoint's, ``--cert-ip``), so clients that check the host accept it.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from collections.abc import Iterable
from pathlib import Path

from asyncua.crypto import cert_gen
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding
from cryptography.x509.oid import ExtendedKeyUsageOID

from starterbus.core.errors import ConfigurationError

CERT_NAME = "server_cert.der"
KEY_NAME = "server_key.pem"


def host_names(extra: Iterable[str] = ()) -> list[x509.GeneralName]:
    """DNS names of this host (host name, FQDN, localhost) and ``extra`` (names or IP addresses; 0.0.0.0 skipped)."""
    dns: list[str] = []
    ips: list[ipaddress.IPv4Address | ipaddress.IPv6Address] = []
    for name in (socket.gethostname(), socket.getfqdn(), "localhost", *extra):
        try:
            ip = ipaddress.ip_address(name.strip("[]"))
        except ValueError:
            if name and name not in dns:
                dns.append(name)
            continue
        if not ip.is_unspecified and ip not in ips:
            ips.append(ip)
    return [*(x509.DNSName(n) for n in dns), *(x509.IPAddress(ip) for ip in ips)]


def ensure_certificate(
    directory: str | Path, application_uri: str, host: str | None = None, addresses: Iterable[str] = ()
) -> tuple[Path, Path]:
    """Return (certificate DER, private key PEM) in ``directory``, generating a self-signed pair if missing.

    A generated certificate names ``application_uri``, ``host`` (default: this host's names, see
    :func:`host_names`) and ``addresses``. The key is written with mode 0600, the directory created with 0700. An
    existing pair is used as it is (replace both files to renew); its URI must equal ``application_uri`` or
    clients refuse the server.
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
        names = [x509.DNSName(host)] if host else host_names(addresses)
        certificate = cert_gen.generate_self_signed_app_certificate(
            private_key,
            "starterbus OPC UA server",
            {"organizationName": "starterbus"},
            [x509.UniformResourceIdentifier(application_uri), *names],
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
