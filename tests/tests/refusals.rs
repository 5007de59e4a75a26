//! Wrong requests as a client sees them from lluavd (DESIGN.md, "Errors"
//! and "Security defaults"): what does not exist, a waypoint that is not
//! an object and a path to the daemon's own files are all -2 `Invalid
//! arguments: <reason>`, the reason in the protocol's words and never a
//! file's content.

use lluav_tests::{Conn, Lluavd, Options};
use serde_json::Value;

const PASSWORD: &str = "s3cret";

/// Sends `frame` and returns `(ret, msg)`.
async fn answer(c: &mut Conn, frame: &str) -> (i64, String) {
    let r: Value = c.request(frame).await;
    (
        r["ret"].as_i64().unwrap_or(0),
        r["msg"].as_str().unwrap_or("").to_owned(),
    )
}

fn invalid(why: &str) -> (i64, String) {
    (-2, format!("Invalid arguments: {why}"))
}

#[tokio::test]
async fn what_does_not_exist_is_a_wrong_request() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let r = c
        .request(r#"mission 1001:{"waypoints":[{"x":1,"y":0,"z":-2},{"x":2,"y":0,"z":-2}]}"#)
        .await;
    assert_eq!(r["ret"], 0, "{r}");
    for (frame, why) in [
        ("rm_map nosuch", "nosuch does not exist"),
        ("set_mappath nosuch", "nosuch does not exist"),
        ("mw_exec 9999:1", "unknown mission 9999"),
        ("mw_exec 1001:4", "mission 1001 has no waypoint 4"),
        ("dump_missionresult 9999", "no run of mission 9999"),
        ("rm_imagedir nosuch", "nosuch does not exist"),
        (
            "mission 2:missions/nosuch.json",
            "missions/nosuch.json does not exist",
        ),
    ] {
        assert_eq!(answer(&mut c, frame).await, invalid(why), "{frame}");
    }
}

#[tokio::test]
async fn waypoints_are_objects_and_mission_reasons_speak_the_protocol() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let not_an_object = r#"waypoint 1: not an object {"x":..,"y":..,"z":..}"#;
    for (frame, why) in [
        ("mission 1:[[2,0,-3,0]]", not_an_object),
        (r#"mission 1:{"waypoints":[[2,0,-3,0]]}"#, not_an_object),
        (
            r#"mission 1:[{"x":1,"y":0,"z":-2},{"y":0,"z":-2}]"#,
            r#"waypoint 2: missing "x""#,
        ),
        (
            r#"mission 1:[{"x":"1","y":0,"z":-2}]"#,
            r#"waypoint 1: "x" is not a number"#,
        ),
        (
            r#"mission 1:[{"x":1e400,"y":0,"z":-2}]"#,
            r#"waypoint 1: "x" out of range (a 64-bit float: -1.7976931348623157e308..1.7976931348623157e308)"#,
        ),
        // "The last one wins" would fly a z nobody reading the first saw.
        (
            r#"mission 1:[{"x":1,"y":0,"z":-2,"z":-0.1}]"#,
            r#"waypoint 1: duplicate member "z""#,
        ),
        (
            r#"mission 1:{"waypoints":[{"x":1,"y":0,"z":-2}],"waypoints":[]}"#,
            r#"duplicate member "waypoints""#,
        ),
    ] {
        assert_eq!(answer(&mut c, frame).await, invalid(why), "{frame}");
    }
    assert_eq!(
        c.request("mw_list").await["ext_id"],
        Value::Null,
        "nothing stored"
    );
}

#[tokio::test]
async fn client_paths_never_reach_the_daemons_own_files() {
    let dir = tempfile::tempdir().expect("temp dir");
    // A saved password, so that passwd can change it (one is kept in the
    // data directory).
    std::fs::write(dir.path().join("password"), PASSWORD).expect("password saved");
    let daemon = Lluavd::start(dir.path(), &Options::default());
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    for frame in [
        "passwd 12345x",
        "set_param takeoff_alt:3",
        "save_param 1",
        "savemap m1",
        "set_mappath m1",
    ] {
        assert_eq!(c.request(frame).await["ret"], 0, "{frame}");
    }
    for file in ["password", "params.json", "state.json", "maps/m1"] {
        for command in ["test_listwp ", "mission 1:", "ai1_mission t:"] {
            let frame = format!("{command}{file}");
            assert_eq!(
                answer(&mut c, &frame).await,
                invalid(&format!("{file} is not in missions/")),
                "{frame}"
            );
        }
    }
    // Links do not lead out of the client areas either, and a file that
    // is not a mission is refused without a word of its content.
    let missions = dir.path().join("missions");
    std::os::unix::fs::symlink(dir.path().join("password"), missions.join("pw")).expect("link");
    std::fs::write(missions.join("notes.json"), r#"{"takeoff_alt": 12345}"#).expect("file");
    assert_eq!(
        answer(&mut c, "test_listwp missions/pw").await,
        invalid("missions/pw leads outside maps/, images/, bags/, logs/ and missions/")
    );
    let (ret, msg) = answer(&mut c, "test_listwp missions/notes.json").await;
    assert_eq!(ret, -2, "{msg}");
    assert!(!msg.contains("takeoff_alt") && !msg.contains("12345"), "{msg}");
    for listing in ["list_maps", "list_imagedir"] {
        let r = c.request(listing).await;
        assert!(!r.to_string().contains("password"), "{listing}: {r}");
    }
}

#[tokio::test]
async fn savemap_onto_a_directory_is_a_wrong_request() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    std::fs::create_dir(dir.path().join("maps/site")).expect("a directory among the maps");
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(
        answer(&mut c, "savemap site").await,
        invalid("site is a directory, not a map file")
    );
    assert!(dir.path().join("maps/site").is_dir(), "left as it was");
}

#[tokio::test]
async fn passwd_says_why_it_refuses_a_special_login_value() {
    let dir = tempfile::tempdir().expect("temp dir");
    std::fs::write(dir.path().join("password"), PASSWORD).expect("password saved");
    let daemon = Lluavd::start(dir.path(), &Options::default());
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    for value in ["1025", "0315"] {
        assert_eq!(
            answer(&mut c, &format!("passwd {value}")).await,
            invalid("the admin and logout values cannot be passwords"),
            "{value}"
        );
    }
    assert_eq!(
        answer(&mut c, "passwd two words").await,
        (-2, "Invalid arguments, usage: passwd new_password".into())
    );
    c.close().await;
    let mut c = Conn::connect(&daemon.url).await;
    assert_eq!(
        c.request(&format!("login {PASSWORD}")).await["ret"],
        0,
        "unchanged"
    );
}
