//! Flight authority (DESIGN.md): one session flies at a time, failsafes
//! win, and the conservative commands stay open to everyone.

mod common;

use std::cell::Cell;
use std::net::SocketAddr;

use common::*;
use lluav_core::{Action, Auth, Failsafe, Server, Session, TABLE, Via};

thread_local! {
    /// This test's clock (each test runs on a thread of its own).
    static NOW: Cell<i64> = const { Cell::new(TS) };
}

fn now() -> i64 {
    NOW.with(Cell::get)
}

fn advance(ms: i64) {
    NOW.with(|n| n.set(n.get() + ms));
}

/// A server on this test's clock, and `n` WebSocket sessions logged in as
/// users from distinct ports of 192.0.2.7.
fn vehicle(n: u16) -> (TestServer, Vec<Session>) {
    let mut s = Server::new(
        MockVehicle::default(),
        now as fn() -> i64,
        Auth::new(Some("pw")).unwrap(),
    );
    let sessions = (0..n)
        .map(|i| {
            let addr: SocketAddr = ([192, 0, 2, 7], 51000 + i).into();
            let mut session = s.open_via(Some(addr.ip().into()), Via::WebSocket(&addr.to_string()));
            assert_eq!(send(&mut s, &mut session, "login pw").ret(), 0);
            session
        })
        .collect();
    (s, sessions)
}

const BATTERY_LOW: Failsafe = Failsafe::new("battery_low", Action::Rtl);
const BATTERY_EMPTY: Failsafe = Failsafe::new("battery_empty", Action::Land);

#[test]
fn the_first_motion_command_takes_free_control_and_another_session_is_refused() {
    let (mut s, mut ss) = vehicle(2);
    let [a, b] = &mut ss[..] else { unreachable!() };
    assert_eq!(
        send(&mut s, a, "control").json()["control"],
        serde_json::Value::Null
    );
    assert_eq!(send(&mut s, a, "set_sp_ned 1:2:-3:0").ret(), 0);
    let seen = send(&mut s, b, "set_sp_ned 5:5:-5:0");
    assert_eq!(
        (seen.ret(), seen.msg()),
        (
            -1,
            format!("Vehicle is flown by ws 192.0.2.7:51000 #1 since {TS}: control_take to take over")
                .as_str()
        )
    );
    assert_eq!(
        s.backend()
            .executed
            .iter()
            .filter(|c| c.name() == "set_sp_ned")
            .count(),
        1
    );
    let mine = send(&mut s, a, "control");
    assert_eq!(
        mine.json()["control"],
        serde_json::json!({"by": "ws 192.0.2.7:51000 #1", "since": TS, "you": true})
    );
    assert_eq!(send(&mut s, b, "control").json()["control"]["you"], false);
    // Neutral commands are anyone's.
    assert_eq!(send(&mut s, b, "ledon").ret(), 0);
}

#[test]
fn a_conservative_command_from_anyone_runs_and_passes_control_to_its_sender() {
    for name in ["land", "rtl", "mrtl", "tether_land", "disarm"] {
        let (mut s, mut ss) = vehicle(2);
        let [pilot, other] = &mut ss[..] else {
            unreachable!()
        };
        assert_eq!(send(&mut s, pilot, "takeoff").ret(), 0);
        assert_eq!(send(&mut s, other, name).ret(), 0, "{name}");
        // The old pilot's stream no longer cancels it.
        assert_eq!(send(&mut s, pilot, "set_sp_ned 1:1:-2:0").ret(), -1, "{name}");
        assert_eq!(
            send(&mut s, other, "control").json()["control"]["you"],
            true,
            "{name}"
        );
    }
}

#[test]
fn control_ends_with_release_the_session_a_logout_and_silence() {
    let (mut s, mut ss) = vehicle(3);
    let [a, b, c] = &mut ss[..] else { unreachable!() };
    assert_eq!(
        send(&mut s, a, "control_release").msg(),
        "This session is not in control"
    );
    assert_eq!(send(&mut s, a, "takeoff").ret(), 0);
    assert_eq!(
        send(&mut s, b, "control_release").ret(),
        -1,
        "only the pilot releases"
    );
    assert_eq!(send(&mut s, a, "control_release").ret(), 0);
    assert_eq!(send(&mut s, b, "set_sp_ned 1:1:-2:0").ret(), 0, "free again");
    // The session ends: free at once.
    s.close(b);
    assert_eq!(send(&mut s, c, "set_sp_ned 1:1:-2:0").ret(), 0);
    // So does logging out (the connection stays).
    assert_eq!(send(&mut s, c, "login 0315").ret(), 0);
    assert_eq!(
        send(&mut s, a, "control").json()["control"],
        serde_json::Value::Null
    );
    assert_eq!(send(&mut s, c, "login pw").ret(), 0);
    assert_eq!(send(&mut s, c, "set_sp_ned 1:1:-2:0").ret(), 0);
    // Any request keeps it; 30 s of silence ends it.
    advance(29_000);
    assert_eq!(send(&mut s, c, "state").ret(), 0);
    advance(29_000);
    assert_eq!(
        send(&mut s, a, "set_sp_ned 1:1:-2:0").ret(),
        -1,
        "kept by the state request"
    );
    advance(30_000);
    assert_eq!(
        send(&mut s, a, "set_sp_ned 1:1:-2:0").ret(),
        0,
        "lapsed after 30 s"
    );
    assert_eq!(
        send(&mut s, c, "control").json()["control"]["by"],
        "ws 192.0.2.7:51000 #1"
    );
}

#[test]
fn the_control_timeout_is_the_backends() {
    let (mut s, mut ss) = vehicle(2);
    s.backend_mut().control_timeout_ms = Some(2_000);
    let [a, b] = &mut ss[..] else { unreachable!() };
    assert_eq!(send(&mut s, a, "takeoff").ret(), 0);
    advance(1_999);
    assert!(!s.expire_control());
    advance(1);
    assert!(s.expire_control(), "an adapter can see it lapse");
    assert_eq!(send(&mut s, b, "set_sp_ned 1:1:-2:0").ret(), 0);
}

#[test]
fn control_take_takes_over_from_a_connected_pilot() {
    let (mut s, mut ss) = vehicle(2);
    let [a, b] = &mut ss[..] else { unreachable!() };
    assert_eq!(send(&mut s, a, "set_sp_ned 1:1:-2:0").ret(), 0);
    advance(5);
    let taken = send(&mut s, b, "control_take");
    assert_eq!(taken.ret(), 0);
    assert_eq!(
        taken.json()["control"],
        serde_json::json!({"by": "ws 192.0.2.7:51001 #2", "since": TS + 5, "you": true})
    );
    assert_eq!(send(&mut s, a, "set_sp_ned 1:1:-2:0").ret(), -1);
    assert_eq!(send(&mut s, b, "set_sp_ned 1:1:-2:0").ret(), 0);
}

#[test]
fn in_lock_mode_an_admin_pilot_keeps_control() {
    let (mut s, mut ss) = vehicle(3);
    let [admin, user, other_admin] = &mut ss[..] else {
        unreachable!()
    };
    assert_eq!(send(&mut s, admin, "login 1025").ret(), 0);
    assert_eq!(send(&mut s, other_admin, "login 1025").ret(), 0);
    assert_eq!(send(&mut s, admin, "admin_lock").ret(), 0);
    assert_eq!(send(&mut s, admin, "takeoff").ret(), 0);
    // A user's landing runs, and the admin keeps control.
    assert_eq!(send(&mut s, user, "land").ret(), 0);
    assert_eq!(send(&mut s, admin, "control").json()["control"]["you"], true);
    assert_eq!(
        send(&mut s, user, "control_take").msg(),
        "CMD not permitted to run in LOCK mode!"
    );
    assert_eq!(send(&mut s, other_admin, "control_take").ret(), 0, "an admin may");
    // Unlocked, conservative commands pass control again.
    assert_eq!(send(&mut s, admin, "admin_unlock").ret(), 0);
    assert_eq!(send(&mut s, user, "land").ret(), 0);
    assert_eq!(send(&mut s, user, "control").json()["control"]["you"], true);
}

#[test]
fn a_failsafe_refuses_motion_and_runs_the_conservative_commands() {
    let (mut s, mut ss) = vehicle(1);
    let a = &mut ss[0];
    s.backend_mut().armed = true;
    s.backend_mut().failsafe = Some(BATTERY_LOW);
    for frame in ["takeoff", "set_sp_ned 1:1:-2:0", "zyhk 2", "mw_exec 1:1"] {
        let seen = send(&mut s, a, frame);
        let msg = if frame == "takeoff" {
            "Not allow when vehicle is ARMED!"
        } else {
            "Vehicle is in failsafe (battery_low): land, rtl or control_take failsafe"
        };
        assert_eq!((seen.ret(), seen.msg()), (-1, msg), "{frame}");
    }
    assert!(s.backend().executed.is_empty());
    for frame in ["land", "rtl", "mrtl", "tether_land", "disarm", "abort_report"] {
        assert_eq!(send(&mut s, a, frame).ret(), 0, "{frame}");
    }
    let state = send(&mut s, a, "state");
    assert_eq!(state.json()["state"]["failsafe"], "battery_low");
}

#[test]
fn a_landing_failsafe_refuses_a_return_too() {
    let (mut s, mut ss) = vehicle(1);
    let a = &mut ss[0];
    s.backend_mut().failsafe = Some(BATTERY_EMPTY);
    for frame in ["rtl", "mrtl"] {
        let seen = send(&mut s, a, frame);
        assert_eq!(
            (seen.ret(), seen.msg()),
            (
                -1,
                "Vehicle is in failsafe (battery_empty): land, tether_land, disarm or control_take failsafe"
            )
        );
    }
    for frame in ["land", "tether_land", "disarm"] {
        assert_eq!(send(&mut s, a, frame).ret(), 0, "{frame}");
    }
}

#[test]
fn only_control_take_failsafe_overrides_a_failsafe() {
    let (mut s, mut ss) = vehicle(1);
    let a = &mut ss[0];
    s.backend_mut().failsafe = Some(Failsafe {
        detail: "RTL",
        ..Failsafe::new("autopilot", Action::Rtl)
    });
    let plain = send(&mut s, a, "control_take");
    assert_eq!(
        (plain.ret(), plain.msg()),
        (
            -1,
            "Vehicle is in failsafe (autopilot: RTL): control_take failsafe overrides it"
        )
    );
    assert_eq!(send(&mut s, a, "control_take failsafe").ret(), 0);
    assert_eq!(send(&mut s, a, "set_sp_ned 1:1:-2:0").ret(), 0);
    assert_eq!(
        send(&mut s, a, "state").json()["state"]["failsafe"],
        "autopilot: RTL (overridden)"
    );
}

#[test]
fn abort_report_steers_only_while_a_mission_runs() {
    let (mut s, mut ss) = vehicle(2);
    let [a, b] = &mut ss[..] else { unreachable!() };
    assert_eq!(send(&mut s, a, "mw_exec 1:1").ret(), 0);
    s.backend_mut().mission_running = true;
    assert_eq!(send(&mut s, b, "abort_report").ret(), -1);
    s.backend_mut().mission_running = false;
    assert_eq!(
        send(&mut s, b, "abort_report").ret(),
        0,
        "closing a report steers nothing"
    );
    assert_eq!(
        send(&mut s, a, "control").json()["control"]["you"],
        true,
        "and takes no control"
    );
    // A running mission's abort steers: a failsafe refuses it, even to the
    // pilot.
    s.backend_mut().mission_running = true;
    s.backend_mut().failsafe = Some(BATTERY_LOW);
    assert_eq!(
        send(&mut s, a, "abort_report").msg(),
        "Vehicle is in failsafe (battery_low): land, rtl or control_take failsafe"
    );
}

#[test]
fn state_says_who_flies_and_no_failsafe() {
    let (mut s, mut ss) = vehicle(1);
    let a = &mut ss[0];
    let before = send(&mut s, a, "state");
    assert_eq!(before.json()["state"]["control"], serde_json::Value::Null);
    assert_eq!(before.json()["state"]["failsafe"], serde_json::Value::Null);
    assert_eq!(send(&mut s, a, "takeoff").ret(), 0);
    assert_eq!(
        send(&mut s, a, "state").json()["state"]["control"],
        serde_json::json!({"by": "ws 192.0.2.7:51000 #1", "since": TS})
    );
}

#[test]
fn uplink_sessions_are_labelled_by_their_client_id() {
    let mut s = server(None);
    let mut op = s.open_via(None, Via::Uplink("alice"));
    let mut ws = Session::new();
    assert_eq!(send(&mut s, &mut op, "takeoff").ret(), 0);
    assert_eq!(
        send(&mut s, &mut ws, "set_sp_ned 1:1:-2:0").msg(),
        format!("Vehicle is flown by mqtt alice since {TS}: control_take to take over")
    );
}

#[test]
fn no_gate_refuses_a_conservative_command_while_control_is_held_elsewhere() {
    for spec in TABLE.iter().filter(|s| s.class.conservative()) {
        let (mut s, mut ss) = vehicle(2);
        let [pilot, other] = &mut ss[..] else {
            unreachable!()
        };
        s.backend_mut().armed = true;
        assert_eq!(send(&mut s, pilot, "set_sp_ned 1:1:-2:0").ret(), 0);
        assert_eq!(send(&mut s, other, spec.name()).ret(), 0, "{}", spec.name());
    }
}

#[test]
fn labels_say_who_without_secrets() {
    let mut s = server(None);
    let label = |s: &mut TestServer, via| s.open_via(None, via).label().as_str().to_owned();
    assert_eq!(
        label(&mut s, Via::WebSocket("192.0.2.7:51234")),
        "ws 192.0.2.7:51234 #1"
    );
    assert_eq!(
        label(&mut s, Via::WebSocket("[2001:db8::1]:40000")),
        "ws [2001:db8::1]:40000 #2"
    );
    assert_eq!(label(&mut s, Via::Uplink("alice")), "mqtt alice");
    assert_eq!(label(&mut s, Via::Local), "local #4");
    let widest = "[ffff:ffff:ffff:ffff:ffff:ffff:ffff:ffff]:65535";
    assert_eq!(
        label(&mut s, Via::WebSocket(widest)),
        format!("ws {widest} #5"),
        "the longest address fits"
    );
    let long_client = "é".repeat(40);
    let cut = label(&mut s, Via::Uplink(&long_client));
    assert!(
        cut.len() <= lluav_core::authority::MAX_LABEL_LEN && cut.starts_with("mqtt é"),
        "{cut}"
    );
}
