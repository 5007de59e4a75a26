"""lluavd over a lossy radio link: the MAVSDK autopilot behind a seeded
lossy relay (loss, duplication, reordering, latency, blackouts, or one
kind of message lost every time). Every test checks what reached the
autopilot, not only lluavd's answers: an answer must agree with what the
autopilot did, and nothing a client did not ask for may reach it."""

import math
import time

import pytest

from conftest import free_udp_port, stays, wait_for
from mavsdk_autopilot import MavsdkAutopilot
from radio import (ARM_DISARM, DO_SET_MODE, MISSION_START, NAV_LAND, NAV_RETURN_TO_LAUNCH, NAV_TAKEOFF, holds,
                   hover, setpoints_since, steer, stream_rate, unrequested, waypoints)
from relay import LossyRelay

# PX4's custom mode for AUTO.RTL: main mode AUTO (4), sub mode RTL (5).
PX4_AUTO_RTL = 4 << 16 | 5 << 24
RADIO = dict(loss=0.15, duplicate=0.05, reorder=0.05, latency=0.02, jitter=0.02)


@pytest.fixture
def relayed(daemon_factory):
    """make(seed, up={...}, down={...}) -> (daemon, relay, autopilot, client)."""
    made = []

    def make(seed=1, up=None, down=None, extra=()):
        port = free_udp_port()
        daemon = daemon_factory(port, extra=extra)
        relay = LossyRelay(port, seed, up, down)
        autopilot = MavsdkAutopilot(relay.port)
        made.append((relay, autopilot))
        client = daemon.client()
        wait_for("link up with home", lambda: (s := client.state())["link"] == "up" and s["home_global"])
        return daemon, relay, autopilot, client

    yield make
    for relay, autopilot in made:
        autopilot.close()
        relay.close()


def test_a_whole_flight_flies_through_15_percent_loss_both_ways(relayed):
    _, relay, ap, client = relayed(seed=7, up=RADIO, down=RADIO)
    hover(client, ap)
    steer(client, ap, 3, 2, -4)
    r = client.ok(f"mission 42:{waypoints(3, radius=4)}")
    assert r["waypoints"] == 3
    holds(ap, 3)
    client.ok("mw_exec 42:1,2,3")
    last = ap.holding[-1]
    wait_for("the last waypoint reached", lambda: ap.mode == "hold" and math.dist(
        ap.position()[:2], [4 * math.cos(4 * math.pi / 3), 4 * math.sin(4 * math.pi / 3)]) < 0.3,
        timeout=60)
    assert last.z == 5.0
    client.ok("land")
    wait_for("landed and disarmed by the autopilot", lambda: not ap.armed, timeout=30)
    assert unrequested(relay) == []
    counters = relay.counters()
    assert counters["up"]["lost"] > 0 and counters["down"]["lost"] > 0, counters


def test_a_short_blackout_changes_nothing(relayed):
    _, relay, ap, client = relayed()
    hover(client, ap)
    steer(client, ap, 2, 0, -3)
    before = client.state()
    relay.blackout(2.0)
    end = time.monotonic() + 2.0
    wait_for("the blackout over", lambda: time.monotonic() > end + 0.5)
    rate = stream_rate(ap, 3)
    assert min(rate) >= 2, f"setpoints per second after the blackout: {rate}"
    after = client.state()
    assert (after["link"], after["fsm"], after["setpoint"]) == ("up", "hover", before["setpoint"])
    assert unrequested(relay) == []


def test_the_same_autopilot_after_a_lost_link_is_the_same_vehicle(relayed):
    _, relay, ap, client = relayed()
    hover(client, ap)
    steer(client, ap, 2, 0, -3)
    setpoint = client.state()["setpoint"]
    relay.blackout(5.0)
    wait_for("link lost", lambda: client.state()["link"] == "lost", timeout=10)
    state = wait_for("link up again", lambda: (s := client.state())["link"] == "up" and s, timeout=10)
    assert (state["fsm"], state["armed"], state["setpoint"]) == ("hover", True, setpoint)
    back = time.monotonic()
    wait_for("setpoints streamed again", lambda: len(setpoints_since(ap, back)) >= 5)
    client.ok("set_sp_ned 0:2:-3:0")
    assert unrequested(relay) == []


def lost_ack(kind, command):
    return lambda m: m.get_type() == kind and getattr(m, "command", None) == command


@pytest.mark.parametrize("lost", ["ARM", "NAV_TAKEOFF"])
def test_a_takeoff_whose_ack_is_lost_answers_0_when_the_vehicle_took_off(relayed, lost):
    _, relay, ap, client = relayed()
    relay.up.drop_if = lost_ack("COMMAND_ACK", {"ARM": ARM_DISARM, "NAV_TAKEOFF": NAV_TAKEOFF}[lost])
    r = client.cmd("takeoff")
    assert r["ret"] == 0, r
    assert relay.commands(NAV_TAKEOFF), "NAV_TAKEOFF never reached the autopilot"
    wait_for("climbing", lambda: ap.position()[2] < -1.0)
    stays("no disarm sent", lambda: not unrequested(relay), 2.0)
    assert ap.armed


LOST_ACKS = {
    # command: (its MAV_CMD, what the autopilot does when it obeys)
    "land": (NAV_LAND, lambda ap: ap.mode in ("land", "landed", "ready")),
    "rtl": (NAV_RETURN_TO_LAUNCH, lambda ap: ap.mode == "rtl"),
    "disarm": (ARM_DISARM, lambda ap: not ap.armed),
    "set_sp_ned 1:1:-3:0": (DO_SET_MODE, lambda ap: ap.mode == "offboard"),
    "mw_exec 8:1,2,3": (MISSION_START, lambda ap: ap.mode == "mission"),
}


@pytest.mark.parametrize("command", list(LOST_ACKS))
def test_a_flight_command_whose_ack_is_lost_answers_0_when_the_autopilot_obeyed(relayed, command):
    _, relay, ap, client = relayed()
    client.ok(f"mission 8:{waypoints(3, radius=4)}")
    hover(client, ap)
    if command == "rtl":
        # Far enough that the return outlasts lluavd's three attempts.
        steer(client, ap, 20, 0, -3)
    mav_cmd, obeyed = LOST_ACKS[command]
    relay.up.drop_if = lost_ack("COMMAND_ACK", mav_cmd)
    r = client.cmd(command)
    assert r["ret"] == 0, r
    assert obeyed(ap)
    assert unrequested(relay, disarm_asked=command == "disarm") == []


def test_a_return_over_before_its_lost_ack_stops_being_waited_for_answers_0(relayed):
    """From 4 m away the return takes about 2 s, within lluavd's three
    attempts: heartbeats said AUTO.RTL while lluavd waited, then the vehicle
    landed and disarmed. It happened, so the answer is 0."""
    _, relay, ap, client = relayed()
    relay.up.keep_log = True
    hover(client, ap)
    steer(client, ap, 4, 0, -2.5)
    relay.up.drop_if = lost_ack("COMMAND_ACK", NAV_RETURN_TO_LAUNCH)
    sent = time.monotonic()
    r = client.cmd("rtl")
    assert ap.commands_named(NAV_RETURN_TO_LAUNCH) and not ap.armed, "the return did not happen (the premise)"
    with relay.lock:
        modes = [m.custom_mode for t, m in relay.up.log if t >= sent and m.get_type() == "HEARTBEAT"]
    assert PX4_AUTO_RTL in modes, f"no AUTO.RTL heartbeat reached lluavd (the premise): {modes}"
    assert r["ret"] == 0, r


def test_reordered_and_duplicated_telemetry_is_not_a_new_autopilot(relayed):
    """Older ATTITUDEs arriving after newer ones must not read as a reboot."""
    heavy = dict(reorder=0.3, duplicate=0.2, latency=0.01, jitter=0.05)
    _, relay, ap, client = relayed(seed=5, up=heavy, down=heavy)
    hover(client, ap)
    steer(client, ap, 2, 0, -3)
    setpoint = client.state()["setpoint"]
    rate = stream_rate(ap, 5)
    assert min(rate) >= 2, f"setpoints per second: {rate}"
    state = client.state()
    assert (state["armed"], state["fsm"], state["setpoint"]) == (True, "hover", setpoint)
    assert relay.counters()["up"]["reordered"] > 50


def test_a_takeoff_that_never_reached_the_autopilot_answers_minus_3_and_nothing_is_cleaned_up(relayed):
    _, relay, ap, client = relayed()
    relay.down.drop_if = lost_ack("COMMAND_LONG", NAV_TAKEOFF)
    r = client.cmd("takeoff")
    assert r["ret"] == -3, r
    stays("no disarm sent", lambda: not unrequested(relay), 2.0)
    assert ap.armed and ap.position()[2] > -0.1  # armed on the ground, as lluavd left it


def test_a_lost_final_mission_ack_is_read_back_not_cancelled(relayed):
    _, relay, ap, client = relayed()
    relay.up.drop_if = lambda m: m.get_type() == "MISSION_ACK"
    r = client.cmd(f"mission 5:{waypoints(3)}")
    assert r["ret"] == 0, r
    holds(ap, 3)
    stays("no cleanup sent", lambda: not unrequested(relay), 2.0)
    assert len(ap.holding) == 3 and ap.clears == 0


def test_takeoff_counts_as_flying_at_once(relayed):
    _, relay, ap, client = relayed()
    for n in range(3):
        assert client.ok("takeoff")["fsm"] == "takeoff"
        state = client.state()
        assert (state["fsm"], state["airborne"]) == ("takeoff", True), (n, state)
        sent = time.monotonic()
        r = client.cmd("set_sp_ned 1:1:-3:0")
        assert r["ret"] == 0, (n, r)
        wait_for("setpoints at the autopilot", lambda since=sent: len(setpoints_since(ap, since)) >= 3)
        client.ok("disarm")
        wait_for("disarmed", lambda: client.state()["armed"] is False and not ap.armed)
