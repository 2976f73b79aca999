"""HTTPS files: a self-signed certificate made once and kept, its fingerprint, and every
problem a clean message naming the file (the gauge never falls back to plain HTTP)."""

from __future__ import annotations

import ipaddress

import pytest
from cryptography import x509
from pydantic import ValidationError

from service.config import ApiSettings
from service.https import fingerprint_sha256, https_files


def test_plain_http_unless_asked(tmp_path) -> None:
    assert https_files(ApiSettings(), tmp_path) is None


def test_a_self_signed_certificate_is_made_once_for_the_gauges_names(tmp_path) -> None:
    api = ApiSettings(tls_self_signed=True, trusted_hosts=["gauge-3.plant.example"])
    first = https_files(api, tmp_path)
    assert first is not None and first.keyfile.stat().st_mode & 0o777 == 0o600
    again = https_files(api, tmp_path)  # a restart keeps it: the operator checked it once
    assert again == first and first.sha256 == fingerprint_sha256(first.certfile)
    assert len(first.sha256.split(":")) == 32
    cert = x509.load_pem_x509_certificate(first.certfile.read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert {"localhost", "gauge-3.plant.example"} <= set(san.get_values_for_type(x509.DNSName))
    assert ipaddress.ip_address("127.0.0.1") in san.get_values_for_type(x509.IPAddress)


def test_a_missing_or_broken_certificate_is_named(tmp_path) -> None:
    cert, key = tmp_path / "c.pem", tmp_path / "k.pem"
    with pytest.raises(ValueError, match=r"api.tls_certfile .*c.pem: no such file"):
        https_files(ApiSettings(tls_certfile=cert, tls_keyfile=key), tmp_path)
    cert.write_text("not a certificate")
    key.write_text("not a key")
    with pytest.raises(ValueError, match=r"c.pem with api.tls_keyfile .*k.pem do not load"):
        https_files(ApiSettings(tls_certfile=cert, tls_keyfile=key), tmp_path)


def test_a_certificate_without_its_key_is_a_config_error(tmp_path) -> None:
    with pytest.raises(ValidationError, match="tls_certfile and tls_keyfile go together"):
        ApiSettings(tls_certfile=tmp_path / "c.pem")
