"""TLS for a console that other machines can reach.

On this machine only (127.0.0.1, the default) the console is plain HTTP: the login
never leaves the host. Opened beyond it (`--console-host`), the login token and every
command would cross the network, so the console is served over TLS only: with the
certificate and key the hospital gives (`--console-cert`, `--console-key`), or else
with a certificate made for this run, whose SHA-256 fingerprint `fw deploy` prints so
the operator can compare it with what the browser shows before accepting it.
"""

from __future__ import annotations

import contextlib
import datetime
import hashlib
import ipaddress
import socket
import ssl
from pathlib import Path

from framework.errors import FwError
from framework.keystore import VALIDITY, alternative_names, private_pem, write_private


class TlsError(FwError):
    """The console's certificate or key cannot be used."""


def is_loopback(host: str) -> bool:
    """Does `host` keep the console on this machine?"""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def is_wildcard(host: str) -> bool:
    """Does `host` listen on every interface (0.0.0.0, ::)?"""
    try:
        return ipaddress.ip_address(host).is_unspecified
    except ValueError:
        return False


def names_for(host: str) -> list[str]:
    """The names a browser may use to reach a console listening on `host`: the address
    itself, or for a wildcard this machine's names and addresses (and loopback's)."""
    if not is_wildcard(host):
        return [host]
    names = ["127.0.0.1", "localhost", "::1", socket.gethostname(), socket.getfqdn()]
    with contextlib.suppress(OSError):
        for info in socket.getaddrinfo(socket.gethostname(), None):
            names.append(str(info[4][0]))
    return list(dict.fromkeys(n for n in names if n and not is_wildcard(n)))


def self_signed(names: list[str], directory: Path) -> tuple[Path, Path]:
    """A self-signed certificate (and its key) for `names`, valid as long as a keystore,
    written into `directory` (the key readable only by the user); (certificate, key)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    directory.mkdir(parents=True, exist_ok=True, mode=0o700)
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fw operator console"),
            x509.NameAttribute(NameOID.COMMON_NAME, names[0][:64]),
        ]
    )
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + VALIDITY)
        .add_extension(x509.SubjectAlternativeName(alternative_names(names)), critical=False)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .sign(key, hashes.SHA256())
    )
    cert_path, key_path = directory / "console.pem", directory / "console.key"
    write_private(key_path, private_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def server_context(cert: Path, key: Path) -> ssl.SSLContext:
    """A server-side TLS context (TLS 1.2 or later) for this certificate and key."""
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        context.load_cert_chain(cert, key)
    except FileNotFoundError as exc:
        raise TlsError(f"no such file: {exc.filename}") from None
    except (ssl.SSLError, OSError) as exc:
        raise TlsError(
            f"cannot serve TLS with certificate {cert} and key {key}: "
            f"{getattr(exc, 'reason', None) or exc} (PEM files, the key matching the certificate)"
        ) from None
    return context


def fingerprint(cert: Path) -> str:
    """The certificate's SHA-256 fingerprint as browsers show it (AB:CD:...)."""
    try:
        der = ssl.PEM_cert_to_DER_cert(cert.read_text(encoding="ascii"))
    except (OSError, ValueError, UnicodeDecodeError) as exc:
        raise TlsError(f"cannot read the certificate {cert}: {exc}") from None
    return fingerprint_der(der)


def fingerprint_der(der: bytes) -> str:
    """The SHA-256 fingerprint of a DER certificate (as a TLS peer sends it)."""
    return ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())
