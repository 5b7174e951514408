"""HTTPS for phones on the LAN: their motion sensors and WebXR need a secure context."""

from __future__ import annotations

import contextlib
import datetime
import ipaddress
import socket
from pathlib import Path

import psutil
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from crowdteleop.coord.guard.private import PRIVATE_FILE, private_dir, tighten, write_private


def local_names() -> list[str]:
    """Names and addresses this machine answers to: every interface's address (psutil; the
    host name often resolves to 127.0.1.1 only on Debian), IPv6 link-local ones aside (a
    browser cannot use them in a URL without a zone). No packet leaves to find them."""
    names = {"localhost", "127.0.0.1", "::1", socket.gethostname()}
    for addresses in psutil.net_if_addrs().values():
        for address in addresses:
            if address.family not in (socket.AF_INET, socket.AF_INET6):
                continue
            host = address.address.split("%", 1)[0]
            with contextlib.suppress(ValueError):
                if not ipaddress.ip_address(host).is_link_local:
                    names.add(host)
    with contextlib.suppress(OSError):
        for info in socket.getaddrinfo(socket.gethostname(), None):
            names.add(str(info[4][0]))
    return sorted(names)


_SERVER_KEY_USAGE = x509.KeyUsage(
    digital_signature=True,  # ECDHE: the key signs the handshake
    content_commitment=False,
    key_encipherment=False,
    data_encipherment=False,
    key_agreement=False,
    key_cert_sign=False,
    crl_sign=False,
    encipher_only=False,
    decipher_only=False,
)


def _san(names: list[str]) -> x509.SubjectAlternativeName:
    entries: list[x509.GeneralName] = []
    for name in names:
        try:
            entries.append(x509.IPAddress(ipaddress.ip_address(name)))
        except ValueError:
            entries.append(x509.DNSName(name))
    return x509.SubjectAlternativeName(entries)


def self_signed(directory: Path, names: list[str], days: int = 825) -> tuple[Path, Path]:
    """(certificate, key) in `directory`, made on first use and kept; a new one is made when
    it lacks one of `names` or is about to expire."""
    cert_path, key_path = directory / "cert.pem", directory / "key.pem"
    private_dir(directory)
    if cert_path.is_file() and key_path.is_file() and _still_good(cert_path, names):
        tighten(key_path, PRIVATE_FILE)
        return cert_path, key_path
    key = ec.generate_private_key(ec.SECP256R1())
    subject = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "crowdteleop (self-signed)")])
    now = datetime.datetime.now(datetime.UTC)
    certificate = (
        x509.CertificateBuilder()
        .subject_name(subject)
        .issuer_name(subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=days))
        .add_extension(_san(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        # iOS and macOS refuse a server certificate without these (Apple's TLS requirements).
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(_SERVER_KEY_USAGE, critical=True)
        .sign(key, hashes.SHA256())
    )
    write_private(  # 0600 from its first byte
        key_path,
        key.private_bytes(
            serialization.Encoding.PEM,
            serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption(),
        ),
    )
    cert_path.write_bytes(certificate.public_bytes(serialization.Encoding.PEM))
    return cert_path, key_path


def _still_good(cert_path: Path, names: list[str]) -> bool:
    """Ours is kept while it names every name, serves TLS servers (an older one without the
    serverAuth usage is remade) and has a week left."""
    try:
        certificate = x509.load_pem_x509_certificate(cert_path.read_bytes())
        san = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        usage = certificate.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    except (ValueError, x509.ExtensionNotFound):
        return False
    if ExtendedKeyUsageOID.SERVER_AUTH not in usage:
        return False
    have = {str(v) for v in san.get_values_for_type(x509.DNSName)}
    have |= {str(v) for v in san.get_values_for_type(x509.IPAddress)}
    soon = datetime.datetime.now(datetime.UTC) + datetime.timedelta(days=7)
    return set(names) <= have and certificate.not_valid_after_utc > soon
