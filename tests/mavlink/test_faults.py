"""What lluavd does when the autopilot misbehaves: a pymavlink autopilot
that delays, refuses or never sends acknowledgements, loses mission items
or dies in the middle of an upload. One daemon and one autopilot each."""

import struct
import threading
import time

import pytest

import geo
from conftest import wait_for
from fault_autopilot import HOME, FaultyAutopilot, mav

ARM = mav.MAV_CMD_COMPONENT_ARM_DISARM
TAKEOFF = mav.MAV_CMD_NAV_TAKEOFF
MISSION = '{"waypoints":[{"x":5,"y":0,"z":-3},{"x":5,"y":5,"z":-3},{"x":0,"y":5,"z":-4}]}'


def test_a_late_ack_is_waited_for_across_a_resend(vehicle):
    _, ap, client = vehicle()
    ap.ack_delay[ARM] = 2.0  # past the first 1.5 s wait
    r = client.ok("takeoff")
    assert r["fsm"] == "takeoff"
    assert [c.confirmation for c in ap.commands(ARM)][:2] == [0, 1]
    takeoff = ap.commands(TAKEOFF)
    assert takeoff and takeoff[0].param7 == pytest.approx(HOME[2] + 2.5)


def test_a_refused_command_answers_minus_1_with_the_result_name(vehicle):
    _, ap, client = vehicle()
    ap.ack_result[ARM] = mav.MAV_RESULT_DENIED
    r = client.cmd("takeoff")
    assert r == {**r, "ret": -1,
                 "msg": "MAV_CMD_COMPONENT_ARM_DISARM refused by the autopilot: MAV_RESULT_DENIED"}
    assert len(ap.commands(ARM)) == 1


def test_a_refused_takeoff_disarms_again(vehicle):
    _, ap, client = vehicle()
    ap.ack_result[TAKEOFF] = mav.MAV_RESULT_TEMPORARILY_REJECTED
    r = client.cmd("takeoff")
    assert r["ret"] == -1 and r["msg"].endswith("MAV_RESULT_TEMPORARILY_REJECTED"), r
    assert [c.param1 for c in ap.commands(ARM)] == [1.0, 0.0]
    wait_for("disarmed again", lambda: client.state()["armed"] is False)


def test_no_ack_answers_minus_3_and_other_sessions_are_served_meanwhile(vehicle):
    daemon, ap, client = vehicle()
    ap.ack_result[ARM] = None
    answer = {}
    waiting = threading.Thread(target=lambda: answer.update(client.cmd("takeoff")))
    waiting.start()
    other = daemon.client()
    slowest = 0.0
    while waiting.is_alive():
        start = time.monotonic()
        assert other.state()["link"] == "up"
        slowest = max(slowest, time.monotonic() - start)
        time.sleep(0.1)
    waiting.join()
    assert answer["ret"] == -3
    assert answer["msg"] == ("No answer from the autopilot: "
                             "no COMMAND_ACK for MAV_CMD_COMPONENT_ARM_DISARM after 3 attempts")
    assert [c.confirmation for c in ap.commands(ARM)] == [0, 1, 2]
    # Bounded generously (a shared, noisy machine): far below the 4.5 s wait.
    assert slowest < 1.0, slowest


def test_a_lost_mission_item_is_sent_again(vehicle):
    _, ap, client = vehicle()
    ap.drop_item_once = {1}
    r = client.ok(f"mission 3:{MISSION}")
    assert (r["ext_id"], r["waypoints"]) == (3, 3)
    assert [m.seq for m in ap.messages("MISSION_ITEM_INT")] == [0, 1, 1, 2]
    assert len(ap.mission) == 3
    lat, lon, _ = geo.global_from(HOME, 5, 5, 0)
    second = ap.mission[1]
    assert abs(second.x - lat * 1e7) <= 1 and abs(second.y - lon * 1e7) <= 1


def test_a_link_that_dies_mid_upload_answers_minus_3(vehicle):
    _, ap, client = vehicle()
    ap.die_after_item = 1
    r = client.cmd(f"mission 3:{MISSION}")
    assert r["ret"] == -3, r
    assert r["msg"].startswith("No answer from the autopilot: mission upload stalled after mission item"), r
    wait_for("link lost", lambda: client.state()["link"] == "lost", timeout=15)
    assert client.cmd("mw_exec 3:1")["ret"] == -2  # never accepted: an unknown mission


def test_a_mission_the_autopilot_refuses_is_invalid_arguments(vehicle):
    _, ap, client = vehicle()
    ap.mission_result = mav.MAV_MISSION_NO_SPACE
    r = client.cmd(f"mission 3:{MISSION}")
    assert r["ret"] == -2, r
    assert r["msg"] == "Invalid arguments: the autopilot refused the mission: MAV_MISSION_NO_SPACE"


def test_ardupilot_takes_off_in_guided_relative_to_home(vehicle):
    _, ap, client = vehicle(mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    client.ok("takeoff")
    modes = ap.commands(mav.MAV_CMD_DO_SET_MODE)
    assert modes and (modes[0].param1, modes[0].param2) == (1.0, 4.0)  # GUIDED
    takeoff = ap.commands(TAKEOFF)
    assert takeoff[0].param7 == 2.5
    order = [m.command for m in ap.messages("COMMAND_LONG")
             if m.command in (mav.MAV_CMD_DO_SET_MODE, ARM, TAKEOFF)]
    assert order == [mav.MAV_CMD_DO_SET_MODE, ARM, TAKEOFF]
    assert wait_for("mode GUIDED", lambda: client.state()["mode"] == "GUIDED")


def test_ardupilot_missions_keep_home_in_item_zero(vehicle):
    _, ap, client = vehicle(mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    client.ok('mission 1:{"waypoints":[{"x":0,"y":10,"z":-2}]}')
    assert len(ap.mission) == 2
    assert (ap.mission[0].x, ap.mission[0].y) == (int(HOME[0] * 1e7), int(HOME[1] * 1e7))
    lat, lon, _ = geo.global_from(HOME, 0, 10, 0)
    assert abs(ap.mission[1].x - lat * 1e7) <= 1 and abs(ap.mission[1].y - lon * 1e7) <= 1
    assert ap.mission[1].z == 2.0


def test_ardupilot_integer_parameters_travel_as_cast_floats(vehicle):
    _, ap, client = vehicle(mav.MAV_AUTOPILOT_ARDUPILOTMEGA)
    ap.params["FRAME_CLASS"] = (1.0, mav.MAV_PARAM_TYPE_INT8)
    ap.params["WPNAV_SPEED"] = (500.0, mav.MAV_PARAM_TYPE_REAL32)
    assert client.ok("get_param FRAME_CLASS")["param"] == {"FRAME_CLASS": 1}
    client.ok("set_param FRAME_CLASS:2")
    assert ap.params["FRAME_CLASS"] == (2.0, mav.MAV_PARAM_TYPE_INT8)
    client.ok("set_param WPNAV_SPEED:750.5")
    assert ap.params["WPNAV_SPEED"][0] == 750.5


def test_px4_integer_parameters_travel_bytewise(vehicle):
    _, ap, client = vehicle()
    bits = struct.unpack("<f", struct.pack("<i", -3))[0]
    ap.params["NAV_RCL_ACT"] = (bits, mav.MAV_PARAM_TYPE_INT32)
    assert client.ok("get_param NAV_RCL_ACT")["param"] == {"NAV_RCL_ACT": -3}
    client.ok("set_param NAV_RCL_ACT:70000")
    raw = ap.params["NAV_RCL_ACT"][0]
    assert struct.unpack("<i", struct.pack("<f", raw))[0] == 70000


def test_an_unknown_parameter_is_minus_3_after_the_retries(vehicle):
    _, _, client = vehicle()
    r = client.cmd("get_param NO_SUCH_PARAM")
    assert r["ret"] == -3 and "no PARAM_VALUE for NO_SUCH_PARAM after 3 requests" in r["msg"], r
