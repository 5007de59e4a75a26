"""The answers the console reads, as each backend really sends them.

A plain WebSocket client asks a real lluavd (the simulator, and the
MAVLink backend in front of a pymavlink autopilot) for `login`, `help`,
`state`, `mw_list` and the flight authority's `control`, `control_take`
and `control_release` in a few situations (control free, held by the
asking session or another, a failsafe and its override), and compares each answer's shape
(member names, JSON types, nulls) with the copy kept in answers/, which
js/vehicle.test.mjs reads the page's parser against. The events of a
flight (`/events`: a mission, a take-over, a failsafe overridden, a
landing) are kept the same way for js/events.test.mjs. A backend that renames,
adds, drops or retypes a member fails here, until its new answer is
captured:

    LLUAV_CAPTURE=1 bash scripts/test-console.sh -k answers
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time

from conftest import PASSWORD
from harness import ROOT, Client, Lluavd, Subscriber, free_udp_port

sys.path.insert(0, str(ROOT / "tests" / "mavlink"))
from fault_autopilot import FaultyAutopilot, mav  # noqa: E402

ANSWERS = ROOT / "tests" / "console" / "answers"
MISSION = {"waypoints": [{"x": 5, "y": 0, "z": -3}, {"x": 5, "y": 5, "z": -3}, {"x": 0, "y": 5, "z": -3, "yaw": 1}]}
MISSION_LINE = f"mission 1001:{json.dumps(MISSION, separators=(',', ':'))}"


def shape(value):
    """What a consumer relies on: member names and JSON types, not values."""
    if value is None or isinstance(value, str):
        return value if value is None else "string"
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, (int, float)):
        return "number"
    if isinstance(value, list):
        return [json.loads(s) for s in sorted({json.dumps(shape(v), sort_keys=True) for v in value})]
    return {k: shape(v) for k, v in value.items()}


def check(name: str, answer: dict) -> None:
    path = ANSWERS / f"{name}.json"
    if os.environ.get("LLUAV_CAPTURE"):
        ANSWERS.mkdir(exist_ok=True)
        path.write_text(json.dumps(answer, indent=2) + "\n")
        return
    kept = json.loads(path.read_text())
    assert shape(answer) == shape(kept), (
        f"{name}: the backend's answer changed shape; make host/console/vehicle.js read the new one, "
        f"then capture it (LLUAV_CAPTURE=1 bash scripts/test-console.sh -k answers).\n"
        f"now:  {json.dumps(answer, sort_keys=True)}\nkept: {json.dumps(kept, sort_keys=True)}"
    )


def test_the_simulator_sends_what_the_console_reads(binary):
    daemon = Lluavd(binary, "--password", PASSWORD, "--sim-speed", "4")
    try:
        client = Client(daemon)
        check("login-refused", client.ask("login not-it"))
        check("login", client.ok(f"login {PASSWORD}"))
        check("help", client.ok("help"))
        check("sim-state-ground", client.state_when("disarmed", lambda s: s["fsm"] == "disarmed"))
        check("sim-mw_list-empty", client.ok("mw_list"))
        client.ok(MISSION_LINE)
        check("sim-mw_list", client.ok("mw_list"))
        client.ok("takeoff")
        client.state_when("hovering", lambda s: s["fsm"] == "hover")
        client.ok("mw_exec 1001:1,2,3")
        check("sim-state-mission", client.state_when("flying the mission", lambda s: s["fsm"] == "mission"))
        # The pilot as another session sees it, then taking over.
        other = Client(daemon)
        other.ok(f"login {PASSWORD}")
        check("sim-control-other", other.ok("control"))
        check("sim-control_take", other.ok("control_take"))
        check("sim-control_release", other.ok("control_release"))
        check("sim-control-free", other.ok("control"))
    finally:
        daemon.stop()


def test_the_simulators_failsafe_as_the_console_reads_it(binary):
    daemon = Lluavd(binary, "--password", PASSWORD, "--sim-speed", "4")
    try:
        client = Client(daemon)
        client.ok(f"login {PASSWORD}")
        # The battery runs low within seconds of the takeoff; the return
        # climbs high, so that it is still on its way when overridden.
        for param in ("battery_drain:100", "low_battery:90", "rtl_alt:120"):
            client.ok(f"set_param {param}")
        client.ok("takeoff")
        check("sim-state-failsafe", client.state_when("in failsafe", lambda s: s["failsafe"] is not None))
        check("sim-control_take-failsafe", client.ok("control_take failsafe"))
        check("sim-state-overridden", client.state_when("overridden", lambda s: s["failsafe"].endswith(" (overridden)")))
    finally:
        daemon.stop()


def test_the_simulators_events_as_the_console_reads_them(binary):
    daemon = Lluavd(binary, "--password", PASSWORD, "--sim-speed", "4")
    try:
        events = Subscriber(daemon, PASSWORD)
        pilot = Client(daemon)
        pilot.ok(f"login {PASSWORD}")
        pilot.ok(MISSION_LINE)
        pilot.ok("takeoff")
        pilot.state_when("hovering", lambda s: s["fsm"] == "hover")
        pilot.ok("mw_exec 1001:1,2,3")
        flight = events.until("the mission completed", lambda e: e["event"] == "mission" and e["status"] == "completed")
        # Another operator takes over and lands.
        other = Client(daemon)
        other.ok(f"login {PASSWORD}")
        other.ok("control_take")
        other.ok("land")
        flight += events.until("disarmed", lambda e: e["event"] == "armed" and not e["armed"])
        # Parameters change on the ground only: the battery then runs low
        # soon after the next takeoff, a failsafe the pilot overrides.
        for param in ("battery_drain:100", "low_battery:90"):
            other.ok(f"set_param {param}")
        other.ok("takeoff")
        flight += events.until("a failsafe", lambda e: e["event"] == "failsafe" and e["reason"] is not None)
        other.ok("control_take failsafe")
        flight += events.until("the override", lambda e: e["event"] == "failsafe" and e["overridden"])
        other.ok("land")
        # The failsafe ends on the ground, disarmed, and says so.
        flight += events.until("the failsafe's end", lambda e: e["event"] == "failsafe" and e["reason"] is None)
        check("sim-events", flight)
    finally:
        daemon.stop()


def telemetry(autopilot: FaultyAutopilot, stop: threading.Event) -> None:
    """What a flying autopilot streams beside its heartbeat and home."""
    m, boot = autopilot.conn.mav, time.monotonic()
    while not stop.wait(0.1):
        ms = int((time.monotonic() - boot) * 1000)
        with autopilot.lock:
            if autopilot.silent.is_set():
                continue
            m.local_position_ned_send(ms, 3.0, -2.0, -10.0, 0.5, 0.25, -0.1)
            m.attitude_send(ms, 0.0, 0.0, 1.25, 0.0, 0.0, 0.0)
            m.global_position_int_send(ms, 473978000, 85455000, 498000, 10000, 50, 25, -10, 12500)
            m.sys_status_send(0, 0, 0, 500, 15200, -1, 76, 0, 0, 0, 0, 0, 0)
            m.extended_sys_state_send(mav.MAV_VTOL_STATE_UNDEFINED, mav.MAV_LANDED_STATE_IN_AIR)


def test_the_mavlink_backend_sends_what_the_console_reads(binary):
    port = free_udp_port()
    daemon = Lluavd(binary, "--mavlink", f"udpin:127.0.0.1:{port}", "--password", PASSWORD)
    autopilot, stop = FaultyAutopilot(port), threading.Event()
    streaming = threading.Thread(target=telemetry, args=(autopilot, stop), daemon=True)
    streaming.start()
    try:
        client = Client(daemon)
        client.ok(f"login {PASSWORD}")
        known = ("position", "velocity", "yaw", "altitude", "battery", "home", "heartbeat_age_ms")
        up = client.state_when("all telemetry known", lambda s: s["link"] == "up" and None not in map(s.get, known))
        check("mavlink-state", up)
        client.ok(MISSION_LINE)
        check("mavlink-mw_list", client.ok("mw_list"))
        autopilot.silent.set()
        check("mavlink-state-lost", client.state_when("link lost", lambda s: s["link"] == "lost"))
    finally:
        stop.set()
        streaming.join()
        autopilot.close()
        daemon.stop()
