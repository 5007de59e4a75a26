"""Fixtures: the real lluavd, started the real way on a free port.

The binary is $LLUAVD, or built with `cargo build -p lluav-host --bin lluavd`.
Each daemon gets its own data directory, is stopped with SIGTERM and must
exit with status 0 (a clean shutdown is part of every test that uses one).
"""

from __future__ import annotations

import json
import os
import selectors
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Callable

import pytest

ROOT = Path(__file__).resolve().parents[2]
STARTUP_TIMEOUT_S = 30.0


def _build_lluavd() -> str:
    """Builds lluavd with cargo and returns the path cargo reports."""
    out = subprocess.run(
        ["cargo", "build", "-p", "lluav-host", "--bin", "lluavd", "--message-format=json-render-diagnostics"],
        cwd=ROOT,
        check=True,
        stdout=subprocess.PIPE,
        text=True,
    ).stdout
    for line in out.splitlines():
        msg = json.loads(line)
        if msg.get("reason") == "compiler-artifact" and msg.get("target", {}).get("name") == "lluavd":
            if msg.get("executable"):
                return str(msg["executable"])
    raise RuntimeError("cargo built no lluavd executable")


@pytest.fixture(scope="session")
def lluavd_path() -> str:
    path = os.environ.get("LLUAVD")
    if path:
        if not os.access(path, os.X_OK):
            raise RuntimeError(f"LLUAVD={path} is not an executable")
        return path
    return _build_lluavd()


class Daemon:
    """One running lluavd."""

    def __init__(self, binary: str, data_dir: Path, args: list[str]) -> None:
        self.data_dir = data_dir
        self.log = data_dir.parent / f"{data_dir.name}.stderr"
        self._stderr = open(self.log, "wb")
        self.proc = subprocess.Popen(
            [binary, "--bind", "127.0.0.1:0", "--data-dir", str(data_dir), *args],
            stdout=subprocess.PIPE,
            stderr=self._stderr,
            stdin=subprocess.DEVNULL,
            # A password in the test runner's environment must not leak in.
            env={k: v for k, v in os.environ.items() if k != "LLUAV_PASSWORD"},
        )
        self.url = self._read_url()

    def _read_url(self) -> str:
        assert self.proc.stdout is not None
        sel = selectors.DefaultSelector()
        sel.register(self.proc.stdout, selectors.EVENT_READ)
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        line = b""
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            if left <= 0 or not sel.select(left):
                self.proc.kill()
                raise RuntimeError(f"lluavd printed no 'listening on' line in {STARTUP_TIMEOUT_S} s: {self.stderr()}")
            chunk = os.read(self.proc.stdout.fileno(), 1)
            if not chunk:
                self.proc.wait()
                raise RuntimeError(f"lluavd exited with {self.proc.returncode}: {self.stderr()}")
            line += chunk
        text = line.decode().strip()
        prefix = "listening on "
        if not text.startswith(prefix):
            raise RuntimeError(f"unexpected first line from lluavd: {text!r}")
        return text[len(prefix) :]

    def stderr(self) -> str:
        self._stderr.flush()
        return self.log.read_text(errors="replace")[-4000:]

    def stop(self) -> int:
        """SIGTERM, then the exit status (killed after 20 s)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._stderr.close()
        assert self.proc.stdout is not None
        self.proc.stdout.close()
        return self.proc.returncode


@pytest.fixture
def lluavd(lluavd_path: str, tmp_path: Path) -> Iterator[Callable[..., Daemon]]:
    """Starts lluavd: `lluavd(password=None, sim_speed=None, *extra_flags)`."""
    daemons: list[Daemon] = []

    def start(*extra: str, password: str | None = None, sim_speed: float | None = None) -> Daemon:
        args = list(extra)
        if password is not None:
            args += ["--password", password]
        if sim_speed is not None:
            args += ["--sim-speed", str(sim_speed)]
        data_dir = tmp_path / f"lluavd{len(daemons)}"
        data_dir.mkdir()
        daemon = Daemon(lluavd_path, data_dir, args)
        daemons.append(daemon)
        return daemon

    yield start
    for daemon in daemons:
        status = daemon.stop()
        assert status == 0, f"lluavd exited with {status}: {daemon.stderr()}"
