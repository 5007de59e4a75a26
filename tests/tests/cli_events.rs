//! `lluav events` against a real lluavd (DESIGN.md, "Events"): the events
//! of a flight flown by another session, in order, as JSON objects and as
//! lines for a person; a refused login ends it with status 1.

use lluav_tests::{Conn, Following, Lluavd, Options, wait_for_state};
use serde_json::{Value, json};

const PASSWORD: &str = "s3cret";

/// The name and the fields that say what happened.
fn gist(e: &Value) -> Value {
    let mut g = json!({"event": e["event"]});
    for key in ["from", "to", "armed"] {
        if let Some(v) = e.get(key) {
            g[key] = v.clone();
        }
    }
    g
}

#[tokio::test]
async fn lluav_events_prints_a_flight_in_order_as_json_and_as_lines() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(
        dir.path(),
        &Options::password(PASSWORD).with_args(&["--sim-speed", "10"]),
    );
    let json = Following::start(&["--url", &daemon.url, "--password", PASSWORD, "events", "--json"]);
    let text = Following::start(&["--url", &daemon.url, "--password", PASSWORD, "events"]);
    // Subscribed once the login is answered, which lluav says on stderr.
    json.stderr_until("following the events");
    text.stderr_until("following the events");

    let mut pilot = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(pilot.request("takeoff").await["ret"], 0);
    wait_for_state(&mut pilot, "hovering", |s| s["fsm"] == "hover").await;
    assert_eq!(pilot.request("land").await["ret"], 0);
    wait_for_state(&mut pilot, "landed", |s| s["armed"] == false).await;

    let expected = [
        json!({"event": "control", "from": null}),
        json!({"event": "fsm", "from": "disarmed", "to": "takeoff"}),
        json!({"event": "armed", "armed": true}),
        json!({"event": "fsm", "from": "takeoff", "to": "hover"}),
        json!({"event": "fsm", "from": "hover", "to": "landing"}),
        json!({"event": "fsm", "from": "landing", "to": "armed"}),
        json!({"event": "fsm", "from": "armed", "to": "disarmed"}),
        json!({"event": "armed", "armed": false}),
    ];
    let mut seen = Vec::new();
    let mut last_seq = 0;
    let task = tokio::task::spawn_blocking(move || {
        while seen.len() < expected.len() {
            let line = json.line().expect("a line");
            let e: Value = serde_json::from_str(&line).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
            assert_eq!(e["seq"], last_seq + 1, "seq counts on: {line}");
            last_seq = e["seq"].as_u64().expect("seq");
            assert!(e["boot"].is_string() && e["ts"].is_i64(), "{line}");
            if !matches!(e["event"].as_str(), Some("battery" | "log")) {
                seen.push(gist(&e));
            }
        }
        assert_eq!(seen, expected);
        // Ctrl-C ends it cleanly.
        assert_eq!(json.interrupt().code(), Some(0));

        let mut lines = Vec::new();
        while lines.len() < 8 {
            let line = text.line().expect("a line");
            if !line.contains(" battery ") && !line.contains(" log ") {
                lines.push(line);
            }
        }
        assert!(lines[0].contains(" #1 control by="), "{lines:?}");
        assert!(
            lines[1].ends_with(" #2 fsm from=disarmed to=takeoff"),
            "{lines:?}"
        );
        assert!(lines[2].ends_with(" armed armed=true"), "{lines:?}");
        // `YYYY-MM-DDTHH:MM:SS.mmmZ` first.
        assert_eq!(lines[1].find('Z'), Some(23), "{lines:?}");
        assert_eq!(text.interrupt().code(), Some(0));
    });
    task.await.expect("the checks");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn lluav_events_with_a_wrong_password_exits_1() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let wrong = Following::start(&["--url", &daemon.url, "--password", "nope", "events"]);
    let said = wrong.stderr_until("Wrong password");
    assert!(said.iter().any(|l| l.contains("/events")), "{said:?}");
    let none = Following::start(&["--url", &daemon.url, "events", "--json"]);
    none.stderr_until("this vehicle has a password");
    tokio::task::spawn_blocking(move || {
        assert_eq!(wrong.wait().code(), Some(1));
        assert_eq!(none.wait().code(), Some(1));
    })
    .await
    .expect("exits");
}
