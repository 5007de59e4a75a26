"""The console's event log (DESIGN.md, "Events"): the page follows lluavd's
`/events` stream beside its command socket, in headless Chromium against a
real lluavd."""

from __future__ import annotations

import json
import re

from conftest import PASSWORD
from harness import Lluavd

MISSION = {"waypoints": [{"x": 5, "y": 0, "z": -3}, {"x": 5, "y": 5, "z": -3}, {"x": 0, "y": 5, "z": -3, "yaw": 1}]}
#: A label of one of this machine's WebSocket sessions, as lluavd names it.
LABEL = r"ws 127\.0\.0\.1:\d+ #\d+"


def told(page) -> list[tuple[str, str]]:
    """The log's event lines, oldest first, without the battery's and the
    log's, which come whenever the simulator says so."""
    return [(e["name"], e["text"]) for e in page.event_lines() if e["kind"] == "event" and e["name"] not in ("battery", "log")]


def matches(lines, expected) -> bool:
    """Whether `lines` are `expected` ((name, regex) pairs), in order and no more."""
    return len(lines) == len(expected) and all(
        name == want_name and re.fullmatch(pattern, text) for (name, text), (want_name, pattern) in zip(lines, expected)
    )


def logged_in(page, daemon) -> None:
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("role") == "user", "logged in")
    page.wait(lambda: page.text("events-conn") == "connected", "the event stream is open")


def test_the_event_log_tells_a_mission_flight_in_order(daemon, page):
    logged_in(page, daemon)
    assert page.event_lines() == [], "nothing happened yet"
    page.command(f"mission 1001:{json.dumps(MISSION, separators=(',', ':'))}")
    page.wait(lambda: page.log_entries()[0]["status"] == "0 ok", "the mission is accepted")
    page.click("takeoff")
    page.confirm("takeoff")
    page.wait(lambda: page.text("fsm") == "HOVER", "the vehicle hovers")
    page.command("mw_exec 1001:1,2,3")
    expected = [
        # The page learns that the pilot is itself from `control`: the
        # line says so once it knows.
        ("control", rf"taken by this console \({LABEL}\)"),
        ("fsm", "disarmed → takeoff"),
        ("armed", "motors armed"),
        ("fsm", "takeoff → hover"),
        ("mission", "mission 1001 started"),
        ("fsm", "hover → mission"),
        ("mission", r"reached waypoint 1 of 3 \(id 1, mission 1001\)"),
        ("mission", r"reached waypoint 2 of 3 \(id 2, mission 1001\)"),
        ("mission", r"reached waypoint 3 of 3 \(id 3, mission 1001\)"),
        ("mission", "mission 1001 completed"),
        ("fsm", "mission → hover"),
    ]
    page.wait(lambda: matches(told(page), expected), "the log tells the flight in order")
    lines = page.event_lines()
    assert [e["kind"] for e in lines] == ["event"] * len(lines), "one run, nothing missed: no marker"
    assert [e["seq"] for e in lines] == list(range(1, len(lines) + 1)), "seq counts from 1 without a skip"
    # Newest first on the page, as the command log.
    newest = page.el("events").find_elements("css selector", "li")[0]
    assert newest.get_attribute("data-seq") == str(lines[-1]["seq"])
    assert re.fullmatch(r"\d\d:\d\d:\d\d", newest.find_element("css selector", "time").text)
    page.screenshot("events")


def test_a_restarted_daemon_is_marked_and_the_stream_comes_back(daemon, binary, page):
    logged_in(page, daemon)
    page.click("take-control")
    page.wait(lambda: matches(told(page), [("control", rf"taken by this console \({LABEL}\)")]), "the take is told")
    address = daemon.addr
    daemon.stop()
    page.wait(lambda: re.fullmatch(r"disconnected · \d+ .*; retry in \d+\.\d s", page.text("events-conn"))
              and page.el("events-conn").get_attribute("data-tone") == "danger",
              "the event log says in red that its stream is gone, and when it tries again")
    again = Lluavd(binary, "--password", PASSWORD, "--sim-speed", "4", bind=address)
    try:
        # Control does not survive a restart: a state saying so comes from
        # the new run, to a command socket that logged in again by itself.
        page.wait(lambda: page.text("control") == "free" and page.shown("take-control"), "the page is back, control free")
        page.wait(lambda: page.text("events-conn") == "connected", "the event stream reopens and logs in again")
        page.click("take-control")
        page.wait(lambda: [(e["kind"], e["name"]) for e in page.event_lines()[-2:]] == [("marker", "restart"), ("event", "control")],
                  "the first event of the new run comes after a restart marker")
        before, marker, control = page.event_lines()[-3:]
        assert "restarted" in marker["text"] and control["seq"] == 1, (marker, control)
        page.wait(lambda: re.fullmatch(rf"taken by this console \({LABEL}\)", page.event_lines()[-1]["text"]),
                  "the new session's take is this console's too")
        assert re.fullmatch(rf"taken by this console \({LABEL}\)", before["text"]), "the old run's line keeps saying so"
        assert before["text"] != page.event_lines()[-1]["text"], "two sessions, two labels"
        page.screenshot("events-restart")
        # While lluavd was gone the page's reconnections failed, which
        # Chromium logs as errors; nothing else may have been logged.
        errors = [e for e in page.driver.get_log("browser") if e["level"] == "SEVERE"]
        assert all("WebSocket connection to" in e["message"] for e in errors), errors
    finally:
        page.driver.get("about:blank")
        again.stop()


def test_a_vehicle_without_password_streams_events_without_a_login(open_daemon, page):
    page.open(open_daemon)
    page.wait(lambda: page.text("role") == "no password", "no login needed")
    page.wait(lambda: page.text("events-conn") == "connected", "the event stream is open without a login")
    page.click("take-control")
    page.wait(lambda: matches(told(page), [("control", rf"taken by this console \({LABEL}\)")]), "the take is told")
