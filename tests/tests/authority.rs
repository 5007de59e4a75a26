//! Flight authority over real sockets (DESIGN.md, "Flight authority"):
//! one session flies at a time, a landing by anyone holds, control ends
//! with its session, its release or its silence, an admin pilot keeps it
//! in lock mode, and a failsafe refuses every motion command.

use std::time::{Duration, Instant};

use lluav_tests::{Conn, Lluavd, Options, WAIT, wait_for_state};
use serde_json::Value;

const PASSWORD: &str = "s3cret";

fn msg(r: &Value) -> &str {
    r["msg"].as_str().unwrap_or("")
}

/// A daemon flying at `speed`, with a password, and `n` logged-in
/// sessions.
async fn vehicle(n: usize, speed: &str) -> (tempfile::TempDir, Lluavd, Vec<Conn>) {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options::password(PASSWORD).with_args(&["--sim-speed", speed]);
    let daemon = Lluavd::start(dir.path(), &options);
    let mut sessions = Vec::new();
    for _ in 0..n {
        sessions.push(Conn::login(&daemon.url, PASSWORD).await);
    }
    (dir, daemon, sessions)
}

async fn hovering(c: &mut Conn) {
    assert_eq!(c.request("takeoff").await["ret"], 0);
    wait_for_state(c, "hovering", |s| s["fsm"] == "hover").await;
}

/// The label `control` gives `c`'s own session.
async fn label_of(c: &mut Conn) -> String {
    let r = c.request("control").await;
    assert_eq!(r["control"]["you"], true, "{r}");
    r["control"]["by"].as_str().expect("a label").to_owned()
}

#[tokio::test]
async fn a_landing_asked_by_another_session_holds_while_the_pilot_streams() {
    let (_dir, _daemon, mut s) = vehicle(2, "10").await;
    let [pilot, other] = &mut s[..] else {
        unreachable!()
    };
    hovering(pilot).await;
    assert_eq!(pilot.request("set_sp_ned 5:0:-3:0").await["ret"], 0);
    let pilot_label = label_of(pilot).await;
    assert!(
        pilot_label.starts_with("ws 127.0.0.1:") && pilot_label.contains(" #"),
        "{pilot_label}"
    );
    assert_eq!(other.request("land").await["ret"], 0);
    let other_label = label_of(other).await;
    // The old pilot streams on: every setpoint is refused and the vehicle
    // comes down.
    let start = Instant::now();
    loop {
        let r = pilot.request("set_sp_ned 5:0:-3:0").await;
        assert_eq!(r["ret"], -1, "{r}");
        assert!(
            msg(&r).starts_with(&format!("Vehicle is flown by {other_label} since ")),
            "{r}"
        );
        let s = other.request("state").await;
        assert_ne!(s["state"]["fsm"], "hover", "the landing was cancelled: {s}");
        if s["state"]["armed"] == false {
            break;
        }
        assert!(start.elapsed() < WAIT, "never landed: {s}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test]
async fn control_take_takes_over_and_control_release_frees_control() {
    let (_dir, daemon, mut s) = vehicle(2, "10").await;
    let [a, b] = &mut s[..] else { unreachable!() };
    assert_eq!(a.request("control").await["control"], Value::Null);
    hovering(a).await;
    let r = b.request("set_sp_ned 1:0:-2:0").await;
    assert!(msg(&r).ends_with(": control_take to take over"), "{r}");
    let taken = b.request("control_take").await;
    assert_eq!(
        (taken["ret"].clone(), taken["control"]["you"].clone()),
        (0.into(), true.into())
    );
    // The take-over is logged (DESIGN), naming both sessions.
    let (pilot, taker) = (label_of(b).await, taken["control"]["by"].clone());
    assert_eq!(taker, pilot.as_str());
    let line = daemon.log_until(&["control changed", &format!("by=\"{pilot}\"")]);
    assert!(line.contains("from=\"ws 127.0.0.1:"), "{line}");
    assert_eq!(b.request("set_sp_ned 1:0:-2:0").await["ret"], 0);
    assert_eq!(a.request("set_sp_ned 2:0:-2:0").await["ret"], -1);
    assert_eq!(
        a.request("control_release").await["msg"],
        "This session is not in control"
    );
    assert_eq!(b.request("control_release").await["control"], Value::Null);
    assert_eq!(
        a.request("set_sp_ned 2:0:-2:0").await["ret"],
        0,
        "control was free"
    );
    // state says who flies.
    let by = label_of(a).await;
    let st = b.request("state").await;
    assert_eq!(st["state"]["control"]["by"], by.as_str(), "{st}");
    assert!(st["state"]["control"].get("you").is_none(), "{st}");
}

#[tokio::test]
async fn control_ends_with_the_pilots_session() {
    // No lapse in this test: only the closed session can free control.
    let (_dir, _daemon, mut s) = vehicle(2, "10").await;
    let mut b = s.pop().expect("two sessions");
    let mut a = s.pop().expect("two sessions");
    assert_eq!(b.request("set_param control_timeout:3600").await["ret"], 0);
    hovering(&mut a).await;
    assert_eq!(b.request("set_sp_ned 1:0:-2:0").await["ret"], -1);
    a.close().await;
    let start = Instant::now();
    while b.request("set_sp_ned 1:0:-2:0").await["ret"] != 0 {
        assert!(start.elapsed() < WAIT, "control never freed");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test]
async fn silence_for_control_timeout_frees_control_and_any_request_keeps_it() {
    let (_dir, _daemon, mut s) = vehicle(2, "10").await;
    let [a, b] = &mut s[..] else { unreachable!() };
    assert_eq!(a.request("set_param control_timeout:4").await["ret"], 0);
    hovering(a).await;
    // Any request keeps it: `state` every half second for four seconds.
    for _ in 0..8 {
        tokio::time::sleep(Duration::from_millis(500)).await;
        assert_eq!(a.request("state").await["ret"], 0);
        assert_eq!(b.request("set_sp_ned 1:0:-2:0").await["ret"], -1, "kept alive");
    }
    let silent = Instant::now();
    while b.request("set_sp_ned 1:0:-2:0").await["ret"] != 0 {
        assert!(silent.elapsed() < WAIT, "control never lapsed");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(
        silent.elapsed() >= Duration::from_secs(3),
        "lapsed after {:?} of silence, before its 4 s",
        silent.elapsed()
    );
}

#[tokio::test]
async fn in_lock_mode_an_admin_pilot_keeps_control_against_a_users_landing() {
    let (_dir, _daemon, mut s) = vehicle(2, "10").await;
    let [admin, user] = &mut s[..] else { unreachable!() };
    assert_eq!(admin.request("login 1025").await["ret"], 0);
    assert_eq!(admin.request("admin_lock").await["ret"], 0);
    hovering(admin).await;
    assert_eq!(user.request("land").await["ret"], 0, "anyone may bring it down");
    assert_eq!(admin.request("control").await["control"]["you"], true);
    assert_eq!(
        msg(&user.request("control_take").await),
        "CMD not permitted to run in LOCK mode!"
    );
}

#[tokio::test]
async fn a_failsafe_refuses_motion_commands_and_says_so_in_state() {
    // At speed 1 the low battery starts about 6 s after takeoff and the
    // empty one a minute later: time enough to look at the first.
    let (_dir, _daemon, mut s) = vehicle(1, "1").await;
    let c = &mut s[0];
    for p in ["battery_drain:100", "low_battery:90", "rtl_alt:30"] {
        assert_eq!(c.request(&format!("set_param {p}")).await["ret"], 0, "{p}");
    }
    assert_eq!(c.request("takeoff").await["ret"], 0);
    wait_for_state(c, "in failsafe", |s| s["failsafe"] == "battery_low").await;
    let r = c.request("set_sp_ned 20:0:-4:0").await;
    assert_eq!(
        (r["ret"].clone(), msg(&r)),
        (
            (-1).into(),
            "Vehicle is in failsafe (battery_low): land, rtl or control_take failsafe"
        )
    );
    assert_eq!(
        c.request("state").await["state"]["fsm"],
        "rtl",
        "the return goes on"
    );
    assert_eq!(c.request("control_take failsafe").await["ret"], 0);
    let st = c.request("state").await;
    assert_eq!(st["state"]["failsafe"], "battery_low (overridden)");
    assert_eq!(c.request("set_sp_ned 2:0:-3:0").await["ret"], 0);
}

#[tokio::test]
async fn a_takeoff_higher_than_max_alt_climbs_to_max_alt_and_says_so() {
    let (_dir, _daemon, mut s) = vehicle(1, "10").await;
    let c = &mut s[0];
    assert_eq!(c.request("set_param max_alt:3").await["ret"], 0);
    assert_eq!(c.request("set_param takeoff_alt:5").await["ret"], 0);
    assert_eq!(c.request("takeoff").await["target_alt"], 3.0);
    let r = c.request("set_sp_ned 0:0:-4:0").await;
    assert_eq!(msg(&r), "Invalid arguments: altitude 4 m above max_alt 3 m");
}
