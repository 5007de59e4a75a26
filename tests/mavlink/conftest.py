"""Fixtures: the real lluavd (LLUAVD=path, default target/debug/lluavd)
on a free WebSocket port, flying the autopilot on a free UDP port over
real UDP, and WebSocket clients for it."""

import contextlib
import json
import os
import pathlib
import socket
import subprocess
import sys
import time

import pytest
from websockets.sync.client import connect

HERE = pathlib.Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
ROOT = HERE.parent.parent
PASSWORD = "mavlink-test"


def free_udp_port():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(what, predicate, timeout=20.0, every=0.05):
    """Polls `predicate` until it returns something truthy; fails after
    `timeout` seconds (generous: the machine is shared and noisy)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(every)


def stays(what, predicate, seconds, every=0.1):
    """Checks `predicate` stays truthy for `seconds`: for what must NOT
    happen (a link that must not come up, a stream that must stay quiet),
    the window is the test's bound, and a failure says when it broke."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        assert predicate(), f"{what} no longer held after {seconds - (deadline - time.monotonic()):.1f} s"
        time.sleep(every)


class Client:
    """One WebSocket session: `cmd` sends a frame and returns the JSON reply.
    `keepalive=False` sends no pings (lluavd answers a ping only after the
    session's pending command, which can outlast websockets' 20 s ping
    timeout on a lossy link)."""

    def __init__(self, url, keepalive=True):
        self._stack = contextlib.ExitStack()
        ping = {} if keepalive else {"ping_interval": None}
        self.ws = self._stack.enter_context(connect(url, open_timeout=10, close_timeout=5, **ping))

    def cmd(self, text, timeout=30.0):
        self.ws.send(text)
        return json.loads(self.ws.recv(timeout=timeout))

    def ok(self, text, timeout=30.0):
        reply = self.cmd(text, timeout)
        assert reply["ret"] == 0, f"{text}: {reply}"
        return reply

    def state(self):
        return self.ok("state")["state"]

    def close(self):
        self._stack.close()


class Events:
    """The daemon's `/events` stream, logged in: `until` reads events into
    `seen` until a condition on them holds."""

    def __init__(self, url):
        self._stack = contextlib.ExitStack()
        self.ws = self._stack.enter_context(connect(url.rstrip("/") + "/events", open_timeout=10, close_timeout=5))
        self.ws.send(f"login {PASSWORD}")
        reply = json.loads(self.ws.recv(timeout=10))
        assert reply["ret"] == 0, reply
        self.seen = []

    def until(self, what, predicate, timeout=40.0):
        end = time.monotonic() + timeout
        while not predicate(self.seen):
            left = end - time.monotonic()
            if left <= 0:
                raise AssertionError(f"timed out after {timeout} s waiting for {what}: {self.seen}")
            try:
                self.seen.append(json.loads(self.ws.recv(timeout=left)))
            except TimeoutError:
                pass
        return self.seen

    def close(self):
        self._stack.close()


class Daemon:
    """lluavd with --mavlink udpin on `port`, or at `address`; `extra`
    arguments appended (`--mavlink-system`, `--mavlink-signing-key`)."""

    def __init__(self, tmp, port, address=None, extra=()):
        exe = os.environ.get("LLUAVD", str(ROOT / "target" / "debug" / "lluavd"))
        self.log = open(tmp / "lluavd.log", "w")
        env = dict(os.environ, RUST_LOG=os.environ.get("RUST_LOG", "info,lluav_host::mavlink=debug"))
        self.proc = subprocess.Popen(
            [exe, "--mavlink", address or f"udpin:127.0.0.1:{port}", "--bind", "127.0.0.1:0",
             "--data-dir", str(tmp / "data"), "--password", PASSWORD, *extra],
            stdout=subprocess.PIPE, stderr=self.log, text=True, env=env)
        line = self.proc.stdout.readline()
        if not line.startswith("listening on "):
            self.proc.wait(timeout=10)
            self.log.close()
            raise AssertionError(f"lluavd did not start: {line!r}: {(tmp / 'lluavd.log').read_text()[-600:]}")
        self.url = line.split()[-1]
        self.clients = []
        self.streams = []

    def client(self, login=True, keepalive=True):
        c = Client(self.url, keepalive)
        self.clients.append(c)
        if login:
            c.ok(f"login {PASSWORD}")
        return c

    def events(self):
        e = Events(self.url)
        self.streams.append(e)
        return e

    def stop(self):
        for c in self.clients + self.streams:
            try:
                c.close()
            except Exception:
                pass
        self.proc.terminate()
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self.log.close()


@pytest.fixture
def udp_port():
    return free_udp_port()


@pytest.fixture
def daemon_factory(tmp_path):
    started = []

    def start(port, address=None, extra=()):
        d = Daemon(tmp_path, port, address, extra)
        started.append(d)
        return d

    yield start
    for d in started:
        d.stop()


@pytest.fixture
def vehicle(daemon_factory, udp_port):
    """make(autopilot=PX4, extra=(), **reports) -> (daemon, pymavlink
    autopilot, logged-in client), the link up and home known; `extra` goes
    to lluavd, `reports` to the autopilot (what it reports from the start,
    its parameters, the modes it enters)."""
    from fault_autopilot import FaultyAutopilot, mav

    made = []

    def make(autopilot=mav.MAV_AUTOPILOT_PX4, extra=(), **reports):
        daemon = daemon_factory(udp_port, extra=extra)
        ap = FaultyAutopilot(udp_port, autopilot, **reports)
        made.append(ap)
        client = daemon.client()
        wait_for("link up with home", lambda: (s := client.state())["link"] == "up" and s["home_global"])
        return daemon, ap, client

    yield make
    for ap in made:
        ap.close()
