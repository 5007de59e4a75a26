"""wss:// with a CA file: against the real lluavd serving TLS
(`--tls-cert/--tls-key`), and against a TLS WebSocket server on loopback
(fakeserver.py) for the client's side alone: the TLS context, the CA file,
hostname checking, and refusing an untrusted server. Certificates are
self-signed, made with the openssl command line tool.
"""

from __future__ import annotations

import asyncio
import ssl
import subprocess
from pathlib import Path

import pytest
from fakeserver import FakeServer

import lluav


def self_signed(directory: Path) -> tuple[Path, Path]:
    cert, key = directory / "cert.pem", directory / "key.pem"
    subprocess.run(
        [
            "openssl",
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:P-256",
            "-nodes",
            "-days",
            "2",
            "-subj",
            "/CN=localhost",
            "-addext",
            "subjectAltName=DNS:localhost,IP:127.0.0.1",
            # rustls (lluavd) refuses a CA certificate as a server's own.
            "-addext",
            "basicConstraints=critical,CA:FALSE",
            "-keyout",
            str(key),
            "-out",
            str(cert),
        ],
        check=True,
        capture_output=True,
    )
    return cert, key


@pytest.fixture
def tls_server(tmp_path):
    cert, key = self_signed(tmp_path)
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.load_cert_chain(cert, key)
    server = FakeServer(tls=context)
    try:
        yield server, cert
    finally:
        server.close()


def test_wss_with_the_servers_certificate_as_cafile_connects(tls_server):
    server, cert = tls_server
    assert server.url.startswith("wss://localhost:")
    with lluav.Client(server.url, cafile=str(cert)) as c:
        assert c.state()["cmd"] == 2

    async def run() -> None:
        async with lluav.AsyncClient(server.url, cafile=str(cert)) as c:
            assert (await c.ver())["cmd"] == 5

    asyncio.run(run())
    assert server.frames == ["state", "ver"]


def test_wss_without_a_trusted_certificate_is_refused(tls_server, tmp_path):
    server, _ = tls_server
    with pytest.raises(lluav.ConnectionError, match="CERTIFICATE_VERIFY_FAILED"):
        lluav.Client(server.url)
    elsewhere = tmp_path / "other"
    elsewhere.mkdir()
    other, _ = self_signed(elsewhere)
    with pytest.raises(lluav.ConnectionError, match="CERTIFICATE_VERIFY_FAILED"):
        asyncio.run(lluav.AsyncClient(server.url, cafile=str(other)).connect())
    assert server.frames == []


def test_wss_against_lluavd_serving_tls(lluavd, tmp_path):
    cert, key = self_signed(tmp_path)
    daemon = lluavd("--tls-cert", str(cert), "--tls-key", str(key), password="s3cret")
    assert daemon.url.startswith("wss://127.0.0.1:")
    with lluav.Client(daemon.url, password="s3cret", cafile=str(cert)) as c:
        assert c.state()["state"]["armed"] is False

    async def run() -> None:
        async with lluav.AsyncClient(daemon.url, password="s3cret", cafile=str(cert)) as c:
            assert (await c.ver())["ret"] == 0

    asyncio.run(run())
    with pytest.raises(lluav.ConnectionError, match="CERTIFICATE_VERIFY_FAILED"):
        lluav.Client(daemon.url, password="s3cret")
