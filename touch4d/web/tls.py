"""https for the page beyond loopback: a self-signed certificate made once and reused while valid,
since a headset's browser grants WebXR only to a secure context (https, or http on localhost).

The private key is written so that no other user can read it at any moment and no planted symlink
can redirect it (touch4d.atomic: a new file of mode 0600, then renamed), in a directory of mode 0700. A key reused
must be a regular file of this user's, readable by nobody else; if not, a new pair is made.
"""
from __future__ import annotations

import datetime
import ipaddress
import os
import ssl
import stat
from pathlib import Path

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from touch4d.atomic import write_atomic
from touch4d.errors import ConfigError

CERT_DAYS = 365
DEFAULT_CERT_DIR = Path(os.environ.get("XDG_CONFIG_HOME", Path.home() / ".config")) / "touch4d" / "webxr-tls"


def ensure_certificate(directory: Path, addresses: list[str]) -> tuple[Path, Path, str]:
    """A self-signed certificate for `addresses` (and localhost) in `directory`, made once and
    reused while valid for them; returns (certificate, key, SHA-256 fingerprint) so a user can
    compare the fingerprint with the one the headset's browser shows before accepting it."""
    directory = Path(directory)
    cert_path, key_path = directory / "cert.pem", directory / "key.pem"
    wanted = {"127.0.0.1", *addresses}
    _private_directory(directory)
    if cert_path.exists() and _private_file(key_path):
        try:
            cert = x509.load_pem_x509_certificate(cert_path.read_bytes())
            sans = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
            have = {str(ip) for ip in sans.get_values_for_type(x509.IPAddress)}
            fresh = cert.not_valid_after_utc > datetime.datetime.now(datetime.timezone.utc) + datetime.timedelta(days=1)
            if wanted <= have and fresh:
                return cert_path, key_path, fingerprint(cert)
        except (ValueError, x509.ExtensionNotFound):
            pass  # unreadable or foreign: make a new one
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
    write_atomic(key_path, key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                              serialization.NoEncryption()), 0o600)
    write_atomic(cert_path, cert.public_bytes(serialization.Encoding.PEM), 0o644)
    return cert_path, key_path, fingerprint(cert)


def _private_directory(directory: Path) -> None:
    """The certificate's directory, made 0700; an existing one of this user's is narrowed to 0700."""
    directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = os.lstat(directory)
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.geteuid():
        raise ConfigError(directory, "cert_dir", "a directory of this user's (not a symlink) for the TLS key")
    if st.st_mode & 0o077:
        os.chmod(directory, 0o700)


def _private_file(path: Path) -> bool:
    """Whether `path` is a key fit to reuse: a regular file (not a symlink) of this user's, mode 0600 or narrower."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return False
    return stat.S_ISREG(st.st_mode) and st.st_uid == os.geteuid() and not st.st_mode & 0o077


def fingerprint(cert: x509.Certificate) -> str:
    return ":".join(f"{b:02X}" for b in cert.fingerprint(hashes.SHA256()))


def server_ssl_context(cert_path: Path, key_path: Path) -> ssl.SSLContext:
    ctx = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
    ctx.minimum_version = ssl.TLSVersion.TLSv1_2
    ctx.load_cert_chain(cert_path, key_path)
    return ctx
