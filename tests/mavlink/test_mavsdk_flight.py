"""A whole flight through the real lluavd, over real WebSocket and real
UDP, with the C++ MAVSDK library as the autopilot. The tests run in file
order on one daemon and one autopilot: each step starts where the last
one left the vehicle."""

import math
import time

import pytest

import geo
from conftest import Daemon, free_udp_port, wait_for
from mavsdk_autopilot import FLOAT_PARAMS, HOME, MavsdkAutopilot

MAV_CMD_COMPONENT_ARM_DISARM = 400
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_NAV_LAND = 21
MAV_CMD_DO_SET_MODE = 176
FORCE_DISARM = 21196


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    port = free_udp_port()
    daemon = Daemon(tmp_path_factory.mktemp("flight"), port)
    autopilot = MavsdkAutopilot(port)
    client = daemon.client()
    yield daemon, autopilot, client
    autopilot.close()
    daemon.stop()


def test_commands_need_a_login(flight):
    daemon, _, _ = flight
    stranger = daemon.client(login=False)
    assert stranger.cmd("takeoff")["msg"] == "Login first!"


def test_the_link_comes_up_with_the_autopilots_telemetry(flight):
    _, _, client = flight
    state = wait_for("link up and home known",
                     lambda: (s := client.state())["link"] == "up" and s["home_global"] and s)
    assert state["autopilot"] == "generic"
    assert state["armed"] is False and state["fsm"] == "disarmed"
    assert state["heartbeat_age_ms"] < 3000
    assert state["home_global"] == {"lat": HOME[0], "lon": HOME[1], "alt": HOME[2]}
    assert wait_for("battery", lambda: client.state()["battery"]) == 87
    counts = client.ok("mavlink_msgs")["mav_msgs"]
    for name in ("HEARTBEAT", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "ATTITUDE",
                 "EXTENDED_SYS_STATE", "HOME_POSITION"):
        assert counts.get(name, 0) > 0, (name, counts)


def test_parameters_are_read_and_written_in_the_autopilots_encoding(flight):
    _, autopilot, client = flight
    r = client.ok("get_param MPC_XY_VEL_MAX")
    assert r["param"] == {"MPC_XY_VEL_MAX": FLOAT_PARAMS["MPC_XY_VEL_MAX"]}
    assert r["info"]["type"] == "REAL32"
    assert client.ok("get_param COM_RC_LOSS_T")["param"] == {"COM_RC_LOSS_T": -7}
    r = client.ok("set_param MPC_XY_VEL_MAX:8.5")
    assert r["param"] == {"MPC_XY_VEL_MAX": 8.5}
    assert autopilot.param_float("MPC_XY_VEL_MAX") == 8.5
    r = client.ok("set_param SYS_AUTOSTART:4002")
    assert r["param"] == {"SYS_AUTOSTART": 4002} and r["info"]["type"] == "INT32"
    assert autopilot.param_int("SYS_AUTOSTART") == 4002
    bad = client.cmd("set_param SYS_AUTOSTART:1.5")
    assert bad["ret"] == -2 and "expects an integer (INT32)" in bad["msg"], bad
    everything = client.ok("param")["param"]
    assert everything == {"MPC_XY_VEL_MAX": 8.5, "MIS_TAKEOFF_ALT": 2.5, "SYS_AUTOSTART": 4002,
                          "COM_RC_LOSS_T": -7}
    long_name = client.cmd("get_param ABCDEFGHIJKLMNOPQ")
    assert long_name["ret"] == -2, long_name


def test_flight_commands_on_the_ground_are_refused(flight):
    _, _, client = flight
    r = client.cmd("land")
    assert (r["ret"], r["msg"]) == (-1, "Vehicle is not flying")
    r = client.cmd("set_sp_ned 1:1:-2:0")
    assert (r["ret"], r["msg"]) == (-1, "Vehicle is not flying")
    r = client.cmd("sleep")
    assert (r["ret"], r["msg"]) == (-2, "Invalid arguments: not supported by this vehicle")


def test_takeoff_arms_and_climbs(flight):
    _, autopilot, client = flight
    r = client.ok("takeoff")
    assert r["target_alt"] == 2.5
    # MAVSDK may call back after its COMMAND_ACK went out: wait for it.
    arm = wait_for("ARM seen", lambda: autopilot.commands_named(MAV_CMD_COMPONENT_ARM_DISARM))
    assert arm[-1]["param1"] == 1.0
    takeoff = wait_for("NAV_TAKEOFF seen", lambda: autopilot.commands_named(MAV_CMD_NAV_TAKEOFF))
    assert takeoff[-1]["param7"] == pytest.approx(HOME[2] + 2.5)
    state = wait_for("hovering at 2.5 m",
                     lambda: (s := client.state())["fsm"] == "hover" and s)
    assert state["armed"] is True
    assert state["altitude"] == pytest.approx(2.5, abs=0.15)
    # The autopilot's hold after the takeoff is lluavd's doing, no failsafe.
    state = wait_for("the hold after the climb", lambda: (s := client.state())["mode"] == "AUTO.LOITER" and s)
    assert state["failsafe"] is None


def test_the_armed_gate_reads_the_heartbeat(flight):
    _, _, client = flight
    r = client.cmd("set_param MPC_XY_VEL_MAX:5")
    assert (r["ret"], r["msg"]) == (-1, "Not allow when vehicle is ARMED!")


def test_setpoints_are_streamed_and_followed(flight):
    _, autopilot, client = flight
    r = client.ok("set_sp_ned 3:2:-4:0.5")
    assert r["sp"] == {"x": 3.0, "y": 2.0, "z": -4.0, "yaw": 0.5}
    wait_for("DO_SET_MODE OFFBOARD seen", lambda: [
        c for c in autopilot.commands_named(MAV_CMD_DO_SET_MODE) if c["param2"] == 6.0])
    start = time.monotonic()
    time.sleep(2.0)
    with autopilot.lock:
        recent = [t for t, _ in autopilot.setpoints if t >= start]
        last = autopilot.setpoints[-1][1]
    assert len(recent) >= 4, f"{len(recent)} setpoints in 2 s: below 2 Hz"
    assert (last["x"], last["y"], last["z"], last["yaw"]) == (3.0, 2.0, -4.0, 0.5)
    assert last["coordinate_frame"] == 1  # MAV_FRAME_LOCAL_NED
    state = wait_for("the vehicle at the setpoint", lambda: (s := client.state())
                     and math.dist([s["position"][k] for k in "xyz"], [3, 2, -4]) < 0.2 and s)
    assert state["mode"] == "OFFBOARD"
    assert state["setpoint"] == {"x": 3.0, "y": 2.0, "z": -4.0, "yaw": 0.5}


def test_streaming_stops_when_the_client_that_set_it_leaves(flight):
    daemon, autopilot, client = flight
    other = daemon.client()
    # One session flies at a time: the second takes over first.
    other.ok("control_take")
    other.ok("set_sp_ned 3:2:-5:0.5")
    client.close()  # set the first setpoint: gone too
    daemon.clients.remove(client)
    other.close()
    daemon.clients.remove(other)

    def quiet_for_a_while():
        # The stream stops once lluavd has seen both sessions end: wait
        # for a window of 1.5 s (three periods of the slowest stream)
        # without one, however long noticing takes on a loaded machine.
        with autopilot.lock:
            count = len(autopilot.setpoints)
        time.sleep(1.5)
        with autopilot.lock:
            return len(autopilot.setpoints) == count

    wait_for("setpoints no longer streamed", quiet_for_a_while, every=0)
    fresh = daemon.client()
    assert fresh.state()["setpoint"] is None


def _client(daemon):
    return daemon.clients[-1] if daemon.clients else daemon.client()


def test_a_mission_is_uploaded_with_global_coordinates(flight):
    daemon, autopilot, _ = flight
    client = _client(daemon)
    mission = '{"waypoints":[{"x":10,"y":0,"z":-5},{"id":7,"x":10,"y":10,"z":-6,"yaw":1.5707964}]}'
    r = client.ok(f"mission 42:{mission}")
    assert (r["ext_id"], r["waypoints"]) == (42, 2)
    items = wait_for("the mission on the autopilot", lambda: autopilot.missions and autopilot.missions[-1])
    assert len(items) == 2
    for item, (n, e, up) in zip(items, [(10, 0, 5), (10, 10, 6)]):
        lat, lon, _ = geo.global_from(HOME, n, e, 0)
        assert abs(item.x - lat * 1e7) <= 1 and abs(item.y - lon * 1e7) <= 1, (item.x, item.y)
        assert item.z == up and item.frame == 6 and item.command == 16
    assert items[1].param4 == pytest.approx(90.0, abs=1e-4)
    listed = client.ok("mw_list")
    assert [w["id"] for w in listed["waypoints"]] == [1, 7]


def _mission(events):
    return [(e["status"], e.get("wp"), e.get("index"), e.get("count"))
            for e in events if e["event"] == "mission"]


def test_mw_exec_flies_the_waypoints_and_reports_progress(flight):
    daemon, autopilot, _ = flight
    client = _client(daemon)
    events = daemon.events()
    r = client.ok("mw_exec 42:1,7")
    assert r["wp_ids"] == [1, 7]
    run = wait_for("the run completed",
                   lambda: (m := client.state()["mission"]) and m["status"] == "completed" and m,
                   timeout=40)
    assert run["reached"] == [1, 7]
    p = autopilot.position()
    assert math.dist(p, [10, 10, -6]) < 0.2, p
    # Nor is the hold at the mission's end.
    state = wait_for("the hold at the end", lambda: (s := client.state())["mode"] == "AUTO.LOITER" and s)
    assert state["failsafe"] is None
    result = client.ok("dump_missionresult 42")["result"]
    assert result["status"] == "completed"
    # The same progress as events, from the autopilot's MISSION_ITEM_REACHED,
    # in order and once each (MAVSDK, like PX4, also sends MISSION_CURRENT).
    seen = events.until("the run told completed", lambda s: ("completed", None, None, None) in _mission(s))
    assert _mission(seen) == [("started", None, None, None), ("reached", 1, 1, 2),
                              ("reached", 7, 2, 2), ("completed", None, None, None)]
    seqs = [e["seq"] for e in seen]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), seqs
    assert any(e["event"] == "fsm" and e["to"] == "mission" for e in seen), seen
    # The hold at the mission's end is the FSM's, not the run's: nothing more.
    assert _mission(events.until("the hold told", lambda s: any(
        e["event"] == "fsm" and e["from"] == "mission" for e in s))) == _mission(seen)


def test_land_then_disarm(flight):
    daemon, autopilot, _ = flight
    client = _client(daemon)
    client.ok("land")
    wait_for("NAV_LAND seen", lambda: autopilot.commands_named(MAV_CMD_NAV_LAND))
    wait_for("landed", lambda: client.state()["landed"] in ("on_ground",), timeout=30)
    client.ok("disarm")
    disarms = wait_for("DISARM seen", lambda: [
        c for c in autopilot.commands_named(MAV_CMD_COMPONENT_ARM_DISARM) if c["param1"] == 0.0])
    assert disarms[-1]["param2"] == FORCE_DISARM
    wait_for("disarmed in the heartbeat", lambda: client.state()["armed"] is False)


def test_a_lost_link_is_reported_and_flight_commands_answer_minus_3(flight):
    daemon, autopilot, _ = flight
    client = _client(daemon)
    autopilot.go_silent()
    state = wait_for("link lost", lambda: (s := client.state())["link"] == "lost" and s, timeout=15)
    assert state["heartbeat_age_ms"] >= 3000
    r = client.cmd("takeoff")
    assert r["ret"] == -3 and r["msg"].startswith("MAVLink link lost: no heartbeat"), r
    r = client.cmd("get_param MPC_XY_VEL_MAX")
    assert r["ret"] == -3, r
