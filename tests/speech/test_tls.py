"""TLS material for phones: when HTTPS is on, what the certificate names, key permissions,
renewal, a brought certificate, the fingerprint serve prints (no server needed)."""

from __future__ import annotations

import datetime as dt
import hashlib
import ipaddress
import stat
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.hazmat.primitives.serialization import Encoding

from server.http.tls import (
    TLSError,
    ensure_server_cert,
    fingerprint,
    is_loopback,
    tls_for,
    user_files,
    wants_tls,
)
from server.settings import Settings


def test_loopback_stays_http_and_other_hosts_get_https(tmp_path: Path) -> None:
    for host in ("127.0.0.1", "127.0.15.9", "::1", "localhost"):  # classified, never bound
        assert is_loopback(host) and not wants_tls(host, tls=True, cert=None)
    for host in ("0.0.0.0", "192.168.1.20", "console.local"):
        assert wants_tls(host, tls=True, cert=None)
        assert not wants_tls(host, tls=False, cert=None)  # --no-tls
    assert wants_tls("127.0.0.1", tls=True, cert=tmp_path / "c.pem")  # --cert: always
    assert tls_for(Settings(host="127.0.0.1", data_dir=tmp_path)) is None


def test_generated_ca_and_server_certificate(tmp_path: Path) -> None:
    files = ensure_server_cert(tmp_path, "0.0.0.0")
    assert files.ca is not None
    for key in (tmp_path / "ca-key.pem", files.key):
        assert stat.S_IMODE(key.stat().st_mode) == 0o600
    cert = x509.load_pem_x509_certificate(files.cert.read_bytes())
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "localhost" in san.get_values_for_type(x509.DNSName)
    assert ipaddress.ip_address("127.0.0.1") in san.get_values_for_type(x509.IPAddress)
    assert cert.not_valid_after_utc - cert.not_valid_before_utc < dt.timedelta(days=825)
    ca = x509.load_pem_x509_certificate(files.ca.read_bytes())
    assert cert.issuer == ca.subject
    cert.verify_directly_issued_by(ca)
    # Kept across restarts; remade for a host it does not name yet, under the same CA.
    assert ensure_server_cert(tmp_path, "0.0.0.0").fingerprint == files.fingerprint
    again = ensure_server_cert(tmp_path, "10.11.12.13")
    assert again.fingerprint != files.fingerprint and again.ca == files.ca
    cert2 = x509.load_pem_x509_certificate(again.cert.read_bytes())
    san2 = cert2.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert ipaddress.ip_address("10.11.12.13") in san2.get_values_for_type(x509.IPAddress)
    # Near expiry: renewed.
    later = dt.datetime.now(dt.UTC) + dt.timedelta(days=800)
    assert ensure_server_cert(tmp_path, "10.11.12.13", now=later).fingerprint != again.fingerprint


def test_brought_certificate_must_match_its_key(tmp_path: Path) -> None:
    a = ensure_server_cert(tmp_path / "a", "0.0.0.0")
    b = ensure_server_cert(tmp_path / "b", "0.0.0.0")
    assert user_files(a.cert, a.key).fingerprint == a.fingerprint
    with pytest.raises(TLSError, match="cannot use --cert"):
        user_files(a.cert, b.key)
    with pytest.raises(TLSError, match="go together"):
        tls_for(Settings(host="0.0.0.0", data_dir=tmp_path, cert=a.cert))


def test_the_fingerprint_is_the_certificates_sha256(tmp_path: Path) -> None:
    files = ensure_server_cert(tmp_path, "0.0.0.0")
    fp = fingerprint(files.cert.read_bytes())
    der = x509.load_pem_x509_certificate(files.cert.read_bytes()).public_bytes(Encoding.DER)
    assert fp == ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())


def test_serve_refuses_half_a_certificate_and_a_bad_recognizer(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """``uav-console serve`` in this process: both refusals come before anything starts."""
    from server.cli import main

    base = ["serve", "--data-dir", str(tmp_path), "--port", "1"]  # never reached
    assert main([*base, "--host", "0.0.0.0", "--cert", str(tmp_path / "c.pem")]) == 2
    assert "--cert and --key go together" in capsys.readouterr().err
    monkeypatch.setenv("UAVC_RECOGNIZER", "cloud")
    assert main(base) == 2
    assert "server, browser or auto" in capsys.readouterr().err
