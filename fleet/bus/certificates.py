"""TLS material of a secured bus (``fleet keys init --tls``): a private certificate authority,
the router's server certificate and one client certificate per identity (mutual TLS).

Keys are ECDSA P-256; the CA is valid 10 years, the others 825 days. The router's
certificate names the endpoint's host (an IP address or a DNS name, plus ``localhost``); each
client certificate's common name is its identity, which the router's access control also
checks (a session must hold the password *and* the certificate of the same identity). The
CA's private key is not kept: a new identity means a new ``fleet keys init --force``.
Needs the ``cryptography`` package."""

from __future__ import annotations

import datetime
import ipaddress
from dataclasses import dataclass
from pathlib import Path

#: The sub-directory of the key directory that holds the TLS files.
TLS_DIR = "tls"
CA_FILE = "ca.pem"


@dataclass(frozen=True)
class Pem:
    """A certificate and its private key, PEM-encoded."""

    cert: bytes
    key: bytes


def _now() -> datetime.datetime:
    return datetime.datetime.now(datetime.UTC)


def make_certificates(router_host: str, identities: list[str]) -> tuple[bytes, dict[str, Pem]]:
    """``(CA certificate, {"router": ..., identity: ...})``: a fresh CA and the certificates it
    signs (see the module docstring); ``router_host`` is the endpoint's host."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def key_pem(k: ec.EllipticCurvePrivateKey) -> bytes:
        return k.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
        )

    now = _now()
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca = (
        x509.CertificateBuilder()
        .subject_name(name("fleet bus CA"))
        .issuer_name(name("fleet bus CA"))
        .public_key(ca_key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=3650))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(
                digital_signature=True,
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
        )  # fmt: skip
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
        .sign(ca_key, hashes.SHA256())
    )

    def leaf(cn: str, server: bool) -> Pem:
        k = ec.generate_private_key(ec.SECP256R1())
        names: list[x509.GeneralName]
        if server:
            names = [x509.DNSName("localhost")]
            try:
                names.append(x509.IPAddress(ipaddress.ip_address(router_host)))
            except ValueError:
                names.append(x509.DNSName(router_host))
        else:
            names = [x509.DNSName(cn)]
        usage = ExtendedKeyUsageOID.SERVER_AUTH if server else ExtendedKeyUsageOID.CLIENT_AUTH
        cert = (
            x509.CertificateBuilder()
            .subject_name(name(cn))
            .issuer_name(ca.subject)
            .public_key(k.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=825))
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([usage]), critical=False)
            .add_extension(x509.SubjectAlternativeName(names), critical=False)
            .add_extension(
                x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
            )
            .sign(ca_key, hashes.SHA256())
        )
        return Pem(cert.public_bytes(serialization.Encoding.PEM), key_pem(k))

    out = {"router": leaf("router", True)}
    out.update({i: leaf(i, False) for i in identities})
    return ca.public_bytes(serialization.Encoding.PEM), out


def tls_endpoint(endpoint: str) -> str:
    """``tls/127.0.0.1:7447`` for ``tcp/127.0.0.1:7447`` (a ``tls/`` endpoint unchanged);
    ValueError for another protocol."""
    proto, _, rest = endpoint.partition("/")
    if proto not in ("tcp", "tls") or not rest:
        raise ValueError(f"TLS needs a tcp/ or tls/ endpoint, got {endpoint!r}")
    return f"tls/{rest}"


def endpoint_host(endpoint: str) -> str:
    """The host of ``tcp/127.0.0.1:7447`` (``127.0.0.1``; IPv6 brackets removed)."""
    rest = endpoint.partition("/")[2]
    host = rest.rsplit(":", 1)[0] if ":" in rest else rest
    return host.strip("[]")


def tls_paths(directory: Path, identity: str) -> tuple[Path, Path, Path]:
    """``(CA certificate, certificate, private key)`` of ``identity`` (or ``router``) in the
    key directory ``directory``."""
    d = directory / TLS_DIR
    return d / CA_FILE, d / f"{identity}.pem", d / f"{identity}.key"
