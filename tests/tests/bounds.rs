//! Bounded by construction (DESIGN.md, "Request grammar"): every value a
//! client can store in lluavd, filled to its documented maximum with the
//! text that is longest once written as JSON, and then every command of
//! the table: none answers `Response too large`, and `state` answers.

use std::path::Path;

use lluav_core::{Grammar, TABLE};
use lluav_tests::{Conn, Lluavd, Options, wait_for_state};
use serde_json::Value;

const TOO_LARGE: &str = "Response too large";

/// A JSON string's worst case: every byte escaped (`"` becomes `\"`).
fn quotes(n: usize) -> String {
    "\"".repeat(n)
}

/// The longest number text: 17 significant digits and a 3-digit exponent.
const LONG: &str = "-1.2345678901234567e-300";

async fn ok(c: &mut Conn, frame: &str) -> Value {
    let r = c.request(frame).await;
    assert_eq!(r["ret"], 0, "{}: {r}", &frame[..frame.len().min(80)]);
    r
}

/// A relative path of `dirs` directories and a file, each component `n`
/// quotes (with a distinct lead), created under `root`; the path.
fn deep_file(root: &Path, dirs: usize, n: usize, content: &str) -> String {
    let parts: Vec<String> = (0..=dirs).map(|i| format!("{i}{}", quotes(n))).collect();
    let rel = parts.join("/");
    let file = root.join(&rel);
    std::fs::create_dir_all(file.parent().expect("a parent")).expect("dirs made");
    std::fs::write(&file, content).expect("file written");
    rel
}

/// An altitude (NED `z`) with as many significant digits as [`LONG`]
/// that stays inside the envelope `fill_parameters` leaves (`min_alt`
/// 1.4 m, `max_alt` 62 m): a waypoint outside it is refused (DESIGN.md,
/// "Flight authority"), and no altitude in it needs an exponent.
const LONG_Z: &str = "-12.345678901234567";

/// A mission of `n` waypoints, each member's number as long as it gets.
fn longest_mission(n: u32) -> String {
    let wps: Vec<String> = (0..n)
        .map(|i| {
            format!(
                r#"{{"id":{},"x":{LONG},"y":{LONG},"z":{LONG_Z},"yaw":{LONG}}}"#,
                u32::MAX - i
            )
        })
        .collect();
    format!(r#"{{"waypoints":[{}]}}"#, wps.join(","))
}

/// Files a client reaches through the areas: with long names, and more
/// than twice what one answer lists.
fn fill_areas(data: &Path) {
    for i in 0..500 {
        let name = format!("{i:04}{}", quotes(200));
        std::fs::write(data.join("maps").join(&name), "{}").expect("map");
        std::fs::write(data.join("bags").join(&name), "x").expect("bag");
        let dir = data.join("images").join(&name);
        std::fs::create_dir_all(&dir).expect("image dir");
        std::fs::write(dir.join("a.ppm"), "x").expect("image");
    }
}

/// Every parameter set to its longest value: the largest integer, a float
/// with 17 significant digits.
async fn fill_parameters(c: &mut Conn) {
    let all = ok(c, "param").await["param"].clone();
    for name in all.as_object().expect("parameters").keys() {
        let info = ok(c, &format!("get_param {name}")).await["info"].clone();
        let (min, max) = (
            info["min"].as_f64().unwrap_or(0.0),
            info["max"].as_f64().unwrap_or(1.0),
        );
        let value = match info["type"].as_str() {
            Some("float") => format!("{}", min + (max - min) * 0.123_456_789_012_345_67),
            Some("int") => format!("{max}"),
            _ => "1".to_owned(),
        };
        ok(c, &format!("set_param {name}:{value}")).await;
    }
}

/// Arguments for each command: the largest the grammar takes, or what
/// names the longest stored thing.
fn largest_args(name: &str, grammar: Grammar, paths: &Paths) -> String {
    match (name, grammar) {
        ("set_mappath", _) => paths.map.clone(),
        ("test_listwp", _) => paths.far.clone(),
        (_, Grammar::Mission) => format!("4294967295:{}", paths.mission),
        (_, Grammar::Ai1Mission) => format!("{}:{}", "t".repeat(64), paths.mission),
        (_, Grammar::None) => String::new(),
        (_, Grammar::Flag) => "1".into(),
        (_, Grammar::OptCount) => "4294967295".into(),
        (_, Grammar::Pwm) => "65535".into(),
        (_, Grammar::Amount | Grammar::OptAmount) => "0".into(),
        (_, Grammar::Angle) => "-89.99999".into(),
        (_, Grammar::Name | Grammar::OptName) => format!("q{}", quotes(127)),
        (_, Grammar::Path) => paths.map.clone(),
        (_, Grammar::Text) => quotes(4096),
        (_, Grammar::TaskName) => quotes(256),
        (_, Grammar::Secret) => "1025".into(),
        (_, Grammar::NewPassword) => "P".repeat(32),
        (_, Grammar::ParamName) => "geofence_radius".into(),
        (_, Grammar::SetParam) => "takeoff_alt:1.2345678901234567".into(),
        (_, Grammar::Setpoint) => "1.2345678:-1.2345678:-2.2345678:-1.2345678".into(),
        (_, Grammar::Point) => "1.2345678e30:-1.2345678e30:-1.2345678e30".into(),
        (_, Grammar::Pose) => "1.2345678,-1.2345678,-2.2345678,-1.2345678".into(),
        (_, Grammar::Zyhk) => vec!["1.2345678"; 32].join(","),
        (_, Grammar::Override) => "failsafe".into(),
        (_, Grammar::MwExec) => {
            let ids: Vec<String> = (1..=64).map(|i| i.to_string()).collect();
            format!("1:{}", ids.join(","))
        }
    }
}

/// Paths (relative, as a client sends them) to the longest stored things.
struct Paths {
    /// A map file under `maps/`, the path as long as it gets.
    map: String,
    /// A mission file of the most waypoints, each as long as it gets.
    mission: String,
    /// A mission file whose every waypoint is out of the fence.
    far: String,
}

#[tokio::test]
async fn with_every_stored_value_at_its_maximum_no_command_answers_response_too_large() {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        sim_speed: Some(50.0),
        ..Options::default()
    };
    let daemon = Lluavd::start(dir.path(), &options);
    let data = dir.path();
    fill_areas(data);
    let paths = Paths {
        map: deep_file(&data.join("maps"), 9, 100, "{}"),
        mission: format!(
            "missions/{}",
            deep_file(&data.join("missions"), 8, 100, &longest_mission(400))
        ),
        far: format!(
            "missions/far/{}",
            deep_file(
                &data.join("missions/far"),
                0,
                10,
                &longest_mission(400)
                    .replace(LONG_Z, LONG)
                    .replace(LONG, "-1.2345678901234567e300")
            )
        ),
    };
    let mut c = Conn::login(&daemon.url, "1025").await;
    fill_parameters(&mut c).await;
    for i in 0..100 {
        // Each plan is logged: the recent log fills with long lines, far
        // more than one answer holds.
        ok(&mut c, &format!("plan {}{i}", quotes(4090))).await;
        ok(&mut c, "unlock_plan").await;
    }
    for (frame, why) in [
        (format!("plan {}", quotes(4097)), "text longer than 4096 bytes"),
        (
            format!("set_taskname {}", quotes(257)),
            "task name longer than 256 bytes",
        ),
        (
            format!(
                "mission 7:{}",
                longest_mission(401).replace(LONG, "-1").replace(LONG_Z, "-2")
            ),
            "more than 400 waypoints",
        ),
        (
            "mission 7:[[2,0,-3,0]]".to_owned(),
            r#"waypoint 1: not an object {"x":..,"y":..,"z":..}"#,
        ),
    ] {
        let r = c.request(&frame).await;
        let refused = (r["ret"].as_i64(), r["msg"].as_str());
        assert_eq!(
            refused,
            (Some(-2), Some(format!("Invalid arguments: {why}").as_str()))
        );
    }
    ok(&mut c, &format!("plan {}", quotes(4096))).await;
    ok(&mut c, &format!("set_taskname {}", quotes(256))).await;
    ok(&mut c, &format!("set_mappath {}", paths.map)).await;
    ok(&mut c, &format!("kill_livox q{}", quotes(127))).await;
    for _ in 0..2 * 300 {
        ok(&mut c, "record").await;
    }
    let videos = ok(&mut c, "siyi_sync").await["siyi"]["videos"].clone();
    assert_eq!(videos.as_array().map(Vec::len), Some(256), "the card keeps 256");
    ok(&mut c, "savebag 1").await;
    ok(&mut c, "set_maplocate 1").await;
    ok(&mut c, "takeoff").await;
    wait_for_state(&mut c, "hovering", |s| s["fsm"] == "hover").await;
    let wps: Vec<String> = (1..=64)
        .map(|i| format!(r#"{{"x":{},"y":0,"z":-2}}"#, f64::from(i) * 0.01))
        .collect();
    ok(
        &mut c,
        &format!(r#"mission 1:{{"waypoints":[{}]}}"#, wps.join(",")),
    )
    .await;
    ok(
        &mut c,
        &format!("mw_exec {}", largest_args("mw_exec", Grammar::MwExec, &paths)),
    )
    .await;
    for k in 0..16 {
        ok(&mut c, &format!("mission {}:{}", u32::MAX - k, paths.mission)).await;
    }
    ok(
        &mut c,
        &format!("ai1_mission {}:{}", "t".repeat(64), paths.mission),
    )
    .await;
    ok(&mut c, "admin_lock").await;

    let mut answered_whole = 0;
    for spec in &TABLE {
        let args = largest_args(spec.name(), spec.grammar, &paths);
        let frame = if args.is_empty() {
            spec.name().to_owned()
        } else {
            format!("{} {args}", spec.name())
        };
        assert!(
            lluav_core::parse(&frame).is_ok(),
            "`{}` must be valid",
            spec.name()
        );
        let r = c.request(&frame).await;
        assert_ne!(r["msg"], TOO_LARGE, "{}", spec.name());
        answered_whole += 1;
        let state = c.request("state").await;
        assert_eq!(state["ret"], 0, "state after {}: {state}", spec.name());
    }
    assert_eq!(answered_whole, lluav_core::TABLE.len());
    for (frame, list) in [
        ("showmsg 4294967295", "msgs"),
        ("list_maps", "maps"),
        ("list_imagedir", "imagedirs"),
    ] {
        let r = ok(&mut c, frame).await;
        assert_eq!(r["truncated"], true, "{frame} left entries out");
        assert!(r[list].as_array().is_some_and(|a| !a.is_empty()), "{frame}");
    }
    ok(&mut c, "disarm").await;
    for frame in ["clear_bags 1000000", "clear_images 1000000"] {
        let r = ok(&mut c, frame).await;
        assert_eq!(r["truncated"], true, "{frame} removed more than it lists: {r}");
    }
    let r = ok(&mut c, "mw_list").await;
    assert_eq!(
        r["waypoints"].as_array().map(Vec::len),
        Some(400),
        "one whole mission"
    );
    let r = ok(&mut c, "dump_missionlist").await;
    assert_eq!(
        r["missions"].as_array().map(Vec::len),
        Some(16),
        "every kept mission"
    );
}

#[tokio::test]
async fn lists_say_truncated_whenever_entries_were_left_out_a_count_included_and_their_total() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password("s3cret"));
    let mut c = Conn::login(&daemon.url, "s3cret").await;
    // Each answered set_param logs a line: more than showmsg's 50.
    for i in 0..60 {
        ok(&mut c, &format!("set_param cruise_speed:{}", 1 + i % 5)).await;
    }
    let r = ok(&mut c, "showmsg").await;
    let total = r["total"].as_u64().expect("total");
    assert!(total >= 60, "{r}");
    assert_eq!(
        (r["msgs"].as_array().map(Vec::len), &r["truncated"]),
        (Some(50), &Value::Bool(true)),
        "50 of {total}"
    );
    let r = ok(&mut c, "showmsg 0").await;
    assert_eq!(
        (r["msgs"].as_array().map(Vec::len), &r["truncated"]),
        (Some(0), &Value::Bool(true)),
        "{r}"
    );
    assert!(r["total"].as_u64().is_some_and(|t| t >= total), "{r}");
    let r = ok(&mut c, "showmsg 4294967295").await;
    assert_eq!(r["truncated"], false, "every line fits: {r}");
    assert_eq!(r["msgs"].as_array().map(|a| a.len() as u64), r["total"].as_u64());

    for name in ["day1", "day2"] {
        std::fs::create_dir(dir.path().join("images").join(name)).expect("image dir");
    }
    for (frame, shown, truncated) in [
        ("list_imagedir 0", 0, true),
        ("list_imagedir 1", 1, true),
        ("list_imagedir 2", 2, false),
        ("list_imagedir", 2, false),
    ] {
        let r = ok(&mut c, frame).await;
        assert_eq!(
            (
                r["imagedirs"].as_array().map(Vec::len),
                &r["truncated"],
                &r["total"]
            ),
            (Some(shown), &Value::Bool(truncated), &Value::from(2)),
            "{frame}: {r}"
        );
    }
    let r = ok(&mut c, "list_maps").await;
    assert_eq!(
        (&r["truncated"], &r["total"]),
        (&Value::Bool(false), &Value::from(0))
    );
}
