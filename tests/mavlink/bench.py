"""Measurements of lluavd's MAVLink backend for BENCHMARKS.md.

1. Command latency: `takeoff` over WebSocket through lluavd (COMMAND_LONG
   ARM + NAV_TAKEOFF, each answered by COMMAND_ACK, then the reply),
   against the same two COMMAND_LONG round trips sent straight to the same
   autopilot (a pymavlink peer that answers at once, on a second UDP port)
   in the same run, interleaved.
2. `state` throughput at C connections (host/benches/state_load.rs) with
   the MAVSDK autopilot streaming telemetry at 50 Hz, against the
   simulator backend, alternating.

    python tests/mavlink/bench.py [--lluavd target/release/lluavd]
        [--rounds 200] [--connections 100] [--seconds 10]
"""

import argparse
import json
import os
import pathlib
import select
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent.parent
sys.path.insert(0, str(HERE))
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil  # noqa: E402
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

from conftest import PASSWORD, Client, free_udp_port, wait_for  # noqa: E402


class QuickAutopilot:
    """A PX4-flavoured pymavlink autopilot answering every COMMAND_LONG at
    once, on two links: lluavd's (udpout) and a bare client's (udpin)."""

    def __init__(self, lluavd_port, bare_port):
        self.links = [
            mavutil.mavlink_connection(f"udpout:127.0.0.1:{lluavd_port}", source_system=1,
                                       source_component=1, dialect="ardupilotmega"),
            mavutil.mavlink_connection(f"udpin:127.0.0.1:{bare_port}", source_system=1,
                                       source_component=1, dialect="ardupilotmega"),
        ]
        self.armed = False
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _heartbeat(self, link):
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
        link.mav.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, 0, mav.MAV_STATE_STANDBY)

    def _run(self):
        lluavd = self.links[0]
        next_beat = 0.0
        fds = {link.port.fileno(): link for link in self.links}
        while not self.stop.is_set():
            now = time.monotonic()
            if now >= next_beat:
                self._heartbeat(lluavd)
                lluavd.mav.home_position_send(473977420, 85455940, 488000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
                next_beat = now + 0.5
            ready, _, _ = select.select(list(fds), [], [], 0.05)
            for fd in ready:
                link = fds[fd]
                msg = link.recv_msg()
                while msg is not None:
                    if msg.get_type() == "COMMAND_LONG":
                        if msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
                            self.armed = msg.param1 == 1.0
                        link.mav.command_ack_send(msg.command, mav.MAV_RESULT_ACCEPTED, 0, 0,
                                                  msg.get_srcSystem(), msg.get_srcComponent())
                        if msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM and link is lluavd:
                            self._heartbeat(lluavd)  # the armed gate sees it at once
                    msg = link.recv_msg()

    def close(self):
        self.stop.set()
        self.thread.join()


def bare_round_trips(link, commands):
    """Sends each COMMAND_LONG and waits for its ACK; seconds for all."""
    start = time.perf_counter()
    for cmd, p1 in commands:
        link.mav.command_long_send(1, 1, cmd, 0, p1, 0, 0, 0, 0, 0, 0)
        while True:
            ack = link.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
            assert ack is not None, "no ACK on the bare link"
            if ack.command == cmd:
                break
    return time.perf_counter() - start


def start_lluavd(exe, tmp, mavlink_port=None):
    args = [exe, "--bind", "127.0.0.1:0", "--data-dir", str(tmp), "--password", PASSWORD,
            "--max-connections", "1000"]
    if mavlink_port:
        args += ["--mavlink", f"udpin:127.0.0.1:{mavlink_port}"]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env=dict(os.environ, RUST_LOG="warn"))
    url = proc.stdout.readline().split()[-1]
    return proc, url


def stop(proc):
    proc.terminate()
    proc.wait(timeout=10)


def pct(values, p):
    values = sorted(values)
    return values[min(len(values) - 1, int(p * (len(values) - 1)))]


def latency(exe, rounds):
    port, bare_port = free_udp_port(), free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = start_lluavd(exe, tmp, port)
        peer = QuickAutopilot(port, bare_port)
        bare = mavutil.mavlink_connection(f"udpout:127.0.0.1:{bare_port}", source_system=255,
                                          source_component=190, dialect="ardupilotmega")
        client = Client(url)
        client.ok(f"login {PASSWORD}")
        wait_for("link up", lambda: client.state()["link"] == "up")
        takeoff = [(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0), (mav.MAV_CMD_NAV_TAKEOFF, 0.0)]
        disarm = [(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0.0)]
        direct, through = [], []
        for _ in range(rounds):
            direct.append(bare_round_trips(bare, takeoff))
            bare_round_trips(bare, disarm)
            start = time.perf_counter()
            client.ok("takeoff")
            through.append(time.perf_counter() - start)
            client.ok("disarm")
            wait_for("disarmed", lambda: client.state()["armed"] is False, every=0.001)
        client.close()
        peer.close()
        stop(proc)
    ms = lambda v: round(v * 1000, 3)  # noqa: E731
    report = {
        "rounds": rounds,
        "bare_ms": {"p50": ms(pct(direct, 0.5)), "p90": ms(pct(direct, 0.9)), "p99": ms(pct(direct, 0.99))},
        "lluavd_ms": {"p50": ms(pct(through, 0.5)), "p90": ms(pct(through, 0.9)), "p99": ms(pct(through, 0.99))},
        "added_p50_ms": ms(statistics.median(t - d for t, d in zip(through, direct))),
    }
    print(json.dumps({"latency": report}))


def load(exe, url, args):
    out = subprocess.run(
        ["cargo", "bench", "-q", "-p", "lluav-host", "--bench", "state_load", "--",
         "--url", url, "--connections", str(args.connections), "--seconds", str(args.seconds),
         "--password", PASSWORD],
        cwd=ROOT, check=True, capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


TELEMETRY = ("LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "ATTITUDE", "EXTENDED_SYS_STATE")


def telemetry_count(url):
    c = Client(url)
    c.ok(f"login {PASSWORD}")
    counts = c.ok("mavlink_msgs")["mav_msgs"]
    c.close()
    return sum(counts.get(name, 0) for name in TELEMETRY)


def throughput(exe, args):
    from mavsdk_autopilot import MavsdkAutopilot, RATE_HZ
    for round_ in range(2):
        for backend in ("simulator", "mavlink"):
            with tempfile.TemporaryDirectory() as tmp:
                peer = None
                if backend == "mavlink":
                    port = free_udp_port()
                    proc, url = start_lluavd(exe, tmp, port)
                    peer = MavsdkAutopilot(port)
                    c = Client(url)
                    c.ok(f"login {PASSWORD}")
                    wait_for("link up", lambda: c.state()["link"] == "up")
                    c.close()
                else:
                    proc, url = start_lluavd(exe, tmp)
                before = telemetry_count(url) if peer else 0
                result = load(exe, url, args)
                if peer:
                    # What the autopilot really streamed during the load
                    # (MAVSDK in Python shares the two cores with the load).
                    received = telemetry_count(url) - before
                    result["telemetry_msgs_per_s"] = round(received / result["seconds"])
                    result["telemetry_target"] = f"4 messages x {RATE_HZ} Hz"
                    peer.close()
                stop(proc)
            print(json.dumps({"throughput": backend, "round": round_, **result}), flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lluavd", default=str(ROOT / "target" / "release" / "lluavd"))
    ap.add_argument("--rounds", type=int, default=200)
    ap.add_argument("--connections", type=int, default=100)
    ap.add_argument("--seconds", type=int, default=10)
    args = ap.parse_args()
    latency(args.lluavd, args.rounds)
    throughput(args.lluavd, args)


if __name__ == "__main__":
    main()
