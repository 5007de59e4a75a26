"""A real MQTT broker for the fleet tests: Debian's Mosquitto, started on a
free loopback port with a config file of its own (never the system's
service). scripts/test-python.sh installs it when it is missing
(scripts/mosquitto.sh); MOSQUITTO=path picks another binary.

``recommended=True`` runs the README's broker config and ACL as written
there (only paths and the port replaced): TLS, accounts, and each account
one identity."""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from pathlib import Path

WAIT = 30.0
README = Path(__file__).resolve().parents[2] / "README.md"


def readme_block(first: str) -> str:
    """The README's fenced block whose first line is ``first``."""
    text = README.read_text()
    start = text.index("```text\n" + first) + len("```text\n")
    return text[start : text.index("```", start)]


def readme_acl(users: dict[str, str]) -> str:
    """The README's ACL, with a block for each of ``users`` it lacks, made
    from the README's block of its kind (``drone-*``: a vehicle's)."""
    acl = readme_block("# /etc/mosquitto/lluav.acl")

    def block(name: str) -> str:
        start = acl.index(f"\nuser {name}\n") + 1
        end = acl.find("\n\n", start)
        return acl[start : end if end >= 0 else len(acl)]

    operator, vehicle = block("alice"), block("drone-1")
    for user in users:
        if f"\nuser {user}\n" not in acl:
            made = vehicle.replace("drone-1", user) if user.startswith("drone-") else operator.replace("alice", user)
            acl += f"\n{made}\n"
    return acl


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
    free one by default) starts it again where a stopped one listened;
    ``recommended`` runs the README's config and ACL (with ``users`` and
    ``tls``)."""

    def __init__(
        self,
        directory: Path,
        users: dict[str, str] | None = None,
        tls: tuple[Path, Path] | None = None,
        port: int | None = None,
        recommended: bool = False,
    ):
        directory.mkdir(parents=True, exist_ok=True)
        self.port = port or free_port()
        lines = ["persistence false", "log_dest stderr", "user root"]
        passwords = directory / "passwords"
        if users:
            passwords.write_text("")
            for name, password in users.items():
                subprocess.run(["mosquitto_passwd", "-b", str(passwords), name, password], check=True)
        if recommended:
            if tls is None or not users:
                raise ValueError("the README's broker serves mqtts:// to accounts: give tls and users")
            acl = directory / "lluav.acl"
            acl.write_text(readme_acl(users))
            paths = {"certfile": tls[0], "keyfile": tls[1], "password_file": passwords, "acl_file": acl}
            for line in readme_block("# /etc/mosquitto/conf.d/lluav.conf").splitlines():
                word = line.split(" ", 1)[0]
                if word == "listener":
                    line = f"listener {self.port} 127.0.0.1"
                elif word in paths:
                    line = f"{word} {paths[word]}"
                lines.append(line)
        else:
            lines += [f"listener {self.port} 127.0.0.1", "set_tcp_nodelay true"]
            if tls is not None:
                lines += [f"certfile {tls[0]}", f"keyfile {tls[1]}"]
            if users:
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
