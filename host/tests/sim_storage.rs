//! What the simulator keeps on disk: parameters, the password, missions
//! from files, maps, images and bags — and that no client path leaves the
//! data directory.

mod sim_support;

use std::os::unix::fs::symlink;

use sim_support::Harness;

#[test]
fn set_param_validates_type_and_range_naming_the_parameter() {
    let mut h = Harness::new(1.0);
    assert_eq!(
        h.fails("set_param takeoff_alt:high", -2),
        "Invalid arguments: takeoff_alt expects float, got 'high'"
    );
    assert_eq!(
        h.fails("set_param takeoff_alt:500", -2),
        "Invalid arguments: takeoff_alt 500 out of range 0.5..120"
    );
    assert_eq!(
        h.fails("set_param autosleep_after:2.5", -2),
        "Invalid arguments: autosleep_after expects int, got '2.5'"
    );
    assert_eq!(
        h.fails("set_param warp_drive:1", -2),
        "Invalid arguments: unknown parameter warp_drive"
    );
    assert_eq!(
        h.fails("get_param warp_drive", -2),
        "Invalid arguments: unknown parameter warp_drive"
    );
    let r = h.ok("set_param takeoff_alt:5");
    assert_eq!(
        (r["param"]["takeoff_alt"].as_f64(), r["unsaved"].as_bool()),
        (Some(5.0), Some(true))
    );
    assert_eq!(h.ok("get_param takeoff_alt")["info"]["unsaved"], true);
}

#[test]
fn saved_parameters_survive_a_restart_and_unsaved_ones_do_not() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("data");
    {
        let mut h = Harness::open(&dir, 1.0, None);
        h.ok("set_param cruise_speed:4.5");
        h.ok("set_param rtl_land:0");
        assert_eq!(h.ok("save_param 1")["saved"], true);
        h.ok("set_param cruise_speed:1");
        h.flush();
    }
    let mut h = Harness::open(&dir, 1.0, None);
    let p = h.ok("param")["param"].clone();
    assert_eq!(
        (p["cruise_speed"].as_f64(), p["rtl_land"].as_bool()),
        (Some(4.5), Some(false))
    );
    assert_eq!(h.ok("get_param cruise_speed")["info"]["unsaved"], false);
}

#[test]
fn save_param_zero_saves_nothing_discards_nothing_and_names_the_unsaved() {
    let mut h = Harness::new(1.0);
    h.ok("set_param climb_speed:2");
    h.ok("save_param 1");
    h.ok("set_param climb_speed:3");
    h.ok("set_param yaw_rate:2");
    let r = h.ok("save_param 0");
    assert_eq!(r["saved"], false);
    assert_eq!(r["unsaved"], serde_json::json!(["climb_speed", "yaw_rate"]));
    assert_eq!(h.ok("get_param climb_speed")["param"]["climb_speed"], 3.0);
    assert_eq!(h.ok("reset_param")["param"]["climb_speed"], 1.0);
    assert_eq!(
        h.ok("save_param 0")["unsaved"],
        serde_json::json!(["climb_speed"])
    );
    h.ok("save_param 1");
    assert_eq!(h.ok("save_param 0")["unsaved"], serde_json::json!([]));
}

#[test]
fn passwd_persists_the_password_for_the_next_start() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("data");
    {
        let mut h = Harness::open(&dir, 1.0, None);
        h.ok("passwd first1");
        h.ok("passwd second2");
        assert_eq!(h.stored_password().as_deref(), Some("second2"));
    }
    let mut h = Harness::open(&dir, 1.0, None);
    assert_eq!(h.stored_password().as_deref(), Some("second2"));
    assert_eq!(h.fails("state", -1), "Login first!");
    h.ok("login second2");
    let file = h.dir.join("password");
    use std::os::unix::fs::PermissionsExt;
    assert_eq!(
        std::fs::metadata(file).unwrap().permissions().mode() & 0o777,
        0o600
    );
}

#[test]
fn symlinks_leaving_the_client_areas_are_refused() {
    let outside = tempfile::tempdir().unwrap();
    std::fs::write(
        outside.path().join("m.json"),
        r#"{"waypoints":[{"x":1,"y":0,"z":-2}]}"#,
    )
    .unwrap();
    std::fs::create_dir(outside.path().join("imgs")).unwrap();
    let mut h = Harness::new(1.0);
    symlink(outside.path(), h.dir.join("missions/escape")).unwrap();
    symlink(h.dir.join("params.json"), h.dir.join("missions/params.json")).unwrap();
    symlink(outside.path().join("m.json"), h.dir.join("maps/evil")).unwrap();
    symlink(outside.path(), h.dir.join("maps/escape")).unwrap();
    symlink(outside.path().join("imgs"), h.dir.join("images/evil")).unwrap();
    let refused = |m: String| {
        assert!(
            m.starts_with("Invalid arguments: ")
                && m.ends_with("leads outside maps/, images/, bags/, logs/ and missions/"),
            "{m}"
        )
    };
    refused(h.fails("mission 1:missions/escape/m.json", -2));
    refused(h.fails("ai1_mission t:missions/escape/m.json", -2));
    refused(h.fails("test_listwp missions/escape/m.json", -2));
    refused(h.fails("test_listwp missions/params.json", -2));
    refused(h.fails("set_mappath escape/m.json", -2));
    refused(h.fails("rm_map evil", -2));
    refused(h.fails("savemap evil", -2));
    refused(h.fails("rm_imagedir evil", -2));
    assert!(outside.path().join("m.json").exists() && outside.path().join("imgs").exists());
    // Links are not listed, so nothing outside is shown or cleared.
    assert_eq!(h.ok("list_maps")["maps"], serde_json::json!([]));
    h.ok("clear_images");
    assert!(outside.path().join("imgs").exists());
}

#[test]
fn the_daemons_own_files_are_out_of_reach_and_never_quoted() {
    let mut h = Harness::new(1.0);
    h.ok("passwd 12345x");
    h.ok("set_param takeoff_alt:3");
    h.ok("save_param 1");
    for file in ["password", "params.json", "state.json", "sim_state.json"] {
        for frame in [
            format!("test_listwp {file}"),
            format!("mission 1:{file}"),
            format!("ai1_mission t:{file}"),
        ] {
            assert_eq!(
                h.fails(&frame, -2),
                format!("Invalid arguments: {file} is not in missions/"),
                "{frame}"
            );
        }
    }
    // A client's own file that is not a mission: the reason says where,
    // never what the file holds.
    std::fs::write(h.dir.join("missions/notes.json"), r#"{"takeoff_alt": 12345}"#).unwrap();
    assert_eq!(
        h.fails("test_listwp missions/notes.json", -2),
        r#"Invalid arguments: unexpected member (a mission object has only "waypoints")"#
    );
    std::fs::write(h.dir.join("missions/bad.json"), "12345x").unwrap();
    assert_eq!(
        h.fails("mission 1:missions/bad.json", -2),
        "Invalid arguments: not JSON (line 1, column 6)"
    );
}

#[test]
fn missions_are_accepted_from_json_or_files_and_refused_with_a_reason() {
    let mut h = Harness::new(1.0);
    let r = h.ok(r#"mission 3:{"waypoints":[{"x":1,"y":2,"z":-3,"yaw":0.5},{"id":9,"x":4,"y":5,"z":-6}]}"#);
    assert_eq!(
        (r["ext_id"].as_u64(), r["waypoints"].as_u64()),
        (Some(3), Some(2))
    );
    let wps = h.ok("mw_list")["waypoints"].clone();
    assert_eq!(wps[1]["id"], 9);
    assert_eq!(wps[0]["yaw"], 0.5);
    assert_eq!(
        h.fails(r#"mission 4:{"waypoints":[{"x":1,"y":2}]}"#, -2),
        r#"Invalid arguments: waypoint 1: missing "z""#
    );
    assert_eq!(
        h.fails("mission 4:missions/none.json", -2),
        "Invalid arguments: missions/none.json does not exist"
    );
    std::fs::write(
        h.dir.join("missions/a.json"),
        r#"{"waypoints":[{"x":0,"y":1,"z":-1}]}"#,
    )
    .unwrap();
    assert_eq!(h.ok("mission 4:missions/a.json")["waypoints"], 1);
    let list = h.ok("dump_missionlist")["missions"].clone();
    assert_eq!(list.as_array().unwrap().len(), 2);
    assert_eq!(list[1]["path"], "missions/a.json");
}

#[test]
fn mw_exec_flies_the_chosen_waypoints_and_records_the_result() {
    let mut h = Harness::new(1.0);
    h.ok(r#"mission 3:{"waypoints":[{"x":2,"y":0,"z":-2},{"x":2,"y":2,"z":-2},{"x":0,"y":2,"z":-2}]}"#);
    assert_eq!(h.fails("mw_exec 3:1,2", -1), "Vehicle is not flying");
    h.airborne();
    assert_eq!(
        h.fails("mw_exec 3:1,7,8", -2),
        "Invalid arguments: mission 3 has no waypoint 7,8"
    );
    assert_eq!(h.fails("mw_exec 4:1", -2), "Invalid arguments: unknown mission 4");
    assert_eq!(h.ok("mw_exec 3:3,1")["fsm"], "mission");
    assert_eq!(
        h.ok("dump_missionresult 3")["mission_result"]["status"],
        "running"
    );
    h.run_until_fsm("hover", 30.0);
    let result = h.ok("dump_missionresult")["mission_result"].clone();
    assert_eq!(result["status"], "completed");
    assert_eq!(result["reached"], serde_json::json!([3, 1]));
    let p = h.state()["position"].clone();
    assert!((p["x"].as_f64().unwrap() - 2.0).abs() < 0.31 && p["y"].as_f64().unwrap().abs() < 0.31);
    assert_eq!(
        h.fails("dump_missionresult 99", -2),
        "Invalid arguments: no run of mission 99"
    );
}

#[test]
fn setpoints_interrupt_and_abort_report_aborts_a_running_mission() {
    let mut h = Harness::new(1.0);
    h.ok(r#"mission 3:{"waypoints":[{"x":20,"y":0,"z":-2},{"x":20,"y":20,"z":-2}]}"#);
    h.airborne();
    h.ok("mw_exec 3:1,2");
    h.run_for(1.0);
    h.ok("set_sp_ned 0:0:-2:0");
    assert_eq!(
        h.ok("dump_missionresult")["mission_result"]["status"],
        "interrupted"
    );
    h.ok("mw_exec 3:1,2");
    let report = h.ok("abort_report 42")["abort_report"].clone();
    assert_eq!(
        (report["abort_id"].as_u64(), report["aborted"].as_bool()),
        (Some(42), Some(true))
    );
    assert_eq!(h.fsm(), "hover");
    assert_eq!(h.ok("dump_missionresult")["mission_result"]["status"], "aborted");
    assert_eq!(h.ok("abort_report")["abort_report"]["aborted"], false);
}

#[test]
fn plan_takes_the_lock_until_unlock_plan() {
    let mut h = Harness::new(1.0);
    assert_eq!(h.ok("plan survey north field")["plan_lock"], true);
    assert_eq!(h.fails("plan another", -1), "Plan locked: unlock_plan first");
    assert_eq!(h.state()["plan_lock"], true);
    h.ok("unlock_plan");
    h.ok("plan another");
}

#[test]
fn maps_are_files_that_can_be_listed_chosen_and_removed() {
    let mut h = Harness::new(1.0);
    h.ok("savemap site_a");
    h.ok("savemap site_b");
    let names: Vec<_> = h.ok("list_maps")["maps"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["name"].clone())
        .collect();
    assert_eq!(names, ["site_b", "site_a"], "newest first");
    let map: serde_json::Value =
        serde_json::from_slice(&std::fs::read(h.dir.join("maps/site_a")).unwrap()).unwrap();
    assert_eq!(map["name"], "site_a");
    h.ok("set_mappath site_a");
    assert_eq!(h.ok("get_submap_info")["kfs"]["map_id"], "site_a");
    assert_eq!(
        h.fails("set_mappath none", -2),
        "Invalid arguments: none does not exist"
    );
    assert_eq!(
        h.fails("rm_map site_a", -1),
        "Map site_a is in use: set_mappath another map first"
    );
    assert!(h.dir.join("maps/site_a").exists(), "the map in use stays");
    h.ok("set_mappath site_b");
    h.ok("rm_map site_a");
    assert_eq!(h.ok("get_submap_info")["kfs"]["map_id"], "site_b");
    assert_eq!(
        h.fails("rm_map site_a", -2),
        "Invalid arguments: site_a does not exist"
    );
    assert!(!h.dir.join("maps/site_a").exists());
}

#[test]
fn captures_make_image_files_that_can_be_listed_and_removed() {
    let mut h = Harness::new(1.0);
    let r = h.ok("capture");
    let dir = r["dir"].as_str().unwrap().to_owned();
    let files = r["files"].as_array().unwrap().clone();
    assert_eq!(files.len(), 2);
    let rgb = std::fs::read(h.dir.join("images").join(&dir).join(files[0].as_str().unwrap())).unwrap();
    assert!(rgb.starts_with(b"P6\n8 8\n255\n") && rgb.len() == 11 + 8 * 8 * 3);
    h.ok("snapshot");
    std::fs::create_dir(h.dir.join("images/older")).unwrap();
    let dirs = h.ok("list_imagedir")["imagedirs"].clone();
    assert_eq!(dirs.as_array().unwrap().len(), 2);
    let newest = h.ok("list_imagedir 1")["imagedirs"].clone();
    assert_eq!(newest.as_array().unwrap().len(), 1);
    assert_eq!(
        dirs[1]["files"].as_u64().unwrap() + dirs[0]["files"].as_u64().unwrap(),
        3
    );
    h.ok(&format!("rm_imagedir {dir}"));
    assert!(!h.dir.join("images").join(&dir).exists());
    assert_eq!(
        h.fails(&format!("rm_imagedir {dir}"), -2),
        format!("Invalid arguments: {dir} does not exist")
    );
}

#[test]
fn bags_record_poses_and_clear_bags_deletes_oldest_first() {
    let mut h = Harness::new(1.0);
    let bag = h.ok("savebag 1")["bag"].as_str().unwrap().to_owned();
    h.airborne();
    let r = h.ok("savebag 0");
    assert_eq!(
        (r["bag"].as_str(), r["recording"].as_bool()),
        (Some(bag.as_str()), Some(false))
    );
    let text = std::fs::read_to_string(h.dir.join("bags").join(&bag)).unwrap();
    assert!(text.lines().count() > 10 && text.contains(" takeoff"), "{text}");
    h.ok("land");
    h.run_until_fsm("disarmed", 20.0);
    std::fs::write(h.dir.join("bags/old.bag"), "x").unwrap();
    // With plenty of free space nothing needs to go; asking for more than
    // any disk has removes every bag.
    assert_eq!(h.ok("clear_bags 0")["removed"], serde_json::json!([]));
    let removed = h.ok("clear_bags 1000000")["removed"].as_array().unwrap().len();
    assert_eq!(removed, 2);
    assert_eq!(std::fs::read_dir(h.dir.join("bags")).unwrap().count(), 0);
}

#[test]
fn a_recording_bag_is_kept_by_clear_bags_and_flushed_on_shutdown() {
    let mut h = Harness::new(1.0);
    let bag = h.ok("savebag 1")["bag"].as_str().unwrap().to_owned();
    h.run_for(1.0);
    assert_eq!(h.ok("clear_bags")["removed"], serde_json::json!([]));
    h.flush();
    let text = std::fs::read_to_string(h.dir.join("bags").join(&bag)).unwrap();
    assert_eq!(text.lines().count(), 11, "header and ten samples: {text}");
}

#[test]
fn siyi_videos_download_into_the_data_dir() {
    let mut h = Harness::new(1.0);
    assert_eq!(h.fails("siyi_downvideo", -1), "No video on the SIYI card");
    assert_eq!(h.ok("record")["recording"], true);
    assert_eq!(h.ok("record")["vid"], 1);
    let r = h.ok("siyi_downvideo 1");
    assert!(h.dir.join(r["file"].as_str().unwrap()).is_file());
    h.ok("siyi_format");
    assert_eq!(
        h.fails("siyi_downvideo 1", -2),
        "Invalid arguments: no video 1 on the SIYI card"
    );
}

#[test]
fn test_listwp_reports_each_waypoint_against_the_fence() {
    let mut h = Harness::new(1.0);
    std::fs::write(
        h.dir.join("missions/wps.json"),
        r#"{"waypoints":[{"x":1,"y":0,"z":-2},{"x":9000,"y":0,"z":-2}]}"#,
    )
    .unwrap();
    let r = h.ok("test_listwp missions/wps.json");
    assert_eq!(r["reachable"], false);
    assert_eq!(r["waypoints"][0]["reachable"], true);
    assert!(
        r["waypoints"][1]["reason"]
            .as_str()
            .unwrap()
            .contains("geofence_radius")
    );
    let r = h.ok("test_wp 3:0:-4");
    assert_eq!(
        (r["reachable"].as_bool(), r["distance_m"].as_f64()),
        (Some(true), Some(5.0))
    );
    // A point on the ground is no target (min_alt).
    let r = h.ok("test_wp 3:4:0");
    assert_eq!(
        (r["reachable"].as_bool(), r["reason"].as_str()),
        (Some(false), Some("altitude 0 m below min_alt 0.5 m"))
    );
}
