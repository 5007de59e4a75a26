"""Once `takeoff` answers 0 the vehicle counts as flying before the
telemetry shows the climb, and no longer once it cannot be: after a
heartbeat that says disarmed, or a `land` or `disarm` answered 0. The
pymavlink autopilot acknowledges the takeoff but never reports a landed
state, so lluavd's word is all that says it flies; what reached the
autopilot is checked, not only lluavd's answers."""

import pytest

from conftest import stays, wait_for
from fault_autopilot import mav

SETPOINT = "SET_POSITION_TARGET_LOCAL_NED"


def autopilot_disarms(ap, client):
    # The autopilot disarms on its own (a failed climb, a pilot's switch),
    # once lluavd has seen it armed.
    wait_for("the armed heartbeat", lambda: client.state()["armed"] is True)
    ap.armed = False
    wait_for("the disarmed heartbeat", lambda: client.state()["armed"] is False)


ENDINGS = {
    "land": lambda ap, client: client.ok("land"),
    "disarm": lambda ap, client: client.ok("disarm"),
    "the autopilot disarms": autopilot_disarms,
}


@pytest.mark.parametrize("ending", list(ENDINGS))
def test_a_takeoff_that_ended_no_longer_counts_as_flying(vehicle, ending):
    _, ap, client = vehicle()
    assert client.ok("takeoff")["fsm"] == "takeoff"
    state = client.state()
    assert (state["fsm"], state["airborne"]) == ("takeoff", True), state
    ENDINGS[ending](ap, client)
    r = client.cmd("set_sp_ned 1:0:-3:0")
    stays("no setpoint at the autopilot", lambda: ap.messages(SETPOINT) == [], 1.5)
    assert (r["ret"], r["msg"]) == (-1, "Vehicle is not flying"), r
    state = client.state()
    assert state["fsm"] != "takeoff" and state["airborne"] is False, state
    assert ap.commands(mav.MAV_CMD_DO_SET_MODE) == [], "switched to offboard after the takeoff ended"
