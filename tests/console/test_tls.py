"""The console over https: the page is served by lluavd's TLS listener and
talks wss:// to the same origin."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

from conftest import PASSWORD
from harness import Lluavd, chromium
from page import Page


@pytest.fixture
def tls_daemon(binary):
    """lluavd serving TLS with a self-signed certificate for 127.0.0.1."""
    with tempfile.TemporaryDirectory(prefix="lluav-tls-") as d:
        cert, key = Path(d) / "cert.pem", Path(d) / "key.pem"
        subprocess.run(
            ["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
             "-nodes", "-days", "1", "-subj", "/CN=127.0.0.1", "-addext", "subjectAltName=IP:127.0.0.1",
             # A server's certificate, not a CA's: lluavd refuses a CA certificate at start.
             "-addext", "basicConstraints=critical,CA:FALSE",
             "-keyout", str(key), "-out", str(cert)],
            check=True, capture_output=True,
        )
        daemon = Lluavd(binary, "--password", PASSWORD, "--tls-cert", str(cert), "--tls-key", str(key))
        yield daemon
        print(f"lluavd stderr:\n{daemon.stderr()[-4000:]}")
        daemon.stop()


@pytest.fixture
def tls_browser():
    """A browser that accepts the self-signed certificate (and nothing else differs)."""
    driver = chromium(extra_flags=("--ignore-certificate-errors",))
    yield driver
    driver.quit()
    shutil.rmtree(driver.profile_dir, ignore_errors=True)


def test_page_served_over_https_talks_wss_to_its_own_origin(tls_daemon, tls_browser):
    assert tls_daemon.http_url.startswith("https://"), tls_daemon.http_url
    page = Page(tls_browser)
    page.open(tls_daemon)
    assert page.text("endpoint") == tls_daemon.ws_url, "the page talks wss:// to its own origin"
    assert tls_daemon.ws_url.startswith("wss://")
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "live state arrives over wss")
    page.screenshot("https")
    severe = [e for e in tls_browser.get_log("browser") if e["level"] == "SEVERE"]
    assert severe == [], f"the page logged errors: {severe}"
