"""The TCP transport, and a link that fails and comes back: lluavd
reopens it and the vehicle is usable again. An address lluavd cannot
open stops it at start."""

import os
import socket
import subprocess

from conftest import ROOT, free_udp_port, wait_for
from fault_autopilot import FaultyAutopilot


def free_tcp_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_a_tcp_link_that_drops_is_reopened(daemon_factory):
    port = free_tcp_port()
    first = FaultyAutopilot(port, transport="tcpin")
    daemon = daemon_factory(free_udp_port(), f"tcpout:127.0.0.1:{port}")
    client = daemon.client()
    try:
        wait_for("link up over TCP", lambda: client.state()["link"] == "up")
    finally:
        first.close()
    wait_for("link lost", lambda: client.state()["link"] == "lost", timeout=15)
    assert client.cmd("takeoff")["ret"] == -3
    second = FaultyAutopilot(port, transport="tcpin")
    try:
        wait_for("link up again", lambda: client.state()["link"] == "up", timeout=20)
        assert client.ok("takeoff")["fsm"] == "takeoff"
    finally:
        second.close()


def test_an_address_lluavd_cannot_open_stops_it_at_start(tmp_path):
    exe = os.environ.get("LLUAVD", str(ROOT / "target" / "debug" / "lluavd"))
    port = free_tcp_port()  # nobody listens there
    r = subprocess.run([exe, "--mavlink", f"tcpout:127.0.0.1:{port}", "--data-dir", str(tmp_path),
                        "--bind", "127.0.0.1:0"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2
    assert f"cannot open the MAVLink link tcpout:127.0.0.1:{port}" in r.stderr
    bad = subprocess.run([exe, "--mavlink", "ttyACM0", "--data-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=30)
    assert bad.returncode == 2 and "--mavlink must be" in bad.stderr
