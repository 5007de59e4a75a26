"""wss:// with a CA file, against a TLS WebSocket server on loopback whose
certificate is self-signed (made with the openssl command line tool).

lluavd itself has no TLS yet in this branch; the server here answers like
one (see fakeserver.py), so what is tested is the client's side: the TLS
context, the CA file, hostname checking, and refusing an untrusted server.
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
