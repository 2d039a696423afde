"""Who may open the page: loopback by default; beyond it a random token in the URL (shown as a QR
code in the terminal) and TLS with a self-signed certificate, since a headset's browser grants
WebXR only to a secure context (https, or http on localhost, which `adb reverse` provides).
"""
from __future__ import annotations

import datetime
import hmac
import ipaddress
import os
import secrets
import socket
import ssl
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from touch4d.bus.config import is_loopback  # noqa: F401  (the bus's rule: 127.0.0.0/8, ::1, localhost)

CERT_DAYS = 365
DEFAULT_CERT_DIR = Path(os.environ.get("XDG_CONFIG_HOME", Path.home() / ".config")) / "touch4d" / "webxr-tls"


def new_token() -> str:
    """A random URL-safe token (128 bits)."""
    return secrets.token_urlsafe(16)


def token_matches(given: str | None, token: str) -> bool:
    """Constant-time comparison (no timing hint about the token's characters)."""
    return given is not None and hmac.compare_digest(given.encode(), token.encode())


def lan_addresses(host: str) -> list[str]:
    """The addresses a headset on the LAN can use to reach a server bound to `host`."""
    if host not in ("0.0.0.0", "::", ""):
        return [host]
    found = []
    # A UDP "connection" sends nothing: it only asks the kernel which local address routes outward.
    # 192.0.2.1 is a documentation address (RFC 5737) that is never contacted.
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.connect(("192.0.2.1", 9))
            found.append(probe.getsockname()[0])
        except OSError:
            pass
    try:
        for info in socket.getaddrinfo(socket.gethostname(), None, socket.AF_INET):
            found.append(info[4][0])
    except OSError:
        pass
    lan = [a for a in dict.fromkeys(found) if not is_loopback(a)]
    return lan or ["127.0.0.1"]


def page_url(scheme: str, address: str, port: int, token: str | None) -> str:
    host = f"[{address}]" if ":" in address else address
    return f"{scheme}://{host}:{port}/" + (f"?token={token}" if token else "")


def qr_text(url: str) -> str:
    """The URL as a QR code drawn with block characters, for a headset's camera or a phone."""
    import io

    import segno

    out = io.StringIO()
    segno.make(url, error="l").terminal(out=out, compact=True)
    return out.getvalue()


# ---- TLS ------------------------------------------------------------------------------------------


def ensure_certificate(directory: Path, addresses: list[str]) -> tuple[Path, Path, str]:
    """A self-signed certificate for `addresses` (and localhost) in `directory`, made once and
    reused while valid for them; returns (certificate, key, SHA-256 fingerprint) so a user can
    compare the fingerprint with the one the headset's browser shows before accepting it."""
    directory = Path(directory)
    cert_path, key_path = directory / "cert.pem", directory / "key.pem"
    wanted = {"127.0.0.1", *addresses}
    if cert_path.exists() and key_path.exists():
        try:
            cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
            sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
            have = {str(ip) for ip in sans.get_values_for_type(x509.IPAddress)}
            fresh = cert.not_valid_after_utc > datetime.datetime.now(datetime.timezone.utc) + datetime.timedelta(days=1)
            if wanted <= have and fresh:
                return cert_path, key_path, fingerprint(cert)
        except (ValueError, x509.ExtensionNotFound):
            pass  # unreadable or foreign: make a new one
    directory.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "touch4d WebXR node"),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "touch4d (self-signed)")])
    now = datetime.datetime.now(datetime.timezone.utc)
    san = [x509.DNSName("localhost")] + [x509.IPAddress(ipaddress.ip_address(a)) for a in sorted(wanted)]
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(days=CERT_DAYS))
            .add_extension(x509.SubjectAlternativeName(san), critical=False)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.ExtendedKeyUsage([x509.oid.ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
            .sign(key, hashes.SHA256()))
    # The key is written readable by its owner only, before any byte of it reaches the disk.
    fd = os.open(key_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                  serialization.NoEncryption()))
    cert_path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path, fingerprint(cert)


def fingerprint(cert: x509.Certificate) -> str:
    return ":".join(f"{b:02X}" for b in cert.fingerprint(hashes.SHA256()))


def server_ssl_context(cert_path: Path, key_path: Path) -> ssl.SSLContext:
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_cert_chain(cert_path, key_path)
    return ctx
