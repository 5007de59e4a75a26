"""Flight authority over MAVLink (DESIGN.md, "Flight authority"): the
autopilot's own failsafes and a pilot taking over win over lluavd's
clients, and lluavd's envelope binds every target it gives the autopilot.

The pymavlink autopilot flies as far as its reports go: it enters the
modes a flying PX4 or ArduPilot enters on lluavd's commands (FLIGHT_MODES)
and reports itself in the air once it took off; a test switches its mode
or status as the autopilot or a pilot on the RC would. What reached the
autopilot is checked, not only lluavd's answers."""

import time

import pytest

import geo
from conftest import stays, wait_for
from fault_autopilot import COPTER, FLIGHT_MODES, HOME, PX4, mav

APM = mav.MAV_AUTOPILOT_ARDUPILOTMEGA
PX4_AP = mav.MAV_AUTOPILOT_PX4
IN_AIR = mav.MAV_LANDED_STATE_IN_AIR
SET_MODE = mav.MAV_CMD_DO_SET_MODE
SETPOINT = "SET_POSITION_TARGET_LOCAL_NED"
# DO_SET_MODE's params 1-3 for the mode that follows setpoints, and its name.
GUIDED = {PX4_AP: ((1.0, 6.0, 0.0), "OFFBOARD"), APM: ((1.0, 4.0, 0.0), "GUIDED")}
NAMES = {PX4_AP: "px4", APM: "ardupilot"}
MOTION = "Vehicle is in failsafe ({}): land, rtl or control_take failsafe"


def flying(vehicle, autopilot=PX4_AP, extra=(), **reports):
    """A vehicle that flies as `autopilot` would, taken off and holding
    in the air: PX4 in AUTO.TAKEOFF, then its hold (AUTO.LOITER);
    ArduPilot in GUIDED throughout."""
    daemon, ap, client = vehicle(autopilot, extra=extra, mode_on=FLIGHT_MODES[autopilot], **reports)
    took_off = client.ok("takeoff")
    if autopilot == PX4_AP:
        wait_for("the takeoff mode", lambda: client.state()["mode"] == "AUTO.TAKEOFF")
        ap.switch(custom_mode=PX4["AUTO.LOITER"], landed_state=IN_AIR)
    else:
        ap.switch(landed_state=IN_AIR)
    wait_for("hovering", lambda: client.state()["fsm"] == "hover")
    return daemon, ap, client, took_off


def follow_setpoints(ap, client, autopilot, sp="2:0:-3:0"):
    """set_sp_ned, and waits for the autopilot to follow it."""
    client.ok(f"set_sp_ned {sp}")
    wait_for("following the setpoint", lambda: client.state()["mode"] == GUIDED[autopilot][1])
    wait_for("setpoints streamed", lambda: ap.messages(SETPOINT))


def guided_modes(ap, autopilot, since):
    """The DO_SET_MODEs into the setpoint mode the autopilot got since `since`."""
    return [c for c in ap.commands(SET_MODE, since) if (c.param1, c.param2, c.param3) == GUIDED[autopilot][0]]


def stream_stopped(ap):
    """Waits for a window of 1 s without a setpoint at the autopilot
    (however long lluavd takes to notice on a loaded machine), then checks
    none comes for 1.5 s more."""
    def quiet_for_a_second():
        before = len(ap.messages(SETPOINT))
        time.sleep(1.0)
        return len(ap.messages(SETPOINT)) == before

    wait_for("setpoints no longer streamed", quiet_for_a_second, every=0)
    count = len(ap.messages(SETPOINT))
    stays("no setpoint streamed", lambda: len(ap.messages(SETPOINT)) == count, 1.5)


FAILSAFES = {
    "px4-return": (PX4_AP, PX4["AUTO.RTL"], "autopilot: AUTO.RTL"),
    "px4-pilot": (PX4_AP, PX4["POSCTL"], "external: POSCTL"),
    "ardupilot-return": (APM, COPTER["RTL"], "autopilot: RTL"),
    "ardupilot-pilot": (APM, COPTER["LOITER"], "external: LOITER"),
}


@pytest.mark.parametrize("case", list(FAILSAFES))
def test_a_mode_nobody_asked_for_while_streaming_is_a_failsafe_lluavd_never_leaves_alone(vehicle, case):
    autopilot, mode, reason = FAILSAFES[case]
    _, ap, client, _ = flying(vehicle, autopilot)
    follow_setpoints(ap, client, autopilot)
    assert client.state()["failsafe"] is None

    switched = ap.switch(custom_mode=mode)
    state = wait_for(reason, lambda: (s := client.state())["failsafe"] == reason and s)
    assert state["setpoint"] is None, state
    stream_stopped(ap)
    r = client.cmd("set_sp_ned 3:0:-3:0")
    assert (r["ret"], r["msg"]) == (-1, MOTION.format(reason)), r
    r = client.cmd("control_take")
    assert (r["ret"], r["msg"]) == (-1, f"Vehicle is in failsafe ({reason}): control_take failsafe overrides it")
    # A conservative command still runs, and does not end the failsafe.
    client.ok("land")
    assert ap.commands(mav.MAV_CMD_NAV_LAND, switched)
    assert client.state()["failsafe"] == reason
    assert ap.commands(SET_MODE, switched) == [], "lluavd switched the autopilot out of the failsafe"

    client.ok("control_take failsafe")
    assert client.state()["failsafe"] == f"{reason} (overridden)"
    overridden = ap.switch()
    client.ok("set_sp_ned 3:0:-3:0")
    wait_for("the setpoint mode asked for", lambda: guided_modes(ap, autopilot, overridden))
    wait_for("following the setpoint again", lambda: client.state()["mode"] == GUIDED[autopilot][1])
    assert client.state()["failsafe"] == f"{reason} (overridden)"


@pytest.mark.parametrize("autopilot", [PX4_AP, APM], ids=NAMES.get)
def test_a_landing_failsafe_refuses_the_return_and_ends_disarmed(vehicle, autopilot):
    _, ap, client, _ = flying(vehicle, autopilot)
    landing = PX4["AUTO.LAND"] if autopilot == PX4_AP else COPTER["LAND"]
    reason = "autopilot: AUTO.LAND" if autopilot == PX4_AP else "autopilot: LAND"
    switched = ap.switch(custom_mode=landing)
    wait_for(reason, lambda: client.state()["failsafe"] == reason)
    for cmd in ("rtl", "mrtl"):
        r = client.cmd(cmd)
        assert (r["ret"], r["msg"]) == (
            -1, f"Vehicle is in failsafe ({reason}): land, tether_land, disarm or control_take failsafe"), r
    client.ok("land")
    client.ok("disarm")
    wait_for("the failsafe over once disarmed", lambda: client.state()["failsafe"] is None)
    assert ap.commands(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH) == [] and ap.commands(SET_MODE, switched) == []


FIRST_SIGHT = {
    "px4-return": (PX4_AP, PX4["AUTO.RTL"], "autopilot: AUTO.RTL"),
    "ardupilot-landing": (APM, COPTER["LAND"], "autopilot: LAND"),
    "px4-pilot": (PX4_AP, PX4["POSCTL"], "external: POSCTL"),
}


@pytest.mark.parametrize("case", list(FIRST_SIGHT))
def test_an_autopilot_already_returning_or_flown_when_first_seen_is_in_failsafe(vehicle, case):
    autopilot, mode, reason = FIRST_SIGHT[case]
    _, ap, client = vehicle(autopilot, armed=True, custom_mode=mode, landed_state=IN_AIR)
    wait_for(reason, lambda: client.state()["failsafe"] == reason)
    for cmd in ("set_sp_ned 1:0:-3:0", "mw_exec 1:1"):
        r = client.cmd(cmd)
        assert (r["ret"], r["msg"]) == (-1, MOTION.format(reason)), (cmd, r)
    assert ap.commands(SET_MODE) == [] and ap.commands(mav.MAV_CMD_MISSION_START) == []
    assert ap.messages(SETPOINT) == []


def test_a_critical_status_is_a_failsafe_and_the_autopilots_return_then_another(vehicle):
    _, ap, client, _ = flying(vehicle)
    follow_setpoints(ap, client, PX4_AP)
    critical = ap.switch(system_status=mav.MAV_STATE_CRITICAL)
    state = wait_for("CRITICAL", lambda: (s := client.state())["failsafe"] == "autopilot: CRITICAL" and s)
    # The status alone changes nothing of the flight: the setpoint still
    # streams, and the autopilot still follows it.
    assert state["setpoint"] == {"x": 2.0, "y": 0.0, "z": -3.0, "yaw": 0.0}, state
    wait_for("a setpoint after the status", lambda: ap.messages(SETPOINT, critical + 0.5))
    r = client.cmd("set_sp_ned 3:0:-3:0")
    assert (r["ret"], r["msg"]) == (-1, MOTION.format("autopilot: CRITICAL")), r
    # Then the autopilot returns on its own: a new, different reason.
    ap.switch(custom_mode=PX4["AUTO.RTL"])
    state = wait_for("its return", lambda: (s := client.state())["failsafe"] == "autopilot: AUTO.RTL" and s)
    assert state["setpoint"] is None, state
    stream_stopped(ap)
    assert ap.commands(SET_MODE, critical) == []
    client.ok("disarm")
    wait_for("over once disarmed", lambda: client.state()["failsafe"] is None)


@pytest.mark.parametrize("autopilot", [PX4_AP, APM], ids=NAMES.get)
def test_the_hold_after_a_takeoff_is_not_a_failsafe(vehicle, autopilot):
    _, ap, client, _ = flying(vehicle, autopilot)
    hold = "AUTO.LOITER" if autopilot == PX4_AP else "GUIDED"
    assert client.state()["mode"] == hold
    stays("no failsafe in the hold", lambda: client.state()["failsafe"] is None, 1.5)
    since = ap.switch()
    follow_setpoints(ap, client, autopilot)
    if autopilot == PX4_AP:
        assert guided_modes(ap, autopilot, since), "OFFBOARD asked for out of the hold"


def test_the_hold_at_a_missions_end_is_not_a_failsafe(vehicle):
    _, ap, client, _ = flying(vehicle)
    client.ok('mission 5:{"waypoints":[{"x":3,"y":0,"z":-3}]}')
    client.ok("mw_exec 5:1")
    wait_for("flying the mission", lambda: client.state()["fsm"] == "mission")
    ap.switch(custom_mode=PX4["AUTO.LOITER"])
    wait_for("the hold at its end", lambda: client.state()["mode"] == "AUTO.LOITER")
    stays("no failsafe in the hold", lambda: client.state()["failsafe"] is None, 1.5)
    since = ap.switch()
    follow_setpoints(ap, client, PX4_AP)
    assert guided_modes(ap, PX4_AP, since)


# A small envelope: targets 0.5 to 3 m above home and 10 m from it; the
# takeoff altitude (5 m) above it.
ENVELOPE = ("--max-alt", "3", "--geofence-radius", "10", "--takeoff-alt", "5")
INSIDE = ["0:0:-3:0", "0:0:-0.5:0", "10:0:-1:0", "6:-8:-2:0", "0:-10:-3:0"]
# (A setpoint at z 0 or below is refused by the request's grammar first.)
OUTSIDE = {
    "0:0:-3.1:0": "altitude 3.1 m above max_alt 3 m",
    "0:0:-0.4:0": "altitude 0.4 m below min_alt 0.5 m",
    "0:0:-0.0001:0": "altitude 0.0001 m below min_alt 0.5 m",
    "10.5:0:-1:0": "distance from home 10.5 m beyond geofence_radius 10 m",
    "6:-8.5:-2:0": "distance from home 10.5 m beyond geofence_radius 10 m",
}


@pytest.mark.parametrize("autopilot", [PX4_AP, APM], ids=NAMES.get)
def test_takeoff_climbs_to_the_takeoff_altitude_clipped_into_the_envelope(vehicle, autopilot):
    _, ap, client, took_off = flying(vehicle, autopilot, extra=ENVELOPE)
    assert took_off["target_alt"] == 3.0, took_off
    # PX4 takes the altitude above mean sea level, ArduPilot above home.
    expected = HOME[2] + 3.0 if autopilot == PX4_AP else 3.0
    assert ap.commands(mav.MAV_CMD_NAV_TAKEOFF)[0].param7 == pytest.approx(expected)


def test_setpoints_and_waypoints_are_checked_against_the_envelope(vehicle):
    _, ap, client, _ = flying(vehicle, extra=ENVELOPE)
    for sp in INSIDE:
        client.ok(f"set_sp_ned {sp}")
    x, y, z, _ = (float(v) for v in INSIDE[-1].split(":"))
    wait_for("the last one inside streamed", lambda: (m := ap.messages(SETPOINT)) and (m[-1].x, m[-1].y, m[-1].z)
             == (x, y, z))
    for sp, why in OUTSIDE.items():
        r = client.cmd(f"set_sp_ned {sp}")
        assert (r["ret"], r["msg"]) == (-2, f"Invalid arguments: {why}"), (sp, r)
    assert client.state()["setpoint"] == {"x": x, "y": y, "z": z, "yaw": 0.0}

    on_limits = ",".join('{"x":%s,"y":%s,"z":%s}' % tuple(p.split(":")[:3]) for p in INSIDE)
    client.ok(f'mission 1:{{"waypoints":[{on_limits}]}}')
    assert len(ap.mission) == len(INSIDE)
    uploads = len(ap.messages("MISSION_COUNT"))
    for sp, why in {**OUTSIDE, "0:0:0:0": "altitude 0 m below min_alt 0.5 m",
                    "0:0:1:0": "altitude -1 m below min_alt 0.5 m"}.items():
        x, y, z = sp.split(":")[:3]
        r = client.cmd(f'mission 2:{{"waypoints":[{{"x":0,"y":0,"z":-2}},{{"x":{x},"y":{y},"z":{z}}}]}}')
        assert (r["ret"], r["msg"]) == (-2, f"Invalid arguments: waypoint 2: {why}"), (sp, r)
    assert len(ap.messages("MISSION_COUNT")) == uploads, "a mission outside the envelope was uploaded"


def test_mw_exec_checks_the_waypoints_again_against_home_now(vehicle):
    _, ap, client, _ = flying(vehicle, extra=ENVELOPE)
    client.ok('mission 3:{"waypoints":[{"x":0,"y":0,"z":-2},{"id":7,"x":9,"y":0,"z":-2}]}')
    # Home moves 5 m south (PX4 sets it at every arming; a ground station
    # may move it): waypoint 7 is now 14 m from home.
    ap.home, ap.home_local = geo.global_from(HOME, -5, 0, 0), (-5.0, 0.0, 0.0)
    wait_for("the new home", lambda: client.state()["home"] == {"x": -5.0, "y": 0.0, "z": 0.0})
    since = ap.switch()
    r = client.cmd("mw_exec 3:1,7")
    assert (r["ret"], r["msg"]) == (
        -2, "Invalid arguments: waypoint 7: distance from home 14 m beyond geofence_radius 10 m"), r
    assert ap.commands(mav.MAV_CMD_MISSION_START, since) == []
    client.ok("mw_exec 3:1")
    wait_for("the mission started", lambda: ap.commands(mav.MAV_CMD_MISSION_START, since))


RETURN_ALT = {
    "px4": (PX4_AP, {"RTL_RETURN_ALT": (30.0, mav.MAV_PARAM_TYPE_REAL32)}, 30.0),
    "ardupilot": (APM, {"RTL_ALT": (1500.0, mav.MAV_PARAM_TYPE_INT16)}, 15.0),
    "unknown": (PX4_AP, {}, None),
}


@pytest.mark.parametrize("case", list(RETURN_ALT))
def test_rtl_answers_the_autopilots_own_return_altitude(vehicle, case):
    autopilot, params, alt = RETURN_ALT[case]
    daemon, ap, client, _ = flying(vehicle, autopilot, extra=ENVELOPE, params=params)
    if params:
        # lluavd reads it when the link comes up.
        wait_for("the RTL altitude read", lambda: client.ok("mavlink_msgs")["mav_msgs"].get("PARAM_VALUE"))
    r = client.ok("rtl")
    assert (r["return_alt"], r["home"]) == (alt, {"x": 0.0, "y": 0.0, "z": 0.0}), r
    assert ap.commands(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH)
    wait_for("returning", lambda: client.state()["mode"] in ("AUTO.RTL", "RTL"))
    assert client.state()["failsafe"] is None, "lluavd's own return is no failsafe"
    if alt is not None:
        # Above max_alt 3 m: lluavd cannot clip it, and says so.
        wait_for("the warning in the log", lambda: "the autopilot's RTL climbs above max_alt" in log_text(daemon))


def log_text(daemon):
    with open(daemon.log.name) as f:
        return f.read()
