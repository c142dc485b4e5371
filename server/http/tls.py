"""HTTPS for phones: a local certificate authority and a server certificate, made on first start.

A phone that opens ``http://LAPTOP-IP:8000`` is not a secure context, so browsers give it no
microphone (W3C Secure Contexts §3; getUserMedia requires one). ``serve`` on a non-loopback
host therefore serves HTTPS/WSS by default with:

* ``ca.pem`` / ``ca-key.pem``: a CA made once per data directory (10 years); the page offers
  ``ca.pem`` for download (``GET /ca.pem``) so a phone can trust it once;
* ``server.pem`` / ``server-key.pem``: signed by that CA, SANs = the host name, ``localhost``,
  and every local address (remade when the set of addresses changes or it nears expiry).

Keys are written 0600. Loopback stays HTTP (it is already a secure context). ``--cert/--key``
take a real certificate instead; ``--no-tls`` opts out. The same CA signs the bus router's
certificate off loopback (``drone.bus``, docs/bus.md#tls).
"""

from __future__ import annotations

import datetime as dt
import hashlib
import ipaddress
import os
import socket
import ssl
from dataclasses import dataclass
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from server.settings import Settings

CA_DAYS = 3650
# Apple platforms reject TLS server certificates valid for more than 825 days
# (support.apple.com/en-us/103769); stay under it.
SERVER_DAYS = 820
RENEW_BEFORE_DAYS = 30


class TLSError(Exception):
    """TLS material cannot be made, read or verified; the message says which file and why."""


@dataclass(frozen=True)
class TLSFiles:
    cert: Path
    key: Path
    ca: Path | None  # None for a certificate the operator brought (--cert/--key)
    fingerprint: str  # SHA-256 of the server certificate (DER), hex with colons


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or address) only serves this machine."""
    if host in ("localhost", "localhost."):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def wants_tls(host: str, *, tls: bool, cert: Path | None) -> bool:
    """HTTPS when a certificate is given, or by default on a non-loopback host."""
    return cert is not None or (tls and not is_loopback(host))


def display_host(host: str) -> str:
    """The address to print in a URL: a wildcard bind shows this machine's LAN address."""
    if host in ("0.0.0.0", "::", ""):
        lan = sorted(
            (a for a in _interface_addresses() if a.version == 4 and not a.is_loopback), key=int
        )
        return str(lan[0]) if lan else socket.gethostname()
    return f"[{host}]" if ":" in host else host


def local_names(host: str) -> tuple[list[str], list[ipaddress.IPv4Address | ipaddress.IPv6Address]]:
    """(DNS names, IP addresses) the server certificate must name."""
    names = {"localhost", socket.gethostname()}
    with _suppress():
        names.add(socket.getfqdn())
    addrs: set[ipaddress.IPv4Address | ipaddress.IPv6Address] = {
        ipaddress.ip_address("127.0.0.1"),
        ipaddress.ip_address("::1"),
    }
    try:
        addrs.add(ipaddress.ip_address(host))
    except ValueError:
        if host not in ("", "0.0.0.0", "::"):
            names.add(host)
    for name in list(names):
        with _suppress():
            for info in socket.getaddrinfo(name, None):
                addrs.add(ipaddress.ip_address(str(info[4][0]).split("%")[0]))
    addrs.update(_interface_addresses())
    addrs.discard(ipaddress.ip_address("0.0.0.0"))
    addrs.discard(ipaddress.ip_address("::"))
    return sorted(n for n in names if n), sorted(addrs, key=lambda a: (a.version, int(a)))


def _interface_addresses() -> set[ipaddress.IPv4Address | ipaddress.IPv6Address]:
    """Addresses of this machine's interfaces (a UDP 'connect' reveals the outgoing one
    without sending anything; psutil is not a dependency)."""
    out: set[ipaddress.IPv4Address | ipaddress.IPv6Address] = set()
    for family, probe in ((socket.AF_INET, "192.0.2.1"), (socket.AF_INET6, "2001:db8::1")):
        with _suppress(), socket.socket(family, socket.SOCK_DGRAM) as s:
            s.connect((probe, 9))
            out.add(ipaddress.ip_address(s.getsockname()[0].split("%")[0]))
    return out


class _suppress:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> bool:
        return exc[0] is not None and issubclass(exc[0], OSError)  # type: ignore[arg-type]


def _write_private(path: Path, data: bytes) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def fingerprint(cert_pem: bytes) -> str:
    """SHA-256 of the certificate's DER form, as browsers show it (AB:CD:…)."""
    der = x509.load_pem_x509_certificate(cert_pem).public_bytes(serialization.Encoding.DER)
    return ":".join(f"{b:02X}" for b in hashlib.sha256(der).digest())


def ensure_ca(directory: Path, now: dt.datetime | None = None) -> tuple[Path, Path]:
    """The CA of ``directory`` (made if missing): (ca.pem, ca-key.pem)."""
    cert_path, key_path = directory / "ca.pem", directory / "ca-key.pem"
    if cert_path.is_file() and key_path.is_file():
        return cert_path, key_path
    now = now or dt.datetime.now(dt.UTC)
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name(
        [
            x509.NameAttribute(NameOID.ORGANIZATION_NAME, "uav-console"),
            x509.NameAttribute(
                NameOID.COMMON_NAME, f"uav-console local CA ({socket.gethostname()})"
            ),
        ]
    )
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=CA_DAYS))
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
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    _write_private(key_path, _key_pem(key))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def ensure_server_cert(
    directory: Path, host: str, now: dt.datetime | None = None, stem: str = "server"
) -> TLSFiles:
    """The server certificate for ``host`` signed by the local CA (made or remade as needed):
    ``<stem>.pem`` and ``<stem>-key.pem`` (the bus router has its own, ``bus``)."""
    now = now or dt.datetime.now(dt.UTC)
    ca_cert_path, ca_key_path = ensure_ca(directory, now)
    cert_path, key_path = directory / f"{stem}.pem", directory / f"{stem}-key.pem"
    names, addrs = local_names(host)
    if cert_path.is_file() and key_path.is_file() and _still_good(cert_path, names, addrs, now):
        return TLSFiles(cert_path, key_path, ca_cert_path, fingerprint(cert_path.read_bytes()))
    try:
        ca_cert = x509.load_pem_x509_certificate(ca_cert_path.read_bytes())
        ca_key = serialization.load_pem_private_key(ca_key_path.read_bytes(), password=None)
    except (ValueError, TypeError) as exc:
        raise TLSError(f"cannot read the local CA in {directory}: {exc}") from exc
    if not isinstance(ca_key, ec.EllipticCurvePrivateKey):
        raise TLSError(f"{ca_key_path} is not the EC key this program makes")
    key = ec.generate_private_key(ec.SECP256R1())
    san: list[x509.GeneralName] = [x509.DNSName(n) for n in names]
    san += [x509.IPAddress(a) for a in addrs]
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, names[0])]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - dt.timedelta(minutes=5))
        .not_valid_after(now + dt.timedelta(days=SERVER_DAYS))
        .add_extension(x509.SubjectAlternativeName(san), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
        .sign(ca_key, hashes.SHA256())
    )
    _write_private(key_path, _key_pem(key))
    pem = cert.public_bytes(serialization.Encoding.PEM)
    cert_path.write_bytes(pem)
    return TLSFiles(cert_path, key_path, ca_cert_path, fingerprint(pem))


def _still_good(
    path: Path,
    names: list[str],
    addrs: list[ipaddress.IPv4Address | ipaddress.IPv6Address],
    now: dt.datetime,
) -> bool:
    try:
        cert = x509.load_pem_x509_certificate(path.read_bytes())
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    except (ValueError, x509.ExtensionNotFound):
        return False
    if cert.not_valid_after_utc - now < dt.timedelta(days=RENEW_BEFORE_DAYS):
        return False
    have_names = set(san.get_values_for_type(x509.DNSName))
    have_addrs = set(san.get_values_for_type(x509.IPAddress))
    return set(names) <= have_names and set(addrs) <= have_addrs


def server_context(cert: Path, key: Path) -> ssl.SSLContext:
    """A server-side SSL context for this certificate and key (a vehicle's safety port).

    Raises:
        TLSError: they cannot be read or do not make a pair.
    """
    try:
        ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        ctx.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError, ValueError) as exc:
        raise TLSError(f"cannot use the certificate {cert} with the key {key}: {exc}") from exc
    return ctx


def user_files(cert: Path, key: Path) -> TLSFiles:
    """A certificate the operator brought (``--cert/--key``), checked to load as a pair."""
    try:
        ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
        ctx.load_cert_chain(cert, key)
        pem = cert.read_bytes()
        fp = fingerprint(pem)
    except (OSError, ssl.SSLError, ValueError) as exc:
        raise TLSError(f"cannot use --cert {cert} --key {key}: {exc}") from exc
    return TLSFiles(cert, key, None, fp)


def tls_for(settings: Settings) -> TLSFiles | None:
    """What ``serve`` should use: None (plain HTTP), the operator's pair, or the local CA's.

    Raises:
        TLSError: only one of cert/key given, or they cannot be used.
    """
    if (settings.cert is None) != (settings.key is None):
        raise TLSError("--cert and --key go together")
    if not wants_tls(settings.host, tls=settings.tls, cert=settings.cert):
        return None
    if settings.cert is not None and settings.key is not None:
        return user_files(settings.cert, settings.key)
    return ensure_server_cert(settings.data_dir / "tls", settings.host)
