"""The console in front of lluavd's MAVLink backend: the link badge and its
heartbeat age, from a small pymavlink autopilot (tests/mavlink)."""

from __future__ import annotations

import sys

import pytest

from conftest import PASSWORD
from harness import ROOT, Lluavd, free_udp_port

sys.path.insert(0, str(ROOT / "tests" / "mavlink"))
from fault_autopilot import FaultyAutopilot  # noqa: E402


@pytest.fixture
def mavlink_daemon(binary):
    port = free_udp_port()
    daemon = Lluavd(binary, "--mavlink", f"udpin:127.0.0.1:{port}", "--password", PASSWORD)
    autopilot = FaultyAutopilot(port)
    yield daemon, autopilot
    autopilot.close()
    print(f"lluavd stderr:\n{daemon.stderr()[-4000:]}")
    daemon.stop()


def test_link_badge_shows_the_autopilot_link_and_its_loss(mavlink_daemon, page):
    daemon, autopilot = mavlink_daemon
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.shown("link") and page.text("link").startswith("link up"), "the link shows up")
    age = float(page.text("link").split("·")[1].split()[0])
    assert age < 2.0, page.text("link")
    assert page.el("link").get_attribute("data-tone") == "good"
    page.screenshot("mavlink")
    autopilot.silent.set()
    page.wait(lambda: page.text("link").startswith("link lost"), "the lost link shows")
    assert page.el("link").get_attribute("data-tone") == "danger"
