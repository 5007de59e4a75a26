"""lluavd on a shared, spoofable UDP port: a hostile neighbour (another
local process, hostile.py) sends garbage, another vehicle's heartbeats
and spoofed mission requests and acknowledgements to lluavd's port while
the MAVSDK autopilot flies. lluavd must keep following its autopilot,
send only to it, and keep streaming setpoints at their rate."""

import math

import pytest

from conftest import Daemon, free_udp_port, stays, wait_for
from fault_autopilot import mav
from hostile import Neighbour
from mavsdk_autopilot import HOME, MavsdkAutopilot
from radio import ARM_DISARM, holds, hover, steer, stream_rate, waypoints


@pytest.fixture(scope="module")
def hovering(tmp_path_factory):
    """One daemon and the MAVSDK autopilot hovering at (2, 0, -3) with a
    setpoint streamed, for the tests that only disturb the link."""
    port = free_udp_port()
    daemon = Daemon(tmp_path_factory.mktemp("shared"), port)
    ap = MavsdkAutopilot(port)
    client = daemon.client()
    wait_for("link up with home", lambda: (s := client.state())["link"] == "up" and s["home_global"])
    hover(client, ap)
    steer(client, ap, 2, 0, -3)
    yield daemon, port, ap, client
    ap.close()
    daemon.stop()


@pytest.mark.parametrize("rate", [1, 100, 2000])
def test_garbage_leaves_the_setpoint_stream_at_its_rate(hovering, rate):
    daemon, port, ap, client = hovering
    neighbour = Neighbour(port, seed=rate, garbage_rate=rate)
    try:
        per_second = stream_rate(ap, 5)
        state = client.state()
    finally:
        result = neighbour.stop()
    assert result["sent"]["garbage"] >= rate * 2, result["sent"]
    # lluavd streams at 10 Hz; PX4 leaves offboard below 2 Hz.
    assert min(per_second) >= 2 and sum(per_second) >= 25, per_second
    assert result["received"] == {}, f"lluavd sent to the neighbour: {result['received']}"
    assert (state["link"], state["fsm"]) == ("up", "hover")


def test_another_vehicles_heartbeats_do_not_take_the_link(hovering):
    daemon, port, ap, client = hovering
    neighbour = Neighbour(port, heartbeat_sysid=2)
    try:
        stays("following the MAVSDK autopilot",
              lambda: (s := client.state())["autopilot"] == "generic" and s["link"] == "up", 3.0)
        steer(client, ap, 2, 1, -3)
        assert client.ok("get_param MPC_XY_VEL_MAX")["param"] == {"MPC_XY_VEL_MAX": 12.0}
        assert client.state()["home_global"]["lat"] == pytest.approx(HOME[0])
    finally:
        result = neighbour.stop()
    assert result["sent"]["HEARTBEAT"] >= 4
    assert result["received"] == {}, f"lluavd sent to the other vehicle: {result['received']}"


def test_spoofed_acknowledgements_and_mission_requests_change_nothing(hovering):
    daemon, port, ap, client = hovering
    neighbour = Neighbour(port, seed=3, spoof_rate=200)
    try:
        for ext_id, n in ((50, 50), (3, 3)):
            r = client.cmd(f"mission {ext_id}:{waypoints(n, radius=3)}")
            assert r["ret"] == 0, r
            holds(ap, n)
        client.ok("mw_exec 3:1,2,3")
        wait_for("the mission started on the autopilot", lambda: ap.mode == "mission")
        wait_for("the mission flown", lambda: ap.mode == "hold" and math.dist(
            ap.position()[:2], [3 * math.cos(4 * math.pi / 3), 3 * math.sin(4 * math.pi / 3)]) < 0.3,
            timeout=40)
        stays("the autopilot's own telemetry in the state", lambda: (s := client.state())["armed"]
              and s["home_global"]["lat"] == pytest.approx(HOME[0]), 2.0, every=0.02)
    finally:
        result = neighbour.stop()
    assert sum(result["sent"].values()) >= 200, result["sent"]
    assert result["received"] == {}, f"lluavd sent to the spoofer: {result['received']}"
    assert ap.clears == 0 and not ap.failed_uploads, (ap.clears, ap.failed_uploads)


def test_a_spoofed_command_ack_does_not_answer_for_the_autopilot(vehicle, udp_port):
    """The autopilot never acknowledges ARM; a neighbour claiming to be it
    does (and denies, and acknowledges everything else)."""
    daemon, ap, client = vehicle()
    ap.ack_result[mav.MAV_CMD_COMPONENT_ARM_DISARM] = None
    neighbour = Neighbour(udp_port, seed=4, spoof_rate=300)
    try:
        r = client.cmd("takeoff")
    finally:
        result = neighbour.stop()
    assert r["ret"] == -3, r
    assert not ap.armed
    assert ap.commands(mav.MAV_CMD_NAV_TAKEOFF) == [], "takeoff sent on a spoofed ARM ack"
    assert result["received"] == {}, f"lluavd sent to the spoofer: {result['received']}"


def test_an_autopilot_asking_for_an_item_past_the_end_is_ignored(vehicle):
    _, ap, client = vehicle()
    ap.request_out_of_range_after = 1
    r = client.cmd(f"mission 3:{waypoints(3)}")
    assert r["ret"] == 0, r
    assert [m.seq for m in ap.mission] == [0, 1, 2]
    assert [m.type for m in ap.messages("MISSION_ACK")] == []


def test_an_autopilot_that_heartbeats_after_another_vehicle_is_the_one_followed(daemon_factory):
    port = free_udp_port()
    daemon = daemon_factory(port)
    client = daemon.client()
    neighbour = Neighbour(port, heartbeat_sysid=2)
    try:
        stays("another vehicle not followed", lambda: client.state()["autopilot"] is None, 2.5)
        ap = MavsdkAutopilot(port)
        try:
            state = wait_for("the autopilot followed", lambda: (s := client.state())["link"] == "up"
                             and s["home_global"] and s)
            assert state["autopilot"] == "generic"
            assert state["home_global"]["lat"] == pytest.approx(HOME[0])
            client.ok("takeoff")
            arms = wait_for("ARM at the autopilot", lambda: ap.commands_named(ARM_DISARM))
            assert arms[0]["target_system"] == 1
        finally:
            ap.close()
    finally:
        result = neighbour.stop()
    assert set(result["received"]) <= {"HEARTBEAT"}, f"lluavd sent to the other vehicle: {result['received']}"
