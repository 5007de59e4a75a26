"""An autopilot killed and replaced in the middle of a flight: rebooted
behind the same address (a flight controller behind a radio), replaced
on another address with the same system id, or by another system id.
A different or rebooted autopilot is a new vehicle: lluavd follows it,
streams it no setpoint until a client sends one, and never flies a
mission it did not give it."""

import pytest

from conftest import free_udp_port, stays, wait_for
from mavsdk_autopilot import MavsdkAutopilot
from radio import ARM_DISARM, NAV_TAKEOFF, NOT_ON_AUTOPILOT, holds, hover, setpoints_since, steer, waypoints
from relay import LossyRelay


@pytest.fixture
def autopilots():
    """Starts MAVSDK autopilots and closes whichever are still running."""
    started = []

    def start(port, system_id=1):
        ap = MavsdkAutopilot(port, system_id)
        started.append(ap)
        return ap

    yield start
    for ap in started:
        ap.close()


def fly_with_a_mission(client, ap):
    """Mission 42 uploaded, then hovering at (2, 0, -3) with a setpoint streamed."""
    wait_for("link up with home", lambda: (s := client.state())["link"] == "up" and s["home_global"])
    client.ok(f"mission 42:{waypoints(3, radius=3)}")
    holds(ap, 3)
    hover(client, ap)
    steer(client, ap, 2, 0, -3)


def a_new_vehicle(client):
    return wait_for("a new vehicle: disarmed, no setpoint",
                    lambda: (s := client.state())["link"] == "up" and not s["armed"]
                    and s["setpoint"] is None and s, timeout=15)


def check_flown_as_a_new_vehicle(client, new, system_id=1, known=0.0):
    """No setpoint reached `new` after lluavd could know it (`known`) until
    a client sent one; the flight commands reach it; mission 42 (which it
    never got) is uploaded again or refused."""
    stays("no setpoint streamed unasked", lambda: not setpoints_since(new, known), 2.0)
    hover(client, new)
    arm = new.commands_named(ARM_DISARM)[0]
    assert (arm["param1"], arm["target_system"]) == (1.0, system_id)
    assert new.commands_named(NAV_TAKEOFF)
    r = client.cmd("mw_exec 42:1,2,3")
    if r["ret"] == 0:
        holds(new, 3)
        wait_for("the mission started", lambda: new.mode == "mission")
    else:
        assert (r["ret"], r["msg"]) == (-2, NOT_ON_AUTOPILOT.format(42)), r
        assert new.mode != "mission"


def test_an_autopilot_rebooted_behind_the_same_address_is_a_new_vehicle(daemon_factory, autopilots):
    port = free_udp_port()
    daemon = daemon_factory(port)
    relay = LossyRelay(port)
    try:
        old = autopilots(relay.port)
        client = daemon.client()
        fly_with_a_mission(client, old)
        old.close()
        relay.up.keep_log = True
        new = autopilots(relay.port)
        state = a_new_vehicle(client)
        assert state["fsm"] == "disarmed"
        # Behind the same address, only its boot time tells lluavd this is
        # another autopilot: a setpoint that was already on its way before
        # the first ATTITUDE arrived is not lluavd's to hold back.
        with relay.lock:
            first = min(t for t, m in relay.up.log if m.get_type() == "ATTITUDE" and t >= new.booted)
        check_flown_as_a_new_vehicle(client, new, known=first + 0.2)
    finally:
        relay.close()


def test_an_autopilot_replaced_on_another_address_is_a_new_vehicle(daemon_factory, autopilots):
    port = free_udp_port()
    daemon = daemon_factory(port)
    old = autopilots(port)
    client = daemon.client()
    fly_with_a_mission(client, old)
    old.close()
    new = autopilots(port)
    a_new_vehicle(client)
    check_flown_as_a_new_vehicle(client, new)


def test_an_autopilot_with_another_system_id_is_followed_when_any_is_allowed(daemon_factory, autopilots):
    port = free_udp_port()
    daemon = daemon_factory(port, extra=("--mavlink-system", "any"))
    old = autopilots(port)
    client = daemon.client()
    fly_with_a_mission(client, old)
    old.close()
    new = autopilots(port, system_id=2)
    a_new_vehicle(client)
    check_flown_as_a_new_vehicle(client, new, system_id=2)


def test_an_autopilot_with_another_system_id_is_not_followed_by_default(daemon_factory, autopilots):
    port = free_udp_port()
    daemon = daemon_factory(port)
    old = autopilots(port)
    client = daemon.client()
    wait_for("link up with home", lambda: (s := client.state())["link"] == "up" and s["home_global"])
    old.close()
    other = autopilots(port, system_id=2)
    wait_for("link lost", lambda: client.state()["link"] == "lost", timeout=10)
    stays("system 2 not followed", lambda: client.state()["link"] == "lost", 2.0)
    assert client.cmd("takeoff")["ret"] == -3
    assert other.commands == [] and other.setpoints == []
