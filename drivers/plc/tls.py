"""Modbus/TCP Security (Modbus.org, "MB-TCP-Security", 2018): Modbus TCP frames inside TLS
1.2 or newer, both ends showing an X.509 certificate issued by an authority the other end
trusts; port 802 by IANA. pymodbus speaks it on both sides (``ModbusTlsServer``,
``AsyncModbusTlsClient``); this module makes their TLS contexts from the settings' files and
tells who a peer's certificate says it is.

A handshake refused (no certificate, one from another authority, an expired one) never reaches
Modbus: asyncio closes the connection before any request, and says nothing of it.
``CountedRefusals`` puts those refusals in the log and the status.
"""

from __future__ import annotations

import logging
import ssl
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SECURE_PORT = 802
refused_log = logging.getLogger("shaftgauge.modbus.refused")


@dataclass(frozen=True)
class TlsFiles:
    """This end's certificate and key, and the authority whose certificates it trusts at
    the other end (PEM files)."""

    certfile: Path
    keyfile: Path
    cafile: Path


def _context(purpose: int, files: TlsFiles, what: str) -> ssl.SSLContext:
    ctx = ssl.SSLContext(purpose)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2  # the specification's floor
    for name, path in (("certfile", files.certfile), ("keyfile", files.keyfile),
                       ("cafile", files.cafile)):
        if not Path(path).is_file():
            raise ValueError(f"{what}.tls.{name} {path}: no such file")
    try:
        ctx.load_cert_chain(files.certfile, files.keyfile)
        ctx.load_verify_locations(cafile=files.cafile)
    except (ssl.SSLError, ValueError) as err:
        raise ValueError(f"{what}.tls: {files.certfile}, {files.keyfile} and {files.cafile} "
                         f"do not load as certificate, key and authority: {err}") from None
    ctx.verify_mode = ssl.CERT_REQUIRED
    return ctx


def server_context(files: TlsFiles, refusals: CountedRefusals | None = None
                   ) -> ssl.SSLContext:
    """The gauge's server: its certificate, and clients' certificates required, from
    ``cafile``'s authority. ValueError names a file that is missing or does not load."""
    ctx = _context(ssl.PROTOCOL_TLS_SERVER, files, "modbus")
    if refusals is not None:
        ctx.sslobject_class = refusals.sslobject_class()
    return ctx


def client_context(files: TlsFiles) -> ssl.SSLContext:
    """The gauge as a client of the CNC: the CNC's certificate must come from ``cafile``'s
    authority and name the address or host it is reached at; the gauge shows its own."""
    return _context(ssl.PROTOCOL_TLS_CLIENT, files, "plc")


def peer_name(transport: Any) -> str:
    """The common name in a TLS peer's certificate ("" over plain TCP)."""
    cert = transport.get_extra_info("peercert") if transport is not None else None
    for rdn in (cert or {}).get("subject", ()):
        for key, value in rdn:
            if key == "commonName":
                return str(value)
    return ""


# OpenSSL's reasons for the refusals a gauge sees, in the words of a plant network
_REASONS = {
    "CERTIFICATE_VERIFY_FAILED": "its certificate is not from the authority in modbus.tls.cafile"
                                 " (or expired)",
    "TLSV1_ALERT_UNKNOWN_CA": "it does not trust the gauge's certificate",
    "PEER_DID_NOT_RETURN_A_CERTIFICATE": "it showed no certificate",
    "WRONG_VERSION_NUMBER": "it does not speak TLS (plain Modbus TCP on the secure port?)",
    "HTTP_REQUEST": "it does not speak TLS",
    "UNSUPPORTED_PROTOCOL": "its TLS is older than 1.2",
}


class CountedRefusals:
    """Handshakes the server refused: counted, the last reason kept, logged (rate-limited
    with the other refusals). asyncio gives no hook for a failed handshake, so the TLS
    objects of the server's context report their own."""

    def __init__(self) -> None:
        self.count = 0
        self.last = ""
        self.reasons: dict[str, int] = {}

    def refused(self, reason: str) -> None:
        """Count one refusal (``reason``: OpenSSL's, such as ``CERTIFICATE_VERIFY_FAILED``)."""
        self.count += 1
        self.reasons[reason] = self.reasons.get(reason, 0) + 1
        self.last = f"a TLS client refused: {_REASONS.get(reason, 'handshake failed')} " \
            f"({reason})"
        refused_log.warning("modbus %s", self.last)

    def sslobject_class(self) -> type[ssl.SSLObject]:
        """An ``SSLObject`` that tells this counter when its handshake fails."""
        counter = self

        class Counted(ssl.SSLObject):
            def do_handshake(self) -> None:
                try:
                    super().do_handshake()
                except (ssl.SSLWantReadError, ssl.SSLWantWriteError):
                    raise  # not done yet: more bytes to come
                except ssl.SSLError as err:
                    counter.refused(err.reason or str(err))
                    raise

        return Counted
