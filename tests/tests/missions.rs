//! The mission store as a client sees it from lluavd (DESIGN.md, "Request
//! grammar"): it never drops the mission that is running, that mission's
//! `ext_id` cannot be uploaded again while it runs, and `ai1_mission`
//! tasks are listed by their own task id.

use lluav_tests::{Conn, Lluavd, Options, wait_for_state};
use serde_json::Value;

const PASSWORD: &str = "s3cret";

async fn ok(c: &mut Conn, frame: &str) -> Value {
    let r = c.request(frame).await;
    assert_eq!(r["ret"], 0, "{frame}: {r}");
    r
}

/// Two waypoints far out: at 2 m/s the run lasts minutes of simulated
/// time, so it is still running whatever the machine's load.
const FAR: &str = r#"[{"id":1,"x":400,"y":0,"z":-3},{"id":2,"x":0,"y":400,"z":-3}]"#;
const NEAR: &str = r#"[{"id":1,"x":1,"y":0,"z":-3}]"#;

#[tokio::test]
async fn the_running_mission_is_never_dropped_nor_replaced_and_ai1_tasks_keep_their_own_id() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    std::fs::write(dir.path().join("missions/survey.json"), NEAR).expect("mission file");
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    ok(&mut c, "takeoff").await;
    wait_for_state(&mut c, "hovering", |s| s["fsm"] == "hover").await;
    ok(&mut c, &format!("mission 7000:{FAR}")).await;
    ok(&mut c, "mw_exec 7000:1,2").await;

    // A running mission's waypoints cannot change under the vehicle.
    let r = c.request(&format!("mission 7000:{NEAR}")).await;
    assert_eq!(
        (r["ret"].as_i64(), r["msg"].as_str()),
        (Some(-1), Some("Mission 7000 is running")),
        "{r}"
    );
    // More missions than the store keeps: the oldest others go, not 7000.
    for ext_id in 1..=17 {
        ok(&mut c, &format!("mission {ext_id}:{NEAR}")).await;
    }
    ok(&mut c, "ai1_mission survey-7:missions/survey.json").await;
    let r = ok(&mut c, "dump_missionlist").await;
    let listed = r["missions"].as_array().expect("missions");
    let ext_ids: Vec<u64> = listed.iter().filter_map(|m| m["ext_id"].as_u64()).collect();
    assert!(ext_ids.contains(&7000), "the running mission stays: {r}");
    assert_eq!(listed.len(), 16, "{r}");
    let ai1: Vec<&Value> = listed.iter().filter(|m| m["source"] == "ai1").collect();
    assert_eq!(ai1.len(), 1, "{r}");
    assert_eq!(ai1[0]["task_id"], "survey-7");
    assert!(ai1[0].get("ext_id").is_none(), "never a second ext_id 0: {r}");
    let r = ok(&mut c, "mw_list").await;
    assert_eq!(
        (&r["task_id"], r.get("ext_id")),
        (&"survey-7".into(), None),
        "{r}"
    );

    let r = ok(&mut c, "dump_missionresult 7000").await;
    assert_eq!(r["mission_result"]["status"], "running", "{r}");
    // What runs can be run again, by the id it runs under.
    ok(&mut c, "mw_exec 7000:2").await;
    // Once it no longer runs, its id takes a new mission.
    ok(&mut c, "abort_report").await;
    ok(&mut c, &format!("mission 7000:{NEAR}")).await;
}
