"""The real pieces the browser tests drive: lluavd, and Debian's Chromium.

Nothing here downloads anything: lluavd is the binary in $LLUAVD or the one
cargo builds from this checkout, Chromium and ChromeDriver are the Debian
packages at fixed paths, and Selenium is told the driver's path so that its
driver manager never runs.
"""

from __future__ import annotations

import json
import os
import pathlib
import queue
import signal
import socket
import subprocess
import tempfile
import threading
import time

import websocket
from selenium import webdriver
from selenium.webdriver.chrome.options import Options
from selenium.webdriver.chrome.service import Service

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCREENSHOTS = ROOT / "target" / "console-screenshots"
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("CHROMEDRIVER", "/usr/bin/chromedriver")
#: Upper bound of any wait: a slow machine makes a test slower, never flaky.
WAIT = 30

# Flags that keep Chromium from reaching for the network on its own
# (updates, sync, field trials, QUIC probes): this machine's network is
# closed, and the tests must not depend on anything but lluavd.
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--no-default-browser-check",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-default-apps",
    "--disable-extensions",
    "--disable-features=Translate,OptimizationHints,MediaRouter",
    "--metrics-recording-only",
    "--password-store=basic",
    "--hide-scrollbars",
]


def lluavd_binary() -> str:
    """$LLUAVD, or the lluavd cargo builds from this checkout."""
    given = os.environ.get("LLUAVD")
    if given:
        return given
    cargo = os.environ.get("CARGO", "cargo")
    out = subprocess.run(
        [cargo, "build", "--quiet", "-p", "lluav-host", "--bin", "lluavd", "--message-format=json"],
        cwd=ROOT,
        check=True,
        stdout=subprocess.PIPE,
        text=True,
    )
    for line in out.stdout.splitlines():
        try:
            msg = json.loads(line)
        except json.JSONDecodeError:
            continue
        if msg.get("reason") == "compiler-artifact" and msg["target"]["name"] == "lluavd" and msg.get("executable"):
            return msg["executable"]
    raise RuntimeError("cargo reported no lluavd executable")


class Lluavd:
    """A running lluavd with its own data directory, on 127.0.0.1 port 0
    unless `bind` names an address (a restart on the address of one that
    stopped: the page reconnects to the same origin)."""

    def __init__(self, binary: str, *args: str, bind: str = "127.0.0.1:0"):
        self._dir = tempfile.TemporaryDirectory(prefix="lluav-console-")
        self.stderr_path = pathlib.Path(self._dir.name) / "stderr.log"
        env = {k: v for k, v in os.environ.items() if k != "LLUAV_PASSWORD"}
        env["RUST_LOG"] = "info"
        self._stderr = open(self.stderr_path, "wb")
        self.proc = subprocess.Popen(
            [binary, "--bind", bind, "--data-dir", str(pathlib.Path(self._dir.name) / "data"), *args],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            env=env,
            text=True,
        )
        lines: queue.Queue[str] = queue.Queue()
        threading.Thread(target=lambda: lines.put(self.proc.stdout.readline()), daemon=True).start()
        try:
            first = lines.get(timeout=WAIT)
        except queue.Empty:
            first = ""
        scheme, _, addr = first.strip().removeprefix("listening on ").partition("://")
        if not first.startswith("listening on ") or scheme not in ("ws", "wss"):
            self.stop()
            raise RuntimeError(f"lluavd did not start: {first!r}\n{self.stderr()}")
        self.addr = addr.rstrip("/")
        web = "https" if scheme == "wss" else "http"
        #: Where the page is served, and where its WebSocket goes.
        self.http_url = f"{web}://{self.addr}/"
        self.ws_url = f"{scheme}://{self.addr}/"

    def stderr(self) -> str:
        return self.stderr_path.read_text(errors="replace") if self.stderr_path.exists() else ""

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=WAIT)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._stderr.close()
        self._dir.cleanup()


class Client:
    """A plain WebSocket client of lluavd beside the page: another operator,
    or a reader of the answers the page reads."""

    def __init__(self, daemon: Lluavd):
        self.ws = websocket.create_connection(daemon.ws_url, timeout=WAIT, suppress_origin=True)
        #: What lluavd calls this session in `control` (`ws ADDR #N`) without its number.
        self.label_prefix = "ws {}:{} #".format(*self.ws.sock.getsockname()[:2])

    def ask(self, line: str) -> dict:
        self.ws.send(line)
        return json.loads(self.ws.recv())

    def ok(self, line: str) -> dict:
        answer = self.ask(line)
        assert answer["ret"] == 0, (line, answer)
        return answer

    def state_when(self, what: str, ready) -> dict:
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            answer = self.ok("state")
            if ready(answer["state"]):
                return answer
            time.sleep(0.1)
        raise AssertionError(f"never {what}: {answer}")

    def close(self) -> None:
        self.ws.close()


class Subscriber:
    """A plain reader of lluavd's `/events` stream beside the page, logged
    in first as DESIGN.md says (the login's answer comes before any event)."""

    def __init__(self, daemon: Lluavd, password: str | None):
        self.ws = websocket.create_connection(daemon.ws_url + "events", timeout=WAIT, suppress_origin=True)
        if password is not None:
            self.ws.send(f"login {password}")
            answer = json.loads(self.ws.recv())
            assert answer["ret"] == 0, answer

    def until(self, what: str, last) -> list[dict]:
        """Every event up to and including the first for which `last(event)` holds."""
        seen = []
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            self.ws.settimeout(max(0.1, deadline - time.monotonic()))
            seen.append(json.loads(self.ws.recv()))
            if last(seen[-1]):
                return seen
        raise AssertionError(f"never {what}: {seen}")

    def close(self) -> None:
        self.ws.close()


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing holds now (for a MAVLink link)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def chromium(width: int = 1440, height: int = 900, extra_flags: tuple[str, ...] = ()) -> webdriver.Chrome:
    """Headless Debian Chromium with a fresh profile, driven by Debian's ChromeDriver."""
    profile = tempfile.mkdtemp(prefix="lluav-chromium-")
    options = Options()
    options.binary_location = CHROMIUM
    for flag in (*CHROMIUM_FLAGS, *extra_flags):
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={profile}")
    options.add_argument(f"--window-size={width},{height}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    service = Service(executable_path=CHROMEDRIVER)
    driver = webdriver.Chrome(service=service, options=options)
    driver.profile_dir = profile
    return driver
