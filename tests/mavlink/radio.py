"""What the radio-link tests share: flying the MAVSDK autopilot to a hover,
missions of any length, and reading what reached the autopilot (setpoint
rates, commands nobody asked for)."""

import json
import math
import time

from conftest import wait_for

ARM_DISARM = 400
NAV_TAKEOFF = 22
NAV_LAND = 21
NAV_RETURN_TO_LAUNCH = 20
MISSION_START = 300
DO_SET_MODE = 176
MISSION_ACCEPTED = 0
NOT_ON_AUTOPILOT = "Invalid arguments: mission {} is not on the autopilot"


def waypoints(n, radius=8.0):
    """A mission of `n` waypoints on a circle, 3-5 m up."""
    wps = [{"x": round(radius * math.cos(2 * math.pi * i / n), 2),
            "y": round(radius * math.sin(2 * math.pi * i / n), 2),
            "z": -3 - (i % 3)} for i in range(n)]
    return json.dumps({"waypoints": wps}, separators=(",", ":"))


def holds(autopilot, n):
    """Waits for the autopilot to hold a mission of `n` items: MAVSDK hands
    an upload to its callback after its MISSION_ACK went out."""
    return wait_for(f"a mission of {n} items on the autopilot", lambda: len(autopilot.holding) == n, timeout=5)


def hover(client, autopilot):
    """Takes off and waits for the hover; returns the takeoff answer."""
    r = client.ok("takeoff")
    wait_for("hovering", lambda: client.state()["fsm"] == "hover", timeout=30)
    wait_for("the autopilot armed", lambda: autopilot.armed)
    return r


def steer(client, autopilot, x, y, z):
    """set_sp_ned, and waits for the autopilot to get there."""
    r = client.ok(f"set_sp_ned {x}:{y}:{z}:0")
    wait_for("at the setpoint", lambda: math.dist(autopilot.position(), [x, y, z]) < 0.3, timeout=30)
    return r


def setpoints_since(autopilot, since):
    """Times of the SET_POSITION_TARGET_LOCAL_NEDs the autopilot got since `since`."""
    with autopilot.lock:
        return [t for t, _ in autopilot.setpoints if t >= since]


def per_second(times, start, seconds):
    """How many of `times` fell in each whole second from `start`."""
    return [sum(1 for t in times if start + i <= t < start + i + 1) for i in range(seconds)]


def stream_rate(autopilot, seconds=4):
    """Setpoints per second the autopilot receives over the next `seconds`."""
    start = time.monotonic()
    time.sleep(seconds)
    return per_second(setpoints_since(autopilot, start), start, seconds)


def unrequested(relay, since=0.0, disarm_asked=False, clear_asked=False):
    """Cleanup messages that reached the autopilot although no client asked
    for them: a disarm, MISSION_CLEAR_ALL, or a transfer cancelled after
    its last item reached the autopilot (which may then hold the whole
    mission; cancelling a transfer that stalled before its end is the
    mission protocol's own way to give up, and leaves the old mission)."""
    found = []
    count, last_sent = None, False
    for m in relay.received(since=since):
        kind = m.get_type()
        if kind == "COMMAND_LONG" and m.command == ARM_DISARM and m.param1 == 0 and not disarm_asked:
            found.append(f"DISARM (param2 {m.param2})")
        elif kind == "MISSION_CLEAR_ALL" and not clear_asked:
            found.append("MISSION_CLEAR_ALL")
        elif kind == "MISSION_COUNT":
            count, last_sent = m.count, False
        elif kind == "MISSION_ITEM_INT" and count is not None and m.seq == count - 1:
            last_sent = True
        elif kind == "MISSION_ACK" and m.type != MISSION_ACCEPTED and last_sent:
            found.append(f"MISSION_ACK {m.type} after the last item")
    return found


def cancelled_transfers(relay):
    """MISSION_ACKs other than accepted that lluavd sent the autopilot."""
    return sum(1 for m in relay.received("MISSION_ACK") if m.type != MISSION_ACCEPTED)
