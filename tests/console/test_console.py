"""The browser console in headless Chromium against a real lluavd."""

from __future__ import annotations

import json

from selenium.webdriver.common.by import By
from selenium.webdriver.common.keys import Keys

from conftest import PASSWORD
from harness import Client
from page import distance


def log_in_and_take_off(page, daemon):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: not page.shown("login"), "the login form goes away")
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows disarmed")
    page.click("takeoff")
    page.confirm("takeoff")
    page.wait(lambda: page.text("fsm") == "HOVER", "the vehicle hovers after takeoff")


def test_password_vehicle_asks_for_login_and_refuses_a_wrong_one(daemon, page):
    page.open(daemon)
    page.wait(lambda: page.shown("login"), "the login form shows")
    assert page.el("main").get_attribute("inert") is not None, "the page behind the form is inert"
    page.screenshot("login")
    page.login("not-it")
    page.wait(lambda: page.text("login-error") == "Wrong password!", "the refusal is shown")
    assert page.shown("login")
    page.login(PASSWORD)
    page.wait(lambda: not page.shown("login"), "the login form goes away")
    page.wait(lambda: page.text("role") == "user", "the role badge says user")
    page.wait(lambda: page.text("fsm") == "DISARMED", "live state shows")
    assert page.text("armed") == "disarmed"
    assert page.text("battery").startswith("100")
    entries = page.log_entries()
    assert [e["request"] for e in entries[:2]] == ["login ••••", "login ••••"], "passwords are never shown"
    assert PASSWORD not in page.text("log") and "not-it" not in page.text("log")


def test_takeoff_confirms_then_the_fsm_changes(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows disarmed")
    page.click("takeoff")
    page.wait(lambda: page.shown("confirm"), "takeoff asks first")
    page.click("confirm-cancel")
    page.wait(lambda: not page.shown("confirm"), "the dialog closes")
    assert page.log_entries()[0]["request"] != "takeoff", "cancel sends nothing"
    page.click("takeoff")
    page.confirm("takeoff")
    page.wait(lambda: page.text("fsm") in ("TAKEOFF", "HOVER"), "the fsm leaves disarmed")
    page.wait(lambda: page.text("armed") == "armed", "the vehicle is armed")
    page.wait(lambda: page.text("fsm") == "HOVER", "the vehicle hovers")
    assert page.text("airborne") == "airborne"
    assert float(page.text("alt")) > 1.5
    assert not page.el("takeoff").is_enabled(), "takeoff is off while flying"


def test_click_on_the_plot_flies_the_vehicle_there(daemon, page):
    log_in_and_take_off(page, daemon)
    before = page.marker("vehicle-marker")
    home = page.marker("home-marker")
    assert distance(before, home) < 0.2
    page.click_plot_at(4.0, 3.0)
    command = page.confirm("set_sp_ned ")
    n, e, d, _yaw = (float(v) for v in command.split(" ")[1].split(":"))
    view_scale = page.view()["scale"]
    assert abs(n - 4.0) < 2 / view_scale + 0.01 and abs(e - 3.0) < 2 / view_scale + 0.01, command
    assert abs(d + 2.0) < 0.05, f"the setpoint keeps the current altitude: {command}"
    page.wait(lambda: distance(page.marker("setpoint-marker"), {"n": n, "e": e}) < 0.05, "the setpoint marker moves there")
    page.wait(lambda: distance(page.marker("vehicle-marker"), {"n": n, "e": e}) < 0.3, "the vehicle reaches the setpoint")
    after = page.marker("vehicle-marker")
    moved_px = distance(after, page.marker("home-marker"), keys=("x", "y"))
    assert moved_px > 40, f"the marker moved away from home on screen ({moved_px:.0f} px)"
    points = page.el("plot").find_element(By.CSS_SELECTOR, ".track").get_attribute("points").split()
    assert len(points) >= 3, "the track flown is drawn"
    page.screenshot("flying")


def test_setpoint_from_the_command_line_moves_the_marker(daemon, page):
    log_in_and_take_off(page, daemon)
    page.command("set_sp_ned -3:-4:-3:1.57")
    page.wait(lambda: page.log_entries()[0]["request"] == "set_sp_ned -3:-4:-3:1.57", "the request is logged")
    assert page.log_entries()[0]["status"] == "0 ok"
    page.wait(lambda: distance(page.marker("vehicle-marker"), {"n": -3, "e": -4}) < 0.3, "the vehicle flies there")
    yaw = float(page.el("vehicle-marker").get_attribute("data-yaw"))
    assert abs(yaw - 1.57) < 0.05, "the marker points where the vehicle heads"
    assert page.text("yaw") == "90°"
    page.wait(lambda: abs(float(page.text("alt")) - 3.0) < 0.1, "the altitude follows")


def test_refused_commands_show_their_error_in_words(daemon, page):
    log_in_and_take_off(page, daemon)
    page.command("reboot_node")
    page.wait(lambda: "reboot_node" in page.text("last-result"), "the answer is shown")
    last = page.el("last-result")
    assert last.get_attribute("data-ret") == "-1"
    assert last.text == "reboot_node: failed or refused (-1) — Not allow when vehicle is ARMED!"
    entry = page.log_entries()[0]
    assert entry["ret"] == "-1" and entry["status"] == "-1 failed or refused"
    assert "Not allow when vehicle is ARMED!" in entry["text"]
    page.screenshot("refused")
    page.command("set_sp_ned 5:0")
    page.wait(lambda: page.log_entries()[0]["request"] == "set_sp_ned 5:0", "the second answer is logged")
    assert page.log_entries()[0]["status"] == "-2 invalid arguments or unsupported"
    assert "usage: set_sp_ned x:y:z:yaw" in page.text("last-result")
    page.command("no_such_command")
    page.wait(lambda: page.log_entries()[0]["request"] == "no_such_command", "the third answer is logged")
    assert "Unsupported command: no_such_command" in page.text("last-result")


def test_command_line_completes_names_and_keeps_history(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows")
    field = page.el("command")
    page.wait(lambda: "Tab completes" in page.text("command-hint"), "the command names arrived")
    field.send_keys("take")
    field.send_keys(Keys.TAB)
    assert field.get_attribute("value") == "takeoff "
    field.clear()
    field.send_keys("set_")
    assert "set_sp_ned" in page.text("command-hint") and "set_param" in page.text("command-hint")
    field.send_keys(Keys.TAB)
    assert field.get_attribute("value") == "set_"
    field.clear()
    page.command("get_param takeoff_alt")
    page.wait(lambda: page.log_entries()[0]["request"] == "get_param takeoff_alt", "the answer is logged")
    page.command("ver")
    page.wait(lambda: page.log_entries()[0]["request"] == "ver", "the answer is logged")
    field.send_keys(Keys.ARROW_UP)
    assert field.get_attribute("value") == "ver"
    field.send_keys(Keys.ARROW_UP)
    assert field.get_attribute("value") == "get_param takeoff_alt"
    field.send_keys(Keys.ARROW_DOWN, Keys.ARROW_DOWN)
    assert field.get_attribute("value") == ""
    answer = page.log_entries()[1]["text"]
    assert '"ret":0' in answer and "takeoff_alt" in answer


def test_mission_waypoints_are_drawn_on_the_plot(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows")
    mission = {"waypoints": [{"x": 5, "y": 0, "z": -3}, {"x": 5, "y": 5, "z": -3}, {"x": 0, "y": 5, "z": -3, "yaw": 1}]}
    page.command(f"mission 1001:{json.dumps(mission, separators=(',', ':'))}")
    page.wait(lambda: page.log_entries()[0]["status"] == "0 ok", "the mission is accepted")
    page.wait(lambda: len(page.driver.find_elements(By.CSS_SELECTOR, "#plot .waypoint")) == 3, "three waypoints are drawn")
    drawn = [
        (float(w.get_attribute("data-n")), float(w.get_attribute("data-e")))
        for w in page.driver.find_elements(By.CSS_SELECTOR, "#plot .waypoint")
    ]
    assert drawn == [(5.0, 0.0), (5.0, 5.0), (0.0, 5.0)]
    page.screenshot("mission")


def test_vehicle_without_password_needs_no_login(open_daemon, page):
    page.open(open_daemon)
    page.wait(lambda: page.text("fsm") == "DISARMED", "live state shows without login")
    assert not page.shown("login")
    assert page.text("role") == "no password"
    page.wait(lambda: page.text("age").startswith("state ") and page.text("age").endswith(" s ago"), "the age shows")
    page.wait(lambda: float(page.text("age").split()[1]) < 1.0, "state is fresh: polled several times a second")


def test_keyboard_alone_flies_the_vehicle(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows")
    page.el("takeoff").send_keys(Keys.ENTER)
    page.wait(lambda: page.shown("confirm"), "takeoff asks first")
    assert page.driver.switch_to.active_element.get_attribute("id") == "confirm-cancel", "a dangerous question starts on Cancel"
    page.driver.switch_to.active_element.send_keys(Keys.ESCAPE)
    page.wait(lambda: not page.shown("confirm"), "Escape says no")
    page.el("takeoff").send_keys(Keys.ENTER)
    page.wait(lambda: page.shown("confirm"), "takeoff asks again")
    page.driver.switch_to.active_element.send_keys(Keys.TAB)
    assert page.driver.switch_to.active_element.get_attribute("id") == "confirm-ok"
    page.driver.switch_to.active_element.send_keys(Keys.ENTER)
    page.wait(lambda: page.text("fsm") == "HOVER", "the vehicle hovers")
    plot = page.el("plot")
    plot.send_keys(Keys.ARROW_RIGHT, Keys.ARROW_UP)
    view = page.view()
    assert plot.get_attribute("data-auto") == "false", "panning ends auto-fit"
    plot.send_keys(Keys.ENTER)
    command = page.confirm("set_sp_ned ")
    n, e = (float(v) for v in command.split(" ")[1].split(":")[:2])
    assert abs(n - view["n"]) < 0.01 and abs(e - view["e"]) < 0.01, "Enter flies to the crosshair"
    page.wait(lambda: distance(page.marker("vehicle-marker"), {"n": n, "e": e}) < 0.3, "the vehicle flies there")
    plot.send_keys("f")
    assert plot.get_attribute("data-auto") == "true"


def test_tablet_and_laptop_widths_fit_without_sideways_scrolling(daemon, page):
    try:
        for name, (w, h) in {"tablet": (820, 1180), "laptop": (1366, 768)}.items():
            page.resize(w, h)
            page.open(daemon)
            page.login(PASSWORD)
            page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows")
            overflow = page.driver.execute_script(
                "return document.documentElement.scrollWidth - document.documentElement.clientWidth"
            )
            assert overflow <= 0, f"{name}: {overflow} px wider than the window"
            for part in ("plot", "takeoff", "land", "rtl", "disarm", "command", "fsm", "battery", "control", "take-control"):
                assert page.shown(part), f"{name}: {part} is not shown"
            assert page.el("plot").size["height"] >= 300, f"{name}: the plot is too small"
            page.screenshot(name)
    finally:
        page.resize(1440, 900)


def test_go_home_and_land_bring_the_vehicle_down(daemon, page):
    log_in_and_take_off(page, daemon)
    page.command("set_sp_ned 4:0:-2:0")
    page.wait(lambda: distance(page.marker("vehicle-marker"), {"n": 4, "e": 0}) < 0.3, "the vehicle flies out")
    page.click("rtl")
    page.wait(lambda: page.log_entries()[0]["request"] == "rtl", "rtl is sent without a question")
    assert page.log_entries()[0]["status"] == "0 ok"
    page.wait(lambda: distance(page.marker("vehicle-marker"), page.marker("home-marker")) < 0.3, "the vehicle returns home")
    page.wait(lambda: page.text("fsm") == "DISARMED", "it lands and disarms")
    page.click("takeoff")
    page.confirm("takeoff")
    page.wait(lambda: page.text("fsm") == "HOVER", "it takes off again")
    page.click("land")
    page.wait(lambda: page.text("fsm") in ("LANDING", "DISARMED"), "land is sent without a question")
    page.wait(lambda: page.text("airborne") == "on ground", "it is on the ground")


def test_disarm_in_the_air_warns_before_it_is_sent(daemon, page):
    log_in_and_take_off(page, daemon)
    page.click("disarm")
    page.wait(lambda: page.shown("confirm"), "disarm asks first")
    assert page.text("confirm-title") == "Disarm in the air?"
    assert "falls" in page.text("confirm-text")
    page.click("confirm-cancel")
    page.wait(lambda: not page.shown("confirm"), "the dialog closes")
    assert page.text("fsm") == "HOVER", "cancel leaves the vehicle flying"
    assert all(e["request"] != "disarm" for e in page.log_entries())


def test_log_out_forgets_the_password_and_asks_again(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("role") == "user", "logged in")
    page.click("logout")
    page.wait(lambda: page.shown("login"), "the login form is back after logging out")
    page.wait(lambda: page.text("conn").startswith("connected"), "on a new connection")
    page.login("1025")
    page.wait(lambda: page.text("role") == "admin", "the admin value gives admin, as in any client")
    page.command("admin_lock")
    page.wait(lambda: page.log_entries()[0]["request"] == "admin_lock", "the answer is logged")
    page.wait(lambda: page.text("lock") == "lock mode", "the lock mode badge shows it")
    page.command("admin_unlock")
    page.wait(lambda: page.text("lock") == "unlocked", "and its end")


def test_login_from_the_command_line_counts_as_the_forms(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("role") == "user", "logged in")
    page.command("login 1025")
    page.wait(lambda: page.text("role") == "admin", "the admin value from the command line gives admin")
    page.command("login not-it")
    page.wait(lambda: page.log_entries()[0]["ret"] == "-1", "the refusal is logged")
    assert page.text("role") == "admin" and not page.shown("login"), "a refused attempt changes nothing"
    page.command("login 0315")
    page.wait(lambda: page.shown("login"), "the logout value asks for the password")
    page.login(PASSWORD)
    page.wait(lambda: page.text("role") == "user", "the form logs in again")


def test_losing_the_daemon_shows_disconnected_and_retries(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows")
    daemon.stop()
    page.wait(lambda: page.text("conn").startswith("disconnected · retry in"), "the header says the link is gone")
    page.wait(lambda: page.text("age").startswith("state ") and float(page.text("age").split()[1]) > 1.5,
              "the state's age grows")
    assert page.el("age").get_attribute("data-tone") in ("warn", "danger")
    notes = page.text("log")
    assert "disconnected (1001" in notes, notes
    # The retries log failed connections; leave before the page fixture reads the log.
    page.driver.get("about:blank")
    page.driver.get_log("browser")


def test_a_setpoint_on_the_ground_is_refused_and_says_why(daemon, page):
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows")
    page.click_plot_at(3.0, 0.0)
    command = page.confirm("set_sp_ned ")
    assert command.split(":")[2] == "0", f"on the ground the setpoint is at ground level: {command}"
    page.wait(lambda: page.el("last-result").get_attribute("data-ret") == "-2", "the refusal is shown")
    assert page.text("last-result").endswith(
        "invalid arguments or unsupported (-2) — Invalid arguments: setpoint at or below the ground "
        "(z >= 0; up is negative z): use land to descend"
    )
    assert page.el("last-result").get_attribute("data-tone") == "warn"
    assert distance(page.marker("vehicle-marker"), page.marker("home-marker")) < 0.05, "nothing moved"


def test_the_pages_policy_keeps_its_websocket_to_its_own_origin(daemon, open_daemon, page):
    # A link to this vehicle's console that names another server's WebSocket
    # (here a real one, open_daemon) must not make the page talk to it.
    page.driver.get(f"{daemon.http_url}?ws={open_daemon.ws_url}")
    page.wait(lambda: page.text("conn").startswith("disconnected"), "the connection is refused")
    assert page.text("fsm") == "UNKNOWN", "no state came from the other server"
    logs = page.driver.get_log("browser")
    assert any("Content Security Policy" in e["message"] for e in logs), logs
    page.driver.get("about:blank")
    page.driver.get_log("browser")


def other_operator(daemon) -> Client:
    """A second session beside the page, logged in as a person with a script would."""
    other = Client(daemon)
    other.ok(f"login {PASSWORD}")
    return other


def test_who_is_in_control_shows_and_take_control_takes_it_back(daemon, page):
    other = other_operator(daemon)
    try:
        # The other operator keeps control however slowly this machine runs
        # the test (30 s of silence would end it).
        other.ok("set_param control_timeout:3600")
        page.open(daemon)
        page.login(PASSWORD)
        page.wait(lambda: page.text("control") == "free", "control is free at first")
        assert page.shown("take-control") and not page.shown("release-control")
        page.click("takeoff")
        page.confirm("takeoff")
        # The takeoff gave this console control; the page finds out it is itself.
        page.wait(lambda: page.text("control") == "this console", "the console shows it is in control")
        assert page.el("control").get_attribute("data-tone") == "good"
        assert page.shown("release-control") and not page.shown("take-control")
        assert not page.shown("failsafe")
        console = page.el("control").get_attribute("title").removeprefix("This console (").split(")")[0]
        assert console.startswith("ws 127.0.0.1:") and not console.startswith(other.label_prefix), console
        page.wait(lambda: page.text("fsm") == "HOVER", "the vehicle hovers after takeoff")
        taken = other.ok("control_take")["control"]
        label = taken["by"]
        assert label.startswith(other.label_prefix) and taken["you"] is True, taken
        page.wait(lambda: page.text("control") == label, "the console shows who took control")
        assert page.el("control").get_attribute("data-you") == "false"
        assert page.el("control").get_attribute("data-tone") == "warn"
        assert page.text("control-since").startswith("since ")
        assert page.shown("take-control") and not page.shown("release-control")
        # A click on the map is a motion command: refused, saying who flies.
        page.click_plot_at(3.0, 0.0)
        page.confirm("set_sp_ned ")
        page.wait(lambda: page.el("last-result").get_attribute("data-ret") == "-1", "the refusal is shown")
        assert page.text("last-result").endswith(
            f"failed or refused (-1) — Vehicle is flown by {label} since {taken['since']}: control_take to take over"
        ), page.text("last-result")
        page.screenshot("control-other")
        page.click("take-control")
        page.wait(lambda: page.log_entries()[0]["request"] == "control_take", "Take control sends control_take at once")
        assert page.log_entries()[0]["status"] == "0 ok"
        page.wait(lambda: page.text("control") == "this console", "the console is in control again")
        assert other.ok("control")["control"]["you"] is False
        refused = other.ask("set_sp_ned 1:0:-2:0")
        assert refused["ret"] == -1 and refused["msg"].startswith(f"Vehicle is flown by {console} since "), refused
        # The map steers again, from this console.
        page.click_plot_at(3.0, 0.0)
        page.confirm("set_sp_ned ")
        page.wait(lambda: page.log_entries()[0]["request"].startswith("set_sp_ned"), "the setpoint is answered")
        assert page.log_entries()[0]["status"] == "0 ok"
        page.click("release-control")
        page.wait(lambda: page.text("control") == "free", "Release leaves control free")
        assert other.ok("control")["control"] is None
        assert page.shown("take-control") and not page.shown("release-control")
    finally:
        other.close()


def test_a_failsafe_shows_and_taking_control_overrides_it_after_a_question(real_time_daemon, page):
    daemon = real_time_daemon
    other = other_operator(daemon)
    try:
        # The battery runs low a few seconds after the takeoff; the return
        # climbs high, so that it is still on its way when overridden.
        for param in ("battery_drain:100", "low_battery:90", "rtl_alt:120"):
            other.ok(f"set_param {param}")
    finally:
        other.close()
    page.open(daemon)
    page.login(PASSWORD)
    page.wait(lambda: page.text("fsm") == "DISARMED", "the state shows disarmed")
    assert not page.shown("failsafe")
    page.click("takeoff")
    page.confirm("takeoff")
    # Not waiting for the hover: on a slow machine the page may not see it
    # before the battery runs low.
    page.wait(lambda: page.shown("failsafe"), "the failsafe shows")
    assert page.text("failsafe-reason") == "battery_low"
    failsafe = page.el("failsafe")
    assert failsafe.get_attribute("data-tone") == "danger"
    assert failsafe.get_attribute("data-overridden") == "false"
    assert "OVERRIDDEN" not in failsafe.text.upper()
    page.wait(lambda: page.text("fsm") == "RTL", "the vehicle returns on its own")
    page.wait(lambda: page.text("control") == "this console", "the console still holds control")
    assert page.shown("take-control"), "overriding is for the pilot too"
    page.screenshot("failsafe")
    # Steering is refused, saying why.
    page.command("set_sp_ned 3:0:-3:0")
    page.wait(lambda: page.log_entries()[0]["request"] == "set_sp_ned 3:0:-3:0", "the refusal is logged")
    assert page.text("last-result").endswith(
        "Vehicle is in failsafe (battery_low): land, rtl or control_take failsafe"
    ), page.text("last-result")
    # Take control asks first; Cancel sends nothing.
    page.click("take-control")
    page.wait(lambda: page.shown("confirm"), "overriding asks first")
    assert page.text("confirm-command") == "control_take failsafe"
    assert "battery_low" in page.text("confirm-text")
    assert page.driver.switch_to.active_element.get_attribute("id") == "confirm-cancel", "it starts on Cancel"
    page.screenshot("failsafe-confirm")
    page.click("confirm-cancel")
    page.wait(lambda: not page.shown("confirm"), "the dialog closes")
    assert all(e["request"] != "control_take failsafe" for e in page.log_entries()), "cancel sends nothing"
    assert page.el("failsafe").get_attribute("data-overridden") == "false"
    page.click("take-control")
    page.confirm("control_take failsafe")
    page.wait(lambda: page.el("failsafe").get_attribute("data-overridden") == "true", "the override shows")
    assert page.log_entries()[0]["request"] == "control_take failsafe"
    assert page.log_entries()[0]["status"] == "0 ok"
    assert page.text("failsafe-reason") == "battery_low" and "OVERRIDDEN" in page.text("failsafe").upper()
    assert page.el("failsafe").get_attribute("data-tone") == "warn"
    assert page.text("control") == "this console"
    assert not page.shown("take-control") and page.shown("release-control")
    checker = other_operator(daemon)
    try:
        assert checker.ok("state")["state"]["failsafe"] == "battery_low (overridden)"
    finally:
        checker.close()
    page.screenshot("failsafe-overridden")
    # The pilot steers again.
    page.command("set_sp_ned 3:0:-3:0")
    page.wait(lambda: page.log_entries()[0]["request"] == "set_sp_ned 3:0:-3:0", "the setpoint is answered")
    assert page.log_entries()[0]["status"] == "0 ok"
