"""MAVLink 2 message signing (`--mavlink-signing-key FILE`, 32 bytes in
hex): a pymavlink autopilot that signs with the same key is flown and
everything lluavd sends it carries a good signature; an autopilot that
signs with another key, or not at all, is never followed."""

import pytest

from conftest import stays, wait_for
from fault_autopilot import FaultyAutopilot, mav

KEY = bytes(range(1, 33))
OTHER_KEY = bytes(range(101, 133))


@pytest.fixture
def signed(daemon_factory, udp_port, tmp_path):
    """make(autopilot_key) -> (daemon, autopilot, client), lluavd holding KEY."""
    key_file = tmp_path / "mavlink.key"
    key_file.write_text(KEY.hex() + "\n")
    made = []

    def make(autopilot_key):
        daemon = daemon_factory(udp_port, extra=("--mavlink-signing-key", str(key_file)))
        ap = FaultyAutopilot(udp_port, signing_key=autopilot_key)
        made.append(ap)
        return daemon, ap, daemon.client()

    yield make
    for ap in made:
        ap.close()


def test_an_autopilot_signing_with_the_same_key_is_flown_and_everything_it_gets_is_signed(signed):
    _, ap, client = signed(KEY)
    wait_for("link up with home", lambda: (s := client.state())["link"] == "up" and s["home_global"])
    assert client.ok("takeoff")["fsm"] == "takeoff"
    assert [c.param1 for c in ap.commands(mav.MAV_CMD_COMPONENT_ARM_DISARM)] == [1.0]
    assert ap.commands(mav.MAV_CMD_NAV_TAKEOFF)
    with ap.lock:
        unsigned = {m.get_type() for _, m in ap.received if not m.get_signed()}
    assert unsigned == set(), f"lluavd sent these unsigned or wrongly signed: {unsigned}"


@pytest.mark.parametrize("autopilot_key", [OTHER_KEY, None], ids=["another key", "unsigned"])
def test_an_autopilot_without_the_key_is_never_followed(signed, autopilot_key):
    _, ap, client = signed(autopilot_key)
    stays("the link never comes up", lambda: (s := client.state())["link"] == "lost"
          and s["autopilot"] is None, 4.0)
    assert client.cmd("takeoff")["ret"] == -3
    assert ap.commands(mav.MAV_CMD_COMPONENT_ARM_DISARM) == []
    with ap.lock:
        good = {m.get_type() for _, m in ap.received if m.get_signed()}
    assert good == set()
