//! Answers are about what happened (DESIGN.md, "Request grammar"), as a
//! client sees them from lluavd: `wakeup` says whether the vehicle slept,
//! `takeoff` with the battery off and `rm_map` of the map in use are
//! refused with their reason, abort report ids are never reused,
//! `set_param` says `unsaved` as `get_param` and `save_param 0` do, no
//! number carries float noise, and a vehicle disarmed in the air falls.

use lluav_tests::{Conn, Lluavd, Options, wait_for_state};
use serde_json::{Value, json};

const PASSWORD: &str = "s3cret";

async fn daemon(speed: f64) -> (tempfile::TempDir, Lluavd, Conn) {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        sim_speed: Some(speed),
        ..Options::password(PASSWORD)
    };
    let daemon = Lluavd::start(dir.path(), &options);
    let conn = Conn::login(&daemon.url, PASSWORD).await;
    (dir, daemon, conn)
}

async fn ok(c: &mut Conn, frame: &str) -> Value {
    let r = c.request(frame).await;
    assert_eq!(r["ret"], 0, "{frame}: {r}");
    r
}

/// `(ret, msg)` of a refused request.
async fn refused(c: &mut Conn, frame: &str) -> (i64, String) {
    let r = c.request(frame).await;
    (
        r["ret"].as_i64().unwrap_or(0),
        r["msg"].as_str().unwrap_or("").to_owned(),
    )
}

#[tokio::test]
async fn wakeup_says_whether_the_vehicle_was_asleep_and_takeoff_follows_either_way() {
    let (_dir, _d, mut c) = daemon(10.0).await;
    assert_eq!(ok(&mut c, "wakeup").await["was_asleep"], false);
    ok(&mut c, "sleep").await;
    assert_eq!(ok(&mut c, "wakeup").await["was_asleep"], true);
    assert_eq!(ok(&mut c, "wakeup").await["was_asleep"], false);
    ok(&mut c, "takeoff").await;
    wait_for_state(&mut c, "hovering", |s| s["fsm"] == "hover").await;
    let r = ok(&mut c, "wakeup").await;
    assert_eq!((&r["was_asleep"], &r["fsm"]), (&json!(false), &json!("hover")));
}

#[tokio::test]
async fn takeoff_with_the_battery_switched_off_is_refused_and_nothing_flies() {
    let (_dir, _d, mut c) = daemon(10.0).await;
    ok(&mut c, "bms_setpower 0").await;
    assert_eq!(
        refused(&mut c, "takeoff").await,
        (-1, "Battery power is off: bms_setpower 1 first".into())
    );
    let s = ok(&mut c, "state").await;
    assert_eq!(
        (&s["state"]["armed"], &s["state"]["fsm"]),
        (&json!(false), &json!("disarmed"))
    );
    ok(&mut c, "bms_setpower 1").await;
    assert_eq!(ok(&mut c, "takeoff").await["fsm"], "takeoff");
}

#[tokio::test]
async fn rm_map_of_the_map_in_use_is_refused_and_map_locate_keeps_its_map() {
    let (dir, _d, mut c) = daemon(10.0).await;
    for frame in ["savemap site_a", "set_mappath site_a", "set_maplocate 1"] {
        ok(&mut c, frame).await;
    }
    assert_eq!(
        refused(&mut c, "rm_map site_a").await,
        (-1, "Map site_a is in use: set_mappath another map first".into())
    );
    assert!(dir.path().join("maps/site_a").is_file());
    assert_eq!(ok(&mut c, "get_submap_info").await["kfs"]["map_id"], "site_a");
    // Another map in use first, then the old one goes.
    for frame in ["savemap site_b", "set_mappath site_b", "rm_map site_a"] {
        ok(&mut c, frame).await;
    }
    assert!(!dir.path().join("maps/site_a").exists());
}

#[tokio::test]
async fn abort_report_ids_are_never_reused() {
    let (_dir, _d, mut c) = daemon(10.0).await;
    let id = |r: &Value| r["abort_report"]["abort_id"].as_u64();
    assert_eq!(id(&ok(&mut c, "abort_report").await), Some(1));
    assert_eq!(id(&ok(&mut c, "abort_report").await), Some(2));
    for used in [0, 2] {
        assert_eq!(
            refused(&mut c, &format!("abort_report {used}")).await,
            (
                -2,
                format!(
                    "Invalid arguments: abort_id {used} is not above the last one given, 2 (abort ids are never reused)"
                )
            ),
        );
    }
    assert_eq!(id(&ok(&mut c, "abort_report 7").await), Some(7));
    assert_eq!(id(&ok(&mut c, "abort_report").await), Some(8));
    assert_eq!(refused(&mut c, "abort_report 7").await.0, -2);
}

#[tokio::test]
async fn set_param_get_param_and_save_param_agree_on_what_is_unsaved() {
    let (_dir, _d, mut c) = daemon(10.0).await;
    // The saved value set again: nothing is unsaved.
    assert_eq!(ok(&mut c, "set_param takeoff_alt:2").await["unsaved"], false);
    assert_eq!(
        ok(&mut c, "get_param takeoff_alt").await["info"]["unsaved"],
        false
    );
    assert_eq!(ok(&mut c, "save_param 0").await["unsaved"], json!([]));
    assert_eq!(ok(&mut c, "set_param takeoff_alt:3").await["unsaved"], true);
    assert_eq!(ok(&mut c, "get_param takeoff_alt").await["info"]["unsaved"], true);
    assert_eq!(
        ok(&mut c, "save_param 0").await["unsaved"],
        json!(["takeoff_alt"])
    );
    assert_eq!(ok(&mut c, "set_param takeoff_alt:2.0").await["unsaved"], false);
    assert_eq!(ok(&mut c, "save_param 0").await["unsaved"], json!([]));
}

/// Every number in `v` with `0 < |n| <= 1e-6`, with where it is.
fn noise(v: &Value, at: &str, found: &mut Vec<String>) {
    match v {
        Value::Number(n) if n.as_f64().is_some_and(|f| f != 0.0 && f.abs() <= 1e-6) => {
            found.push(format!("{at} = {n}"));
        }
        Value::Array(items) => {
            for (i, item) in items.iter().enumerate() {
                noise(item, &format!("{at}[{i}]"), found);
            }
        }
        Value::Object(members) => {
            for (k, item) in members {
                noise(item, &format!("{at}.{k}"), found);
            }
        }
        _ => {}
    }
}

#[tokio::test]
async fn no_answer_carries_float_noise_after_a_flight_that_turned_back() {
    let (_dir, _d, mut c) = daemon(10.0).await;
    ok(&mut c, "takeoff").await;
    wait_for_state(&mut c, "hovering", |s| s["fsm"] == "hover").await;
    // Out and back with turns: arithmetic that lands next to zero.
    for (x, y, yaw) in [(1.0, 1.0, 2.5), (0.0, 0.0, 0.0)] {
        ok(&mut c, &format!("set_sp_ned {x}:{y}:-2:{yaw}")).await;
        wait_for_state(&mut c, "at the setpoint", |s| {
            let at = |v: &Value, want: f64| v.as_f64().is_some_and(|v| (v - want).abs() < 1e-3);
            at(&s["position"]["x"], x) && at(&s["position"]["y"], y) && at(&s["yaw"], yaw)
        })
        .await;
    }
    let mut found = Vec::new();
    for frame in ["state", "hud1", "lidarpose", "show_sp", "statics"] {
        let r = ok(&mut c, frame).await;
        noise(&r, frame, &mut found);
    }
    assert!(found.is_empty(), "{found:?}");
}

#[tokio::test]
async fn a_vehicle_disarmed_in_the_air_falls_and_state_shows_the_fall() {
    // Real time: from 30 m the fall takes about 2.5 s, far longer than a
    // `state` round trip.
    let (_dir, _d, mut c) = daemon(1.0).await;
    ok(&mut c, "set_param takeoff_alt:30").await;
    ok(&mut c, "set_param climb_speed:5").await;
    ok(&mut c, "takeoff").await;
    wait_for_state(&mut c, "hovering at 30 m", |s| {
        s["fsm"] == "hover" && s["velocity"]["z"].as_f64().is_some_and(|v| v.abs() < 0.5)
    })
    .await;
    let r = ok(&mut c, "disarm").await;
    assert_eq!(
        (&r["armed"], &r["fsm"]),
        (&json!(false), &json!("falling")),
        "{r}"
    );
    let s = ok(&mut c, "state").await["state"].clone();
    assert_eq!(
        (&s["armed"], &s["fsm"], &s["airborne"]),
        (&json!(false), &json!("falling"), &json!(true)),
        "{s}"
    );
    assert!(s["altitude"].as_f64().is_some_and(|a| a > 5.0), "still high: {s}");
    assert_eq!(
        refused(&mut c, "land").await,
        (-1, "Vehicle is falling: it was disarmed in the air".into())
    );
    let down = wait_for_state(&mut c, "on the ground", |s| s["fsm"] == "disarmed").await;
    assert_eq!(
        (&down["state"]["altitude"], &down["state"]["velocity"]["z"]),
        (&json!(0.0), &json!(0.0)),
        "{down}"
    );
}
