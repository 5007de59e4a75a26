"""What the autopilot says, told as events on `/events` (DESIGN.md,
"Events"): its link, arming, `STATUSTEXT`s of severity WARNING and graver
as `log`, through the real lluavd from a pymavlink autopilot. Mission
progress from a real autopilot library is in test_mavsdk_flight.py."""

from conftest import wait_for
from fault_autopilot import mav


def _named(events, name):
    return [e for e in events if e["event"] == name]


def test_statustext_of_warning_and_graver_is_told_as_log(vehicle):
    daemon, ap, _ = vehicle()
    events = daemon.events()
    for severity, text in [(mav.MAV_SEVERITY_INFO, "Takeoff detected"),
                           (mav.MAV_SEVERITY_WARNING, "Low battery"),
                           (mav.MAV_SEVERITY_CRITICAL, "PreArm: GPS not healthy")]:
        ap._send(ap.conn.mav.statustext_send, severity, text.encode())
    seen = events.until("two log events", lambda s: len(_named(s, "log")) >= 2)
    assert [(e["level"], e["msg"]) for e in _named(seen, "log")] == [
        ("warning", "autopilot: Low battery"),
        ("error", "autopilot: PreArm: GPS not healthy"),
    ]
    # Every one reaches lluavd's log (what showmsg shows), the notice too.
    client = daemon.clients[0]
    wait_for("the notice in the log",
             lambda: any("Takeoff detected" in line for line in client.ok("showmsg")["msgs"]))


def test_arming_and_the_link_are_told_as_the_heartbeat_says(vehicle):
    daemon, ap, _ = vehicle()
    events = daemon.events()
    ap.armed = True
    seen = events.until("armed", lambda s: _named(s, "armed"))
    assert _named(seen, "armed")[0]["armed"] is True
    ap.armed = False
    seen = events.until("disarmed", lambda s: len(_named(s, "armed")) >= 2)
    assert _named(seen, "armed")[1]["armed"] is False
    ap.silent.set()
    seen = events.until("the link lost", lambda s: _named(s, "link"), timeout=20)
    assert _named(seen, "link")[0]["state"] == "lost"
    ap.silent.clear()
    seen = events.until("the link back", lambda s: len(_named(s, "link")) >= 2, timeout=20)
    assert _named(seen, "link")[1]["state"] == "up"
    seqs = [e["seq"] for e in seen]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), seqs
