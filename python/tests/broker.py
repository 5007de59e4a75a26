"""A real MQTT broker for the fleet tests: Debian's Mosquitto, started on a
free loopback port with a config file of its own (never the system's
service). scripts/test-python.sh installs it when it is missing
(scripts/mosquitto.sh); MOSQUITTO=path picks another binary."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

WAIT = 30.0


def mosquitto_bin() -> str:
    found = os.environ.get("MOSQUITTO") or shutil.which("mosquitto")
    for candidate in [found, "/usr/sbin/mosquitto", "/usr/local/sbin/mosquitto"]:
        if candidate and os.access(candidate, os.X_OK):
            return candidate
    raise RuntimeError("Mosquitto is not installed: run `bash scripts/mosquitto.sh` (scripts/test-python.sh does)")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Mosquitto:
    """One running broker. ``users`` {name: password} turn anonymous access
    off; ``tls`` (certificate, key) serves mqtts:// instead; ``port`` (a
    free one by default) starts it again where a stopped one listened."""

    def __init__(
        self,
        directory: Path,
        users: dict[str, str] | None = None,
        tls: tuple[Path, Path] | None = None,
        port: int | None = None,
    ):
        directory.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        lines = [
            f"listener {self.port} 127.0.0.1",
            "persistence false",
            "log_dest stderr",
            "set_tcp_nodelay true",
            "user root",
        ]
        if tls is not None:
            lines += [f"certfile {tls[0]}", f"keyfile {tls[1]}"]
        if users:
            passwords = directory / "passwords"
            passwords.write_text("")
            for name, password in users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(passwords), name, password], check=True)
            lines += ["allow_anonymous false", f"password_file {passwords}"]
        else:
            lines.append("allow_anonymous true")
        config = directory / "mosquitto.conf"
        config.write_text("\n".join(lines) + "\n")
        self.log = directory / "mosquitto.log"
        self._log = open(self.log, "wb")
        self.proc = subprocess.Popen(
            [mosquitto_bin(), "-c", str(config)], stdin=subprocess.DEVNULL, stdout=self._log, stderr=self._log
        )
        self.url = f"{'mqtts://localhost' if tls else 'mqtt://127.0.0.1'}:{self.port}"
        deadline = time.monotonic() + WAIT
        while True:
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            except OSError:
                if self.proc.poll() is not None or time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(f"mosquitto did not start: {self.log.read_text()}") from None
                time.sleep(0.02)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            self.proc.wait(timeout=WAIT)
        self._log.close()
