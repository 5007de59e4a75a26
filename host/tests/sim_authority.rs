//! Flight authority on the simulator (DESIGN.md): one envelope for every
//! command that gives the vehicle a target, and failsafes that no motion
//! command cancels. Driven through lluav-core's server with simulated
//! time.

mod sim_support;

use serde_json::{Value, json};
use sim_support::Harness;

/// A vehicle with `min_alt` 1, `max_alt` 3 and `geofence_radius` 10,
/// hovering at 2 m over home.
fn boxed_in() -> Harness {
    let mut h = Harness::new(10.0);
    for p in ["min_alt:1", "max_alt:3", "geofence_radius:10"] {
        h.ok(&format!("set_param {p}"));
    }
    h.airborne();
    h
}

fn reason(h: &mut Harness, frame: &str) -> String {
    h.fails(frame, -2)
        .strip_prefix("Invalid arguments: ")
        .unwrap_or_else(|| panic!("{frame}: not a reason"))
        .to_owned()
}

#[test]
fn setpoints_inside_and_on_each_limit_are_flown_and_just_outside_refused() {
    let mut h = boxed_in();
    for frame in [
        "set_sp_ned 1:1:-2:0",
        "set_sp_ned 0:0:-1:0",
        "set_sp_ned 0:0:-3:0",
        "set_sp_ned 10:0:-2:0",
        "set_sp_ned 6:-8:-2:0",
    ] {
        assert_eq!(h.ok(frame)["tracking"], true, "{frame}");
    }
    for (frame, why) in [
        ("set_sp_ned 0:0:-0.99:0", "altitude 0.99 m below min_alt 1 m"),
        ("set_sp_ned 0:0:-0.0001:0", "altitude 0.0001 m below min_alt 1 m"),
        ("set_sp_ned 0:0:-3.01:0", "altitude 3.01 m above max_alt 3 m"),
        (
            "set_sp_ned 10.01:0:-2:0",
            "distance from home 10.1 m beyond geofence_radius 10 m",
        ),
    ] {
        assert_eq!(reason(&mut h, frame), why, "{frame}");
    }
    assert_eq!(
        h.ok("show_sp")["sp"],
        json!({"x": 6.0, "y": -8.0, "z": -2.0, "yaw": 0.0})
    );
}

#[test]
fn zyhk_heights_and_its_landing_point_are_checked_against_the_envelope() {
    let mut h = boxed_in();
    assert_eq!(reason(&mut h, "zyhk 2,3.5"), "altitude 3.5 m above max_alt 3 m");
    assert_eq!(reason(&mut h, "zyhk 0.5"), "altitude 0.5 m below min_alt 1 m");
    assert_eq!(
        reason(&mut h, "zyhk 2 11,0,0"),
        "distance from home 11 m beyond geofence_radius 10 m"
    );
    assert_eq!(h.ok("zyhk 1,3 10,0,0")["heights"], json!([1.0, 3.0]));
}

#[test]
fn mission_waypoints_are_checked_at_upload_and_again_at_mw_exec() {
    let mut h = boxed_in();
    let wp = |z: &str| format!(r#"mission 7:{{"waypoints":[{{"x":1,"y":0,"z":{z}}}]}}"#);
    for z in ["0", "-0.0", "-1e-50"] {
        assert_eq!(
            reason(&mut h, &wp(z)),
            "waypoint 1: altitude 0 m below min_alt 1 m",
            "z {z}"
        );
    }
    assert_eq!(
        reason(&mut h, &wp("-3.5")),
        "waypoint 1: altitude 3.5 m above max_alt 3 m"
    );
    h.ok(r#"mission 6:{"waypoints":[{"x":1,"y":0,"z":-1}]}"#);
    h.ok(&wp("-3"));
    h.ok(r#"mission 8:{"waypoints":[{"x":10,"y":0,"z":-1}]}"#);
    assert_eq!(
        reason(
            &mut h,
            r#"mission 9:{"waypoints":[{"x":1,"y":0,"z":-2},{"x":0,"y":10.01,"z":-2}]}"#
        ),
        "waypoint 2: distance from home 10.1 m beyond geofence_radius 10 m",
        "refused whole"
    );
    assert_eq!(
        reason(&mut h, "mw_exec 9:1"),
        "unknown mission 9",
        "nothing stored"
    );
    // The limits move on the ground; the stored missions no longer fit.
    h.ok("land");
    h.run_until_fsm("disarmed", 30.0);
    h.ok("set_param max_alt:2.5");
    h.ok("set_param geofence_radius:9");
    h.airborne();
    assert_eq!(
        reason(&mut h, "mw_exec 7:1"),
        "waypoint 1: altitude 3 m above max_alt 2.5 m"
    );
    assert_eq!(
        reason(&mut h, "mw_exec 8:1"),
        "waypoint 1: distance from home 10 m beyond geofence_radius 9 m"
    );
    assert_eq!(h.fsm(), "hover", "nothing was flown");
}

#[test]
fn an_ai1_mission_file_is_held_to_the_envelope_like_a_mission() {
    let mut h = boxed_in();
    let missions = h.dir.join("missions");
    std::fs::create_dir_all(&missions).expect("missions dir");
    std::fs::write(
        missions.join("high.json"),
        r#"[{"x":1,"y":0,"z":-2},{"x":1,"y":1,"z":-3.5}]"#,
    )
    .expect("written");
    std::fs::write(
        missions.join("edge.json"),
        r#"[{"x":6,"y":8,"z":-3},{"x":0,"y":0,"z":-1}]"#,
    )
    .expect("written");
    assert_eq!(
        reason(&mut h, "ai1_mission t1:missions/high.json"),
        "waypoint 2: altitude 3.5 m above max_alt 3 m"
    );
    assert_eq!(h.ok("ai1_mission t2:missions/edge.json")["task_id"], "t2");
}

#[test]
fn test_listwp_tells_each_waypoint_of_a_file_against_the_envelope() {
    let mut h = boxed_in();
    let missions = h.dir.join("missions");
    std::fs::create_dir_all(&missions).expect("missions dir");
    std::fs::write(
        missions.join("m.json"),
        r#"[{"x":0,"y":0,"z":-1},{"x":10,"y":0,"z":-3},{"x":0,"y":0,"z":-3.01},{"x":0,"y":10.01,"z":-2},{"x":0,"y":0,"z":-0.99}]"#,
    )
    .expect("written");
    let r = h.ok("test_listwp missions/m.json");
    assert_eq!(r["reachable"], false);
    assert_eq!(
        r["waypoints"],
        json!([
            {"id": 1, "reachable": true},
            {"id": 2, "reachable": true},
            {"id": 3, "reachable": false, "reason": "altitude 3.01 m above max_alt 3 m"},
            {"id": 4, "reachable": false, "reason": "distance from home 10.1 m beyond geofence_radius 10 m"},
            {"id": 5, "reachable": false, "reason": "altitude 0.99 m below min_alt 1 m"},
        ])
    );
}

#[test]
fn takeoff_and_return_climb_only_as_high_as_max_alt_and_say_so() {
    let mut h = Harness::new(10.0);
    h.ok("set_param max_alt:3");
    h.ok("set_param takeoff_alt:5");
    assert_eq!(h.ok("takeoff")["target_alt"], 3.0);
    h.run_until_fsm("hover", 20.0);
    assert!((h.state()["altitude"].as_f64().unwrap() - 3.0).abs() < 0.05);
    h.ok("set_sp_ned 5:0:-2:0");
    h.run_for(5.0);
    // rtl_alt is 10: the return climbs to 3 only.
    assert_eq!(h.ok("rtl")["return_alt"], 3.0);
    let mut highest: f64 = 0.0;
    while h.fsm() == "rtl" {
        highest = highest.max(h.state()["altitude"].as_f64().unwrap());
        h.run_for(0.5);
    }
    assert!(highest <= 3.0 + 1e-6, "climbed to {highest}");
    // The mission return alike.
    h.ok("set_sp_ned 5:0:-2:0");
    h.run_until_fsm("hover", 20.0);
    assert_eq!(h.ok("mrtl")["return_alt"], 3.0);
    // And no lower than min_alt.
    let mut low = Harness::new(10.0);
    low.ok("set_param min_alt:2.5");
    low.ok("set_param takeoff_alt:1");
    low.ok("set_param rtl_alt:2");
    assert_eq!(low.ok("takeoff")["target_alt"], 2.5);
    low.run_until_fsm("hover", 20.0);
    low.ok("set_sp_ned 3:0:-2.5:0");
    low.run_for(5.0);
    assert_eq!(low.ok("rtl")["return_alt"], 2.5);
}

#[test]
fn set_param_refuses_only_an_empty_envelope() {
    let mut h = Harness::new(1.0);
    h.ok("set_param max_alt:3");
    assert_eq!(
        reason(&mut h, "set_param min_alt:3"),
        "min_alt 3 m not below max_alt 3 m: no altitude would be left to fly"
    );
    h.ok("set_param min_alt:2.9");
    assert_eq!(
        reason(&mut h, "set_param max_alt:2"),
        "min_alt 2.9 m not below max_alt 2 m: no altitude would be left to fly"
    );
    // Other relations are settled by clipping, never refused.
    h.ok("set_param takeoff_alt:100");
    h.ok("set_param rtl_alt:100");
}

#[test]
fn test_wp_only_tests_and_says_why_a_point_is_outside() {
    let mut h = boxed_in();
    let r = h.ok("test_wp 1:0:0");
    assert_eq!(
        (r["reachable"].clone(), r["reason"].clone()),
        (json!(false), json!("altitude 0 m below min_alt 1 m"))
    );
    assert_eq!(h.ok("test_wp 1:0:-2")["reachable"], true);
    for frame in ["test_wp 0:0:-1", "test_wp 0:0:-3", "test_wp 6:8:-2"] {
        let r = h.ok(frame);
        assert_eq!(
            (&r["reachable"], &r["reason"]),
            (&json!(true), &Value::Null),
            "{frame}"
        );
    }
    for (frame, why) in [
        ("test_wp 0:0:-3.01", "altitude 3.01 m above max_alt 3 m"),
        (
            "test_wp 0:10.01:-2",
            "distance from home 10.1 m beyond geofence_radius 10 m",
        ),
    ] {
        let r = h.ok(frame);
        assert_eq!(
            (&r["reachable"], &r["reason"]),
            (&json!(false), &json!(why)),
            "{frame}"
        );
    }
    assert_eq!(h.fsm(), "hover", "testing flies nothing");
}

#[test]
fn relocate_pos_puts_a_vehicle_on_the_ground_inside_the_fence() {
    let mut h = Harness::new(1.0);
    h.ok("set_maplocate 1");
    h.ok("set_param geofence_radius:10");
    assert_eq!(
        reason(&mut h, "relocate_pos 1,2,-3,0.5"),
        "z -3 is not on the ground: relocate_pos places a vehicle on the ground (z 0)"
    );
    assert_eq!(
        reason(&mut h, "relocate_pos 30,0,0,0"),
        "distance from home 30 m beyond geofence_radius 10 m"
    );
    h.ok("relocate_pos 6,-8,0,0");
    assert_eq!(
        reason(&mut h, "relocate_pos 0,10.01,0,0"),
        "distance from home 10.1 m beyond geofence_radius 10 m"
    );
    h.ok("relocate_pos 1,2,0,0.5");
    assert_eq!(h.state()["altitude"], 0.0);
    assert_eq!(h.ok("takeoff")["target_alt"], 2.0);
    h.run_until_fsm("hover", 20.0);
    assert!((h.state()["altitude"].as_f64().unwrap() - 2.0).abs() < 0.05);
}

/// A vehicle whose battery drains 100 %/min with `low_battery` at 90: in
/// the air, it starts its low-battery return within seconds.
fn low_battery() -> Harness {
    let mut h = Harness::new(1.0);
    h.ok("set_param battery_drain:100");
    h.ok("set_param low_battery:90");
    h.ok("set_param rtl_alt:30");
    h.airborne();
    h.ok("set_sp_ned 20:0:-2:0");
    while h.state()["failsafe"].is_null() {
        h.run_for(0.1);
    }
    h
}

const LOW: &str = "Vehicle is in failsafe (battery_low): land, rtl or control_take failsafe";

#[test]
fn a_low_battery_return_refuses_every_motion_command_and_changes_nothing() {
    let mut h = low_battery();
    let s = h.state();
    assert_eq!(
        (s["failsafe"].clone(), s["fsm"].clone()),
        (json!("battery_low"), json!("rtl"))
    );
    h.ok(r#"mission 1:{"waypoints":[{"x":1,"y":0,"z":-2}]}"#);
    for frame in ["set_sp_ned 20:0:-4:0", "zyhk 2", "mw_exec 1:1"] {
        assert_eq!(h.fails(frame, -1), LOW, "{frame}");
        assert_eq!(h.fsm(), "rtl", "{frame}");
    }
    assert_eq!(h.fails("takeoff", -1), "Not allow when vehicle is ARMED!");
    // Neither a plain take-over.
    assert_eq!(
        h.fails("control_take", -1),
        "Vehicle is in failsafe (battery_low): control_take failsafe overrides it"
    );
}

#[test]
fn the_conservative_commands_run_during_a_low_battery_return() {
    for frame in ["land", "rtl", "mrtl", "tether_land", "disarm"] {
        let mut h = low_battery();
        assert_eq!(h.send(frame)["ret"], 0, "{frame}");
    }
}

#[test]
fn control_take_failsafe_overrides_and_an_empty_battery_starts_a_new_failsafe() {
    let mut h = low_battery();
    let taken = h.ok("control_take failsafe");
    assert_eq!(taken["control"]["you"], true);
    assert_eq!(h.state()["failsafe"], "battery_low (overridden)");
    assert_eq!(
        h.ok("set_sp_ned 5:0:-3:0")["tracking"],
        true,
        "the pilot flies again"
    );
    h.run_for(3.0);
    assert_eq!(h.fsm(), "hover", "the low battery does not start again");
    while h.state()["failsafe"] != "battery_empty" {
        assert_eq!(h.fsm(), "hover");
        h.run_for(0.5);
    }
    assert_eq!(h.fsm(), "landing");
    let empty = "Vehicle is in failsafe (battery_empty): land, rtl or control_take failsafe";
    assert_eq!(h.fails("set_sp_ned 5:0:-3:0", -1), empty);
    // A return would climb: only land, tether_land and disarm.
    let landing =
        "Vehicle is in failsafe (battery_empty): land, tether_land, disarm or control_take failsafe";
    assert_eq!(h.fails("rtl", -1), landing);
    assert_eq!(h.fails("mrtl", -1), landing);
    h.ok("land");
    h.run_until_fsm("disarmed", 30.0);
    assert_eq!(
        h.state()["failsafe"],
        Value::Null,
        "over once disarmed on the ground"
    );
}

#[test]
fn the_hold_after_a_takeoff_and_a_mission_is_no_failsafe() {
    let mut h = Harness::new(10.0);
    h.airborne();
    h.ok(r#"mission 1:{"waypoints":[{"x":2,"y":0,"z":-2}]}"#);
    h.ok("mw_exec 1:1");
    h.run_until_fsm("hover", 30.0);
    assert_eq!(h.state()["failsafe"], Value::Null);
    assert_eq!(h.ok("set_sp_ned 1:0:-2:0")["tracking"], true);
}
