"""HTTPS for the API and dashboard: which certificate, a self-signed one made on first start
when asked, and its fingerprint (what the operator compares with what the browser shows
before trusting it).

A certificate from the plant's own authority is the better choice: browsers then trust it
without a warning. The self-signed one is for a gauge without one: the browser warns once,
and the fingerprint printed at every start tells the operator that the certificate it shows
is the gauge's own.
"""

from __future__ import annotations

import datetime as dt
import hashlib
import ipaddress
import logging
import os
import socket
import ssl
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from service.config import ApiSettings

log = logging.getLogger("shaftgauge.https")
SELF_SIGNED_DAYS = 3650  # a gauge runs for years; the fingerprint, not the date, is checked


@dataclass(frozen=True)
class HttpsFiles:
    """The certificate and key the API serves, and the certificate's SHA-256 fingerprint."""

    certfile: Path
    keyfile: Path
    sha256: str


def fingerprint_sha256(certfile: Path) -> str:
    """The SHA-256 fingerprint of a PEM certificate's first block, as browsers show it
    (``AB:12:...``)."""
    cert = x509.load_pem_x509_certificate(certfile.read_bytes())
    return ":".join(f"{b:02X}" for b in hashlib.sha256(
        cert.public_bytes(serialization.Encoding.DER)).digest())


def names_of_this_host(api: ApiSettings) -> list[str]:
    """What a browser may call the gauge: localhost, its name, loopback, the address it
    listens on, the trusted host names."""
    names = ["localhost", socket.gethostname(), "127.0.0.1", "::1", *api.trusted_hosts]
    if api.host not in ("0.0.0.0", "::", ""):
        names.append(api.host)
    return list(dict.fromkeys(n for n in names if n))


def make_self_signed(certfile: Path, keyfile: Path, names: list[str]) -> None:
    """Write a self-signed certificate for ``names`` (host names and addresses) and its key
    (P-256; the key readable by its owner only, written before the certificate)."""
    key = ec.generate_private_key(ec.SECP256R1())
    alt: list[x509.GeneralName] = []
    for name in names:
        try:
            alt.append(x509.IPAddress(ipaddress.ip_address(name)))
        except ValueError:
            alt.append(x509.DNSName(name))
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"shaftgauge {names[0]}"),
                         x509.NameAttribute(NameOID.ORGANIZATION_NAME, "shaftgauge")])
    now = dt.datetime.now(dt.UTC)
    cert = (x509.CertificateBuilder().subject_name(subject).issuer_name(subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(now - dt.timedelta(minutes=5))
            .not_valid_after(now + dt.timedelta(days=SELF_SIGNED_DAYS))
            .add_extension(x509.SubjectAlternativeName(alt), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([x509.ExtendedKeyUsageOID.SERVER_AUTH]),
                           critical=False)
            .sign(key, hashes.SHA256()))
    keyfile.parent.mkdir(parents=True, exist_ok=True)
    certfile.parent.mkdir(parents=True, exist_ok=True)
    pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                            serialization.NoEncryption())
    fd = os.open(keyfile, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    os.chmod(keyfile, 0o600)  # an existing file keeps its mode through O_CREAT
    certfile.write_bytes(cert.public_bytes(serialization.Encoding.PEM))


def https_files(api: ApiSettings, data_dir: Path) -> HttpsFiles | None:
    """The files to serve HTTPS with, made when ``tls_self_signed`` asks; None for plain HTTP.

    Raises
    ------
    ValueError
        A certificate or key that is missing (and not to be made) or does not load; the
        message names the file. The gauge then does not start: it never falls back to plain
        HTTP when HTTPS was asked for.
    """
    if api.tls_certfile is None and not api.tls_self_signed:
        return None
    cert = api.tls_certfile or data_dir / "https" / "certificate.pem"
    key = api.tls_keyfile or data_dir / "https" / "key.pem"
    if api.tls_self_signed and not cert.exists() and not key.exists():
        make_self_signed(cert, key, names_of_this_host(api))
        log.warning("made a self-signed HTTPS certificate %s (its key %s)", cert, key)
    for what, path in (("api.tls_certfile", cert), ("api.tls_keyfile", key)):
        if not path.is_file():
            raise ValueError(f"{what} {path}: no such file (set api.tls_self_signed = true "
                             "to have one made)")
    try:
        ssl.create_default_context(ssl.Purpose.CLIENT_AUTH).load_cert_chain(cert, key)
        sha256 = fingerprint_sha256(cert)
    except (ssl.SSLError, ValueError) as err:
        raise ValueError(f"api.tls_certfile {cert} with api.tls_keyfile {key} do not load: "
                         f"{err}") from None
    return HttpsFiles(cert, key, sha256)
