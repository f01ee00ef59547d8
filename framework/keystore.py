"""Per-deployment credentials: who may join a deployment's bus.

`fw deploy` creates a keystore for every run: a certificate authority of its own and
one certificate per process of the topology, plus `control` (the process of
`fw deploy`: Coordinator, Configurator, console) and `operator` (the `fw status`,
`fw ls`, `fw send`... clients). Every Zenoh link is mutual TLS against that CA, so a
session without one of these certificates cannot open a link to any process of the
deployment: it reads nothing, puts nothing, and no query of its reaches a queryable.
A certificate's common name is its subject; the bus's access rules
(`framework/access.py`) say what each subject may do.

The keystore is a directory only the user can read (0700, files 0600); nothing of it
is ever put on a command line or in an environment. The CA's private key is never
written: once the certificates are issued, nobody can issue another. The default
place is per namespace under `$XDG_RUNTIME_DIR/fw` (else `~/.cache/fw/run`), where the
clients of a deployment find the operator's certificate; `FW_KEYS` overrides the root.
Several hosts (`fw deploy --host`) share one keystore made with `fw keys`.
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import shutil
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from framework.errors import FwError

CONTROL = "control"
"""The subject of the process running `fw deploy` (Coordinator, Configurator)."""
OPERATOR = "operator"
"""The subject of the command-line clients (`fw status`, `fw ls`, `fw send`, ...)."""
VALIDITY = datetime.timedelta(days=30)


class KeystoreError(FwError):
    """A keystore is missing, incomplete or unsafe (readable by other users)."""


@dataclass(frozen=True)
class Keystore:
    """A deployment's credentials on disk (see the module docstring)."""

    root: Path

    @property
    def ca(self) -> Path:
        """The deployment's CA certificate (the only certificate a peer trusts)."""
        return self.root / "ca.pem"

    def certificate(self, subject: str) -> Path:
        """`subject`'s certificate (common name = subject)."""
        return self.root / f"{subject}.pem"

    def private_key(self, subject: str) -> Path:
        """`subject`'s private key."""
        return self.root / f"{subject}.key"

    def subjects(self) -> list[str]:
        """Every subject with a certificate here."""
        return sorted(p.stem for p in self.root.glob("*.key"))

    def check(self, subject: str) -> None:
        """Raise `KeystoreError` unless `subject` can use this keystore safely."""
        if not self.ca.is_file():
            raise KeystoreError(f"no keystore at {self.root} (is the deployment running?)")
        mode = self.root.stat().st_mode & 0o077
        if mode:
            raise KeystoreError(
                f"keystore {self.root} is readable by other users (mode "
                f"{self.root.stat().st_mode & 0o777:o}); it must be 0700"
            )
        if not self.private_key(subject).is_file():
            raise KeystoreError(f"keystore {self.root} has no credentials for {subject!r}")

    def remove(self) -> None:
        """Delete the keystore (the deployment is over)."""
        shutil.rmtree(self.root, ignore_errors=True)


def default_root() -> Path:
    """Where keystores live unless told otherwise (`FW_KEYS`, then the user's runtime
    directory, then `~/.cache/fw/run`)."""
    if os.environ.get("FW_KEYS"):
        return Path(os.environ["FW_KEYS"])
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime and Path(runtime).is_dir():
        return Path(runtime) / "fw"
    return Path.home() / ".cache" / "fw" / "run"


def keystore_for(namespace: str) -> Keystore:
    """The default keystore of the deployment whose bus namespace is `namespace`."""
    return Keystore(default_root() / namespace)


def write_private(path: Path, data: bytes) -> None:
    """Write `data` into a file only the user can read (0600 from its creation)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as out:
        out.write(data)


def private_pem(key: Any) -> bytes:
    """A private key as unencrypted PKCS#8 PEM (the file holding it is 0600)."""
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(
        serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
    )


def alternative_names(hosts: Iterable[str]) -> list[Any]:
    """Subject alternative names for these hosts: IP addresses as such, others as DNS."""
    from cryptography import x509

    names: list[x509.GeneralName] = []
    for host in dict.fromkeys(hosts):
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return names


def create_keystore(
    root: Path, subjects: Iterable[str], hosts: Iterable[str] = ("127.0.0.1",)
) -> Keystore:
    """Issue a fresh CA and a certificate for every subject (plus `control` and
    `operator`) into `root`, replacing what was there. `hosts` are the addresses the
    processes listen on (each certificate names them all: any process may listen)."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    root = Path(root)
    if root.exists():
        shutil.rmtree(root)
    root.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    root.mkdir(mode=0o700)
    os.chmod(root, 0o700)
    now = datetime.datetime.now(datetime.UTC)

    def name(common: str) -> x509.Name:
        return x509.Name(
            [
                x509.NameAttribute(NameOID.ORGANIZATION_NAME, "fw deployment"),
                x509.NameAttribute(NameOID.COMMON_NAME, common),
            ]
        )

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = name(f"fw CA {root.name}")
    ca = (
        x509.CertificateBuilder()
        .subject_name(ca_name)
        .issuer_name(ca_name)
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + VALIDITY)
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=False,
                content_commitment=False,
                key_encipherment=False,
                data_encipherment=False,
                key_agreement=False,
                key_cert_sign=True,
                crl_sign=True,
                encipher_only=False,
                decipher_only=False,
            ),
            critical=True,
        )
        .sign(ca_key, hashes.SHA256())
    )
    write_private(root / "ca.pem", ca.public_bytes(serialization.Encoding.PEM))
    names = alternative_names(["localhost", *hosts])
    for subject in dict.fromkeys([*subjects, CONTROL, OPERATOR]):
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (
            x509.CertificateBuilder()
            .subject_name(name(subject))
            .issuer_name(ca_name)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + VALIDITY)
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(
                x509.ExtendedKeyUsage(
                    [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
                ),
                critical=False,
            )
            .sign(ca_key, hashes.SHA256())
        )
        write_private(root / f"{subject}.pem", cert.public_bytes(serialization.Encoding.PEM))
        write_private(root / f"{subject}.key", private_pem(key))
    return Keystore(root)
