"""A hostile neighbour on the autopilot's link: another local process that
sends to lluavd's UDP port while a flight runs.

    python hostile.py --port P [--seed S] [--garbage-rate N]
        [--heartbeat-sysid 2 [--heartbeat-autopilot ardupilot]]
        [--spoof-rate N] [--spoof-sysid 1]

- garbage: random datagrams, N per second; a third start with a MAVLink 2
  magic byte and a plausible length, so lluavd's parser has to read them;
- foreign heartbeats: 2 Hz from another system id (an ArduPilot by
  default), with HOME_POSITION, as a second vehicle on a shared port;
- spoofed answers: MISSION_REQUEST_INT / MISSION_REQUEST (in range and out
  of range), MISSION_ACK (accepted, error, cancelled), COMMAND_ACK
  (accepted, denied, for the flight commands), a disarmed HEARTBEAT and a
  HOME_POSITION elsewhere, claiming the autopilot's system and component
  ids, N per second in all.

Everything lluavd sends to it is counted by message type. On SIGTERM it
prints one JSON line: {"sent": {...}, "received": {...}}.

`Neighbour` starts and stops the process from a test.
"""

import argparse
import collections
import json
import os
import pathlib
import random
import select
import signal
import socket
import subprocess
import sys
import time

os.environ["MAVLINK20"] = "1"
from pymavlink.dialects.v20 import ardupilotmega as mav  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
SPOOFED_COMMANDS = (mav.MAV_CMD_COMPONENT_ARM_DISARM, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_LAND,
                    mav.MAV_CMD_DO_SET_MODE, mav.MAV_CMD_MISSION_START)
# lluavd's system (the autopilot's, by default) and component ids.
LLUAVD = (1, 191)
# A home far from the autopilot's (lat, lon in 1e-7 degrees).
SPOOFED_HOME = (473000000, 85000000)
AUTOPILOTS = {"ardupilot": mav.MAV_AUTOPILOT_ARDUPILOTMEGA, "px4": mav.MAV_AUTOPILOT_PX4}


class Buffer:
    """pymavlink writes encoded messages to a file: keep the bytes."""

    def __init__(self):
        self.data = b""

    def write(self, data):
        self.data += data

    def take(self):
        data, self.data = self.data, b""
        return data


def garbage(rng):
    n = rng.randint(1, 280)
    body = rng.randbytes(n)
    if rng.random() < 1 / 3:
        # A MAVLink 2 frame header with a length that fits the datagram.
        body = bytes([0xFD, max(0, n - 12) % 256]) + body[2:]
    return body


def spoof(rng, link):
    """One spoofed answer or piece of telemetry, as if from the autopilot."""
    kind = rng.randrange(6)
    seq = rng.choice([0, 1, 2, rng.randint(3, 60), 999, 65535])
    if kind == 0:
        link.mission_request_int_send(LLUAVD[0], LLUAVD[1], seq)
        return "MISSION_REQUEST_INT"
    if kind == 1:
        link.mission_request_send(LLUAVD[0], LLUAVD[1], seq)
        return "MISSION_REQUEST"
    if kind == 2:
        link.mission_ack_send(LLUAVD[0], LLUAVD[1], rng.choice([mav.MAV_MISSION_ACCEPTED, mav.MAV_MISSION_ERROR,
                                                mav.MAV_MISSION_OPERATION_CANCELLED]))
        return "MISSION_ACK"
    if kind == 3:
        link.command_ack_send(rng.choice(SPOOFED_COMMANDS),
                              rng.choice([mav.MAV_RESULT_ACCEPTED, mav.MAV_RESULT_DENIED]), 0, 0, *LLUAVD)
        return "COMMAND_ACK"
    if kind == 4:
        # Disarmed, whatever the vehicle is doing.
        link.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_GENERIC, 0, 0, mav.MAV_STATE_STANDBY)
        return "HEARTBEAT"
    link.home_position_send(SPOOFED_HOME[0], SPOOFED_HOME[1], 100000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
    return "HOME_POSITION"


class Schedule:
    """`rate` events per second, caught up in batches (a busy machine)."""

    def __init__(self, rate, now):
        self.period = 1.0 / rate if rate > 0 else None
        self.next = now

    def due(self, now):
        if self.period is None:
            return 0
        n = 0
        while self.next <= now and n < 1000:
            self.next += self.period
            n += 1
        if self.next < now:  # too far behind: do not try to catch up forever
            self.next = now
        return n


def run(args):
    rng = random.Random(args.seed)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    dest = ("127.0.0.1", args.port)
    out = Buffer()
    foreign = mav.MAVLink(out, srcSystem=args.heartbeat_sysid or 2, srcComponent=1)
    spoofer = mav.MAVLink(out, srcSystem=args.spoof_sysid, srcComponent=1)
    sent, received = collections.Counter(), collections.Counter()
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(True))
    now = time.monotonic()
    junk, fakes, beats = Schedule(args.garbage_rate, now), Schedule(args.spoof_rate, now), Schedule(
        2.0 if args.heartbeat_sysid else 0, now)
    print(json.dumps({"port": sock.getsockname()[1]}), flush=True)

    def send(data, kind):
        try:
            sock.sendto(data, dest)
            sent[kind] += 1
        except OSError:
            sent["failed"] += 1

    while not stop:
        now = time.monotonic()
        for _ in range(junk.due(now)):
            send(garbage(rng), "garbage")
        for _ in range(fakes.due(now)):
            kind = spoof(rng, spoofer)
            send(out.take(), kind)
        for _ in range(beats.due(now)):
            foreign.heartbeat_send(mav.MAV_TYPE_QUADROTOR, AUTOPILOTS[args.heartbeat_autopilot],
                                   mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0, mav.MAV_STATE_STANDBY)
            send(out.take(), "HEARTBEAT")
            foreign.home_position_send(*SPOOFED_HOME, 100000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0)
            send(out.take(), "HOME_POSITION")
        ready, _, _ = select.select([sock], [], [], 0.002)
        while ready:
            try:
                data = sock.recv(65535)
            except (BlockingIOError, ConnectionRefusedError):
                break
            parser = mav.MAVLink(None)
            parser.robust_parsing = True
            for m in parser.parse_buffer(data) or []:
                received[m.get_type()] += 1
            ready, _, _ = select.select([sock], [], [], 0)
    print(json.dumps({"sent": sent, "received": received}), flush=True)


class Neighbour:
    """The hostile process, from a test: `Neighbour(port, garbage_rate=...)`;
    `stop()` returns its counters."""

    def __init__(self, port, seed=1, garbage_rate=0, heartbeat_sysid=None, heartbeat_autopilot="ardupilot",
                 spoof_rate=0, spoof_sysid=1):
        args = [sys.executable, str(HERE / "hostile.py"), "--port", str(port), "--seed", str(seed),
                "--garbage-rate", str(garbage_rate), "--spoof-rate", str(spoof_rate),
                "--spoof-sysid", str(spoof_sysid), "--heartbeat-autopilot", heartbeat_autopilot]
        if heartbeat_sysid:
            args += ["--heartbeat-sysid", str(heartbeat_sysid)]
        self.proc = subprocess.Popen(args, stdout=subprocess.PIPE, text=True)
        self.port = json.loads(self.proc.stdout.readline())["port"]
        self.result = None

    def stop(self):
        if self.result is None:
            self.proc.terminate()
            out, _ = self.proc.communicate(timeout=10)
            self.result = json.loads(out.strip().splitlines()[-1])
        return self.result


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--port", type=int, required=True)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--garbage-rate", type=float, default=0)
    ap.add_argument("--heartbeat-sysid", type=int, default=0)
    ap.add_argument("--heartbeat-autopilot", choices=sorted(AUTOPILOTS), default="ardupilot")
    ap.add_argument("--spoof-rate", type=float, default=0)
    ap.add_argument("--spoof-sysid", type=int, default=1)
    run(ap.parse_args())


if __name__ == "__main__":
    main()
