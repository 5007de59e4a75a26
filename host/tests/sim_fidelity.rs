//! Answers a client written against the specification and DESIGN.md can
//! rely on: numbers, error codes, whole reasons, map paths, mission
//! shapes, what clearing keeps, and who may change the password.

mod sim_support;

use serde_json::{Value, json};
use sim_support::Harness;

#[test]
fn f32_values_read_back_in_their_shortest_form() {
    let mut h = Harness::new(1.0);
    h.airborne();
    let r = h.ok("set_sp_ned 0.1:0.2:-3.3:0.7");
    let sp = json!({"x": 0.1, "y": 0.2, "z": -3.3, "yaw": 0.7});
    assert_eq!(r["sp"], sp);
    assert_eq!(h.ok("show_sp")["sp"], sp);
    assert_eq!(h.state()["setpoint"], sp);
    h.run_for(10.0);
    let s = h.state();
    assert_eq!(
        (&s["position"], &s["yaw"]),
        (&json!({"x": 0.1, "y": 0.2, "z": -3.3}), &json!(0.7))
    );
    assert_eq!(s["altitude"], 3.3);
}

#[test]
fn test_wp_and_relocate_pos_echo_the_numbers_sent() {
    let mut h = Harness::new(1.0);
    let r = h.ok("test_wp 0.1:0.2:0.3");
    assert_eq!(r["reachable"], false);
    assert_eq!(r["reason"], "altitude -0.3 m below min_alt 0.5 m");
    h.ok("set_maplocate 1");
    let r = h.ok("relocate_pos 0.1,0.2,0,0.7");
    assert_eq!(
        (&r["position"], &r["yaw"]),
        (&json!({"x": 0.1, "y": 0.2, "z": 0.0}), &json!(0.7))
    );
}

#[test]
fn values_the_vehicle_refuses_are_invalid_arguments_and_state_is_minus_one() {
    let mut h = Harness::new(1.0);
    for (frame, msg) in [
        ("get_param warp", "Invalid arguments: unknown parameter warp"),
        ("set_param warp:1", "Invalid arguments: unknown parameter warp"),
        (
            "set_param max_alt:0",
            "Invalid arguments: max_alt 0 out of range 1..500",
        ),
        (
            "set_param rtl_land:maybe",
            "Invalid arguments: rtl_land expects bool, got 'maybe'",
        ),
        ("apron_vol 60.5", "Invalid arguments: voltage 60.5 above 60"),
        ("apron_amp 30.5", "Invalid arguments: amperage 30.5 above 30"),
        (
            "utg_set 20001",
            "Invalid arguments: UTG sonic speed 20001 above 20000",
        ),
    ] {
        assert_eq!(h.fails(frame, -2), msg, "{frame}");
    }
    h.airborne();
    assert_eq!(
        h.fails("zyhk 2,0", -2),
        "Invalid arguments: zyhk height 0 must be above 0"
    );
    h.ok("land");
    h.run_until_fsm("disarmed", 20.0);
    assert_eq!(h.fails("rtl", -1), "Vehicle is not flying");
}

#[test]
fn reasons_are_whole_however_long() {
    let mut h = Harness::new(1.0);
    let name = format!("{}mission.json", "a_very_long_mission_directory_name/".repeat(4));
    let msg = h.fails(&format!("mission 1:missions/{name}"), -2);
    assert_eq!(msg, format!("Invalid arguments: missions/{name} does not exist"));
    assert!(msg.len() > 96, "longer than a cut reason would be");
}

#[test]
fn a_failed_stat_other_than_not_found_is_a_system_failure() {
    let mut h = Harness::new(1.0);
    h.ok("savemap m1");
    // m1 is a file, so m1/x fails with ENOTDIR, not ENOENT.
    assert!(
        h.fails("set_mappath m1/x", -3)
            .starts_with("stat maps/m1/x: Not a directory")
    );
    std::fs::write(h.dir.join("missions/m1"), "{}").unwrap();
    assert!(
        h.fails("mission 1:missions/m1/x", -3)
            .starts_with("stat missions/m1/x: ")
    );
    assert_eq!(
        h.fails("set_mappath m2", -2),
        "Invalid arguments: m2 does not exist"
    );
}

#[test]
fn map_paths_are_relative_to_the_map_directory() {
    let mut h = Harness::new(1.0);
    h.ok("savemap m1");
    assert_eq!(h.ok("set_mappath m1")["map_path"], "m1");
    assert_eq!(h.ok("list_maps")["maps"][0]["name"], "m1");
    assert_eq!(h.ok("get_submap_info")["kfs"]["map_id"], "m1");
    std::fs::create_dir(h.dir.join("maps/site")).unwrap();
    std::fs::write(h.dir.join("maps/site/north"), "{}").unwrap();
    assert_eq!(h.ok("set_mappath site/north")["map_path"], "site/north");
    assert_eq!(h.ok("rm_map m1")["removed"], "m1");
    assert!(!h.dir.join("maps/m1").exists());
}

#[test]
fn hud1_and_get_submap_info_share_one_kfs_shape() {
    let mut h = Harness::new(1.0);
    let shape = |v: &Value| {
        let kfs = v["kfs"].as_object().expect("kfs is an object").clone();
        (kfs.keys().cloned().collect::<Vec<_>>(), kfs["count"].is_u64())
    };
    let want = (vec!["map_id".to_owned(), "count".to_owned()], true);
    assert_eq!(shape(&h.ok("hud1")), want);
    assert_eq!(shape(&h.ok("get_submap_info")), want);
    h.ok("savemap m1");
    h.ok("set_mappath m1");
    assert_eq!(h.ok("hud1")["kfs"], h.ok("get_submap_info")["kfs"]);
}

#[test]
fn a_mission_may_be_a_top_level_array_of_waypoints() {
    let mut h = Harness::new(1.0);
    let r = h.ok(r#"mission 5:[{"x":1,"y":0,"z":-2},{"x":2,"y":0,"z":-2,"yaw":0.5}]"#);
    assert_eq!(
        (r["ext_id"].as_u64(), r["waypoints"].as_u64()),
        (Some(5), Some(2))
    );
    assert_eq!(h.ok("mw_list")["waypoints"][1]["yaw"], 0.5);
    assert_eq!(h.fails("mission 6:[]", -2), "Invalid arguments: no waypoints");
    assert_eq!(
        h.fails("mission 6:[[2,0,-3,0]]", -2),
        r#"Invalid arguments: waypoint 1: not an object {"x":..,"y":..,"z":..}"#,
        "an array is never read positionally as a waypoint"
    );
}

#[test]
fn clear_images_never_deletes_the_directory_being_written() {
    let mut h = Harness::new(1.0);
    let today = h.ok("capture")["dir"].as_str().unwrap().to_owned();
    assert_eq!(
        today, "20240427",
        "the capture directory of the request's UTC day"
    );
    std::fs::create_dir(h.dir.join("images/20240426")).unwrap();
    assert_eq!(h.ok("clear_images")["removed"], json!(["20240426"]));
    assert_eq!(h.ok("clear_images 1000000")["removed"], json!([]));
    assert!(h.dir.join("images").join(&today).is_dir());
    h.ok(&format!("rm_imagedir {today}"));
    assert!(!h.dir.join("images").join(&today).exists());
}

#[test]
fn clear_bags_never_deletes_the_bag_being_recorded() {
    let mut h = Harness::new(1.0);
    let bag = h.ok("savebag 1")["bag"].as_str().unwrap().to_owned();
    std::fs::write(h.dir.join("bags/old.bag"), "x").unwrap();
    assert_eq!(h.ok("clear_bags")["removed"], json!(["old.bag"]));
    assert_eq!(h.ok("clear_bags 1000000")["removed"], json!([]));
    assert!(h.dir.join("bags").join(&bag).is_file());
}

#[test]
fn a_password_pinned_by_the_configuration_is_not_changed_by_passwd() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("data");
    let mut h = Harness::open(&dir, 1.0, Some("pinned1"));
    h.ok("login pinned1");
    assert_eq!(
        h.fails("passwd other22", -1),
        "Password is set by the daemon's configuration"
    );
    assert_eq!(h.stored_password(), None);
    assert!(!dir.join("password").exists());
    assert_eq!(h.fails("login other22", -1), "Wrong password!");
    h.ok("login pinned1");
}
