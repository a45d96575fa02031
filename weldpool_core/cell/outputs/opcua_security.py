"""The OPC UA server's security (``opcua``): the policy, certificate and trust it applies, and
the self-signed certificate ``weldpool opcua-certificate`` makes for it."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from weldpool_core.errors import InvalidInputError

if TYPE_CHECKING:
    from weldpool_core.cell.outputs.base import Reporter
    from weldpool_core.cell.outputs.opcua import OpcUaOptions

APPLICATION_URI = "urn:weldpool:stream:server"
CERTIFICATE_FILE = "weldpool-opcua-cert.der"
KEY_FILE = "weldpool-opcua-key.pem"


def make_certificate(folder: Path, hostname: str, days: int = 365) -> tuple[Path, Path]:
    """A self-signed certificate and private key for the server (``--opcua-security
    sign-encrypt``): RSA 2048, the server's application URI and ``hostname`` in its subject
    alternative names, as OPC UA clients check them. Clients must be told to trust it.
    Refuses to overwrite files already there."""
    from asyncua.crypto.cert_gen import (
        dump_private_key_as_pem,
        generate_private_key,
        generate_self_signed_app_certificate,
    )
    from cryptography import x509
    from cryptography.hazmat.primitives import serialization
    from cryptography.x509.oid import ExtendedKeyUsageOID

    if not folder.is_dir():
        raise InvalidInputError(f"There is no folder {str(folder)!r}; create it first.")
    certificate, key = folder / CERTIFICATE_FILE, folder / KEY_FILE
    for path in (certificate, key):
        if path.exists():
            raise InvalidInputError(
                f"{str(path)!r} exists already; move it or choose another folder."
            )
    private = generate_private_key()
    names = [x509.UniformResourceIdentifier(APPLICATION_URI), x509.DNSName(hostname)]
    cert = generate_self_signed_app_certificate(
        private,
        "weldpool stream",
        {"organizationName": "weldpool"},
        names,
        [ExtendedKeyUsageOID.SERVER_AUTH],
        days=days,
    )
    descriptor = os.open(key, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)  # never readable
    with os.fdopen(descriptor, "wb") as handle:
        handle.write(dump_private_key_as_pem(private))
    certificate.write_bytes(cert.public_bytes(serialization.Encoding.DER))
    return certificate, key


async def secure(server: Any, options: OpcUaOptions, reporter: Reporter) -> None:
    """Apply ``options``' security policy, certificate and trust to ``server`` (not started)."""
    from asyncua import ua

    if options.security == "none":
        server.set_security_policy([ua.SecurityPolicyType.NoSecurity])
        return
    server.set_security_policy([ua.SecurityPolicyType.Basic256Sha256_SignAndEncrypt])
    await server.load_certificate(str(options.certificate))
    await server.load_private_key(str(options.private_key))
    if options.trust_dir is None:
        reporter.problem(
            "trust",
            "sign-encrypt without --opcua-trust accepts any client certificate within its "
            "dates (encrypted, not authenticated); give a folder of trusted certificates",
        )
    else:
        from asyncua.crypto.truststore import TrustStore
        from asyncua.crypto.validator import CertificateValidator, CertificateValidatorOptions

        store = TrustStore([options.trust_dir], [])
        await store.load()
        checks = CertificateValidatorOptions  # the default checks dates only: trust too
        validator = CertificateValidator(
            checks.TRUSTED_VALIDATION | checks.PEER_CLIENT, trust_store=store
        )
        server.set_certificate_validator(validator)
