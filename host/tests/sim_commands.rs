//! Every command of lluav-core's table that reaches the backend succeeds
//! under the simulator in a suitable state, and answers with the spec's
//! field names.

mod sim_support;

use lluav_core::{CommandId, Grammar, Spec, TABLE};
use serde_json::Value;
use sim_support::Harness;

/// Answered by the core itself; they never reach a backend.
const CORE_OWNED: [CommandId; 4] = [
    CommandId::Login,
    CommandId::Help,
    CommandId::AdminLock,
    CommandId::AdminUnlock,
];

const MISSION_FILE: &str = r#"{"waypoints":[{"x":1,"y":0,"z":-2},{"x":2,"y":1,"z":-2,"yaw":0.5}]}"#;

/// Arguments that make sense for a command of this grammar in the
/// fixture [`prepared`] builds.
fn sample_args(spec: &Spec) -> &'static str {
    match spec.grammar {
        Grammar::None | Grammar::OptCount | Grammar::OptAmount | Grammar::OptName => "",
        Grammar::Flag => "1",
        Grammar::Pwm => "1500",
        Grammar::Amount => "12.5",
        Grammar::Angle => "10",
        Grammar::Name => "t1",
        Grammar::Path if spec.id == CommandId::SetMappath => "t1",
        Grammar::Path => "missions/m.json",
        Grammar::Text => "p1",
        Grammar::TaskName => "survey east",
        Grammar::Secret | Grammar::NewPassword => "newpass1",
        Grammar::ParamName => "takeoff_alt",
        Grammar::SetParam => "takeoff_alt:3",
        Grammar::Setpoint => "1:2:-3:0.5",
        Grammar::Point => "1:2:-3",
        Grammar::Pose => "1,2,0,0.5",
        Grammar::Zyhk => "1.5,2",
        Grammar::Mission => r#"8:{"waypoints":[{"x":1,"y":0,"z":-2}]}"#,
        Grammar::MwExec => "7:1,2",
        Grammar::Ai1Mission => "task1:missions/m.json",
        Grammar::Override => "failsafe",
    }
}

/// A simulator with a map `t1`, an image directory `t1`, a mission file,
/// mission 7, map localisation on and a video on the camera's card.
fn prepared(airborne: bool) -> Harness {
    let mut h = Harness::new(1.0);
    std::fs::create_dir_all(h.dir.join("missions")).unwrap();
    std::fs::write(h.dir.join("missions/m.json"), MISSION_FILE).unwrap();
    std::fs::create_dir_all(h.dir.join("images/t1")).unwrap();
    std::fs::write(h.dir.join("images/t1/a.ppm"), "P6\n1 1\n255\n\0\0\0").unwrap();
    h.ok("savemap t1");
    h.ok(&format!("mission 7:{MISSION_FILE}"));
    h.ok("set_maplocate 1");
    h.ok("record");
    h.ok("record");
    if airborne {
        h.airborne();
    }
    h
}

fn frame(spec: &Spec) -> String {
    let args = sample_args(spec);
    if args.is_empty() {
        spec.name().to_owned()
    } else {
        format!("{} {args}", spec.name())
    }
}

#[test]
fn every_backend_command_succeeds_in_a_suitable_state() {
    let mut failures = Vec::new();
    for spec in TABLE.iter().filter(|s| !CORE_OWNED.contains(&s.id)) {
        let frame = frame(spec);
        let on_ground = prepared(false).send(&frame);
        assert_eq!(on_ground["cmd"], u8::from(spec.id), "{frame}: {on_ground}");
        if on_ground["ret"] == 0 {
            continue;
        }
        // Flight commands need the vehicle in the air; the armed gate keeps
        // the others on the ground.
        let in_air = spec.flags.run_on_arm().then(|| prepared(true).send(&frame));
        if in_air.as_ref().is_none_or(|v| v["ret"] != 0) {
            failures.push(format!("{frame}: ground {on_ground}, air {in_air:?}"));
        }
    }
    assert!(
        failures.is_empty(),
        "commands that never succeeded:\n{}",
        failures.join("\n")
    );
}

fn keys(v: &Value, wanted: &[&str]) {
    for k in wanted {
        assert!(v.get(k).is_some(), "missing {k}: {v}");
    }
}

#[test]
fn telemetry_answers_under_the_spec_field_names() {
    let mut h = Harness::new(1.0);
    keys(
        &h.ok("param")["param"],
        &["takeoff_alt", "cruise_speed", "rtl_land"],
    );
    keys(&h.ok("get_param rtl_alt"), &["param", "info"]);
    assert_eq!(h.ok("get_param rtl_alt")["param"]["rtl_alt"], 10.0);
    keys(&h.ok("ver")["version"], &["lluav", "backend"]);
    keys(
        &h.ok("sysinfo")["sysinfo"],
        &["uptime", "ram_total_MB", "ram_free_MB", "loads"],
    );
    assert!(h.ok("diskusage")["available_MB"].is_u64());
    keys(&h.ok("statics"), &["comm", "rosrecord", "stat", "node_boot_sec"]);
    keys(&h.ok("hud1"), &["kfs", "uav_pos_enu", "extra"]);
    keys(
        &h.ok("lidarpose")["lidar_pose"],
        &["x", "y", "z", "yaw", "roll", "pitch", "frame", "usec"],
    );
    keys(&h.ok("apron_state"), &["apron_status", "apron_comm"]);
    keys(&h.ok("mavlink_msgs")["mav_msgs"], &["HEARTBEAT", "ATTITUDE"]);
    keys(&h.ok("get_submap_info")["kfs"], &["map_id", "count"]);
    keys(&h.ok("show_sp")["sp"], &["x", "y", "z", "yaw"]);
    assert_eq!(h.ok("show_apguid2")["guid2"].as_str().unwrap().len(), 36);
    assert!(h.ok("showmsg")["msgs"].is_array());
}

#[test]
fn machineid_is_the_real_machine_id() {
    let mut h = Harness::new(1.0);
    let r = h.send("machineid");
    match std::fs::read_to_string("/etc/machine-id") {
        Ok(id) => assert_eq!(r["did"], id.trim()),
        Err(_) => assert_eq!(r["ret"], -3),
    }
}

#[test]
fn mavlink_counts_grow_with_simulated_time() {
    let mut h = Harness::new(10.0);
    h.run_for(1.0);
    let m = h.ok("mavlink_msgs")["mav_msgs"].clone();
    assert_eq!(
        (m["HEARTBEAT"].as_u64(), m["ATTITUDE"].as_u64()),
        (Some(10), Some(500))
    );
    h.ok("reboot_ap");
    assert_eq!(h.ok("mavlink_msgs")["mav_msgs"]["HEARTBEAT"], 0);
}

#[test]
fn showmsg_returns_the_newest_log_lines_newest_first_as_many_as_fit() {
    let mut h = Harness::new(1.0);
    for i in 0..5 {
        h.log.push(format!("line {i}"));
    }
    let r = h.ok("showmsg 2");
    assert_eq!(r["msgs"], serde_json::json!(["line 4", "line 3"]));
    assert_eq!(
        (&r["truncated"], &r["total"]),
        (&serde_json::json!(true), &serde_json::json!(5)),
        "a count leaves lines out too"
    );
    let r = h.ok("showmsg 0");
    assert_eq!(
        (r["msgs"].as_array().map(Vec::len), &r["truncated"]),
        (Some(0), &serde_json::json!(true))
    );
    let r = h.ok("showmsg 5");
    assert_eq!(
        (&r["truncated"], &r["total"]),
        (&serde_json::json!(false), &serde_json::json!(5))
    );
    let long = "x".repeat(10_000);
    for _ in 0..10 {
        h.log.push(long.clone());
    }
    let r = h.ok("showmsg 15");
    assert_eq!(r["truncated"], true, "ten lines of 10 kB do not all fit");
    let shown = r["msgs"].as_array().unwrap();
    assert!((1..10).contains(&shown.len()), "{}", shown.len());
    assert!(shown.iter().all(|l| l == long.as_str()), "the newest lines");
    let r = h.ok("savemsg");
    assert_eq!(r["count"], 15);
    let saved = std::fs::read_to_string(h.dir.join(r["file"].as_str().unwrap())).unwrap();
    assert!(saved.starts_with("line 0\nline 1\nline 2\nline 3\nline 4\nxxx"));
}

#[test]
fn led_commands_follow_enable_and_disable() {
    let mut h = Harness::new(1.0);
    assert_eq!(h.ok("ledpwm 300")["led"]["pwm"], 300);
    h.ok("leddisable");
    assert_eq!(h.fails("ledon", -1), "LED control is disabled: ledenable first");
    h.ok("ledenable");
    let led = h.ok("led_blink")["led"].clone();
    assert_eq!(
        (led["on"].as_bool(), led["blink"].as_bool()),
        (Some(true), Some(true))
    );
}

#[test]
fn apron_and_utg_refuse_values_the_devices_cannot_take() {
    let mut h = Harness::new(1.0);
    assert_eq!(h.ok("apron_vol 48")["apron_status"]["voltage"], 48.0);
    assert_eq!(
        h.fails("apron_vol 61", -2),
        "Invalid arguments: voltage 61 above 60"
    );
    assert_eq!(
        h.fails("apron_amp 31", -2),
        "Invalid arguments: amperage 31 above 30"
    );
    assert_eq!(
        h.fails("utg_set 0", -2),
        "Invalid arguments: UTG sonic speed must be above 0"
    );
    assert_eq!(h.ok("utg_set 6000")["utg"]["thickness_mm"], 10.2);
}

#[test]
fn relocate_pos_needs_map_localisation() {
    let mut h = Harness::new(1.0);
    assert_eq!(
        h.fails("relocate_pos 1,2,0,0.5", -1),
        "Map localization is disabled: set_maplocate 1 first"
    );
    h.ok("set_maplocate 1");
    h.ok("relocate_pos 1,2,0,0.5");
    let s = h.state();
    assert_eq!(
        (s["position"]["x"].as_f64(), s["yaw"].as_f64()),
        (Some(1.0), Some(0.5))
    );
    assert_eq!(h.ok("lidarpose")["lidar_pose"]["frame"], "map");
}

#[test]
fn preflight_enabled_blocks_takeoff_when_a_check_fails() {
    let mut h = Harness::new(1.0);
    h.ok("preflight_enable 1");
    h.ok("lidaronoff 0");
    assert_eq!(h.ok("preflight_check")["preflight"]["passed"], false);
    assert!(
        h.fails("takeoff", -1)
            .starts_with("Preflight check failed: lidar")
    );
    h.ok("lidaronoff 1");
    assert_eq!(h.ok("preflight_check")["preflight"]["passed"], true);
    h.ok("takeoff");
}

#[test]
fn reboot_commands_are_simulated() {
    let mut h = Harness::new(1.0);
    for frame in ["reboot_system", "poweroff_system", "reboot_node"] {
        let r = h.ok(frame);
        assert!(
            r.get("reboot").or(r.get("poweroff")).unwrap()["simulated"] == true,
            "{frame}: {r}"
        );
    }
}
