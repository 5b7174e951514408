"""HTTPS for phones on the LAN: a self-signed certificate made once, and `serve --https`."""

from __future__ import annotations

import datetime
import ipaddress
import json
import socket
import ssl
import time

import httpx
import psutil
from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from crowdteleop.coord.guard.tls import local_names, self_signed
from tests.fixtures.coord import coord_server


def test_the_self_signed_certificate_is_made_once_and_remade_for_new_names(tmp_path):
    cert, key = self_signed(tmp_path, ["localhost", "127.0.0.1"])
    first = cert.read_bytes()
    assert self_signed(tmp_path, ["127.0.0.1"])[0].read_bytes() == first, "kept"
    self_signed(tmp_path, ["127.0.0.1", "phone-lan.example"])
    remade = x509.load_pem_x509_certificate(cert.read_bytes())
    names = remade.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "phone-lan.example" in names.get_values_for_type(x509.DNSName)
    assert oct(key.stat().st_mode & 0o777) == "0o600"
    ssl.create_default_context().load_cert_chain(cert, key)  # a pair that belongs together


def test_serve_https_gives_phones_an_https_link_and_teleop_servers_a_loopback_one(tmp_path):
    with coord_server(tmp_path, "--https") as server:
        assert server.url.startswith("https://127.0.0.1:")
        cert = server.data_dir / "tls" / "cert.pem"
        with httpx.Client(
            base_url=server.url, verify=ssl.create_default_context(cafile=cert)
        ) as http:
            assert http.get("/health").json()["status"] == "ok"
            token = http.post("/api/join", json={"params": {}}).json()["worker_token"]
            headers = {"Authorization": f"Bearer {token}"}
            sid = http.post("/api/sessions", headers=headers).json()["session_id"]
            pairing = http.post(f"/api/sessions/{sid}/pairing", headers=headers).json()
            link = f"{server.url}/phone?code={pairing['code']}&key="
            assert pairing["phone_url"].startswith(link)
            written = server.data_dir / "sessions" / sid / "teleop.json"
            deadline = time.monotonic() + 20
            while not written.exists():
                assert time.monotonic() < deadline
                time.sleep(0.05)
            report_url = json.loads(written.read_text())["report_url"]
            assert report_url.startswith("http://127.0.0.1:")
            assert report_url.endswith("/internal/episodes")
            internal = report_url.removesuffix("/internal/episodes")
            assert internal != server.url.replace("https", "http")
            assert httpx.get(f"{internal}/health").json()["status"] == "ok", "plain loopback"


def test_the_certificate_serves_tls_servers_as_ios_requires_and_an_older_one_is_remade(tmp_path):
    cert, _key = self_signed(tmp_path, ["127.0.0.1"])
    made = x509.load_pem_x509_certificate(cert.read_bytes())
    usage = made.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert ExtendedKeyUsageOID.SERVER_AUTH in usage
    assert made.extensions.get_extension_for_class(x509.KeyUsage).value.digital_signature
    # A certificate an earlier version made, without the extended key usage: remade.
    old_key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "old")])
    now = datetime.datetime.now(datetime.UTC)
    old = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(old_key.public_key())
        .serial_number(1)
        .not_valid_before(now)
        .not_valid_after(now + datetime.timedelta(days=30))
        .add_extension(
            x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]),
            critical=False,
        )
        .sign(old_key, hashes.SHA256())
    )
    cert.write_bytes(old.public_bytes(serialization.Encoding.PEM))
    self_signed(tmp_path, ["127.0.0.1"])
    remade = x509.load_pem_x509_certificate(cert.read_bytes())
    assert (
        ExtendedKeyUsageOID.SERVER_AUTH
        in remade.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    )


def test_the_certificate_names_every_address_of_every_interface(tmp_path):
    interfaces = {
        a.address.split("%")[0]
        for addresses in psutil.net_if_addrs().values()
        for a in addresses
        if a.family in (socket.AF_INET, socket.AF_INET6)
        and not ipaddress.ip_address(a.address.split("%")[0]).is_link_local
    }
    names = set(local_names())
    assert interfaces <= names, "a phone on any of this machine's networks can verify it"
    assert {"localhost", "127.0.0.1"} <= names
