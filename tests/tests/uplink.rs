//! lluavd's MQTT uplink against a real broker (Mosquitto, started here on
//! a free port with its own config): requests and gates per client id,
//! repeats, bad input, status and will, state publishing, broker restarts,
//! mqtts, credentials, bridged brokers, several vehicles, and the `lluav
//! --broker` command line. Needs `--features broker` (scripts/test-uplink.sh).

use std::collections::{HashMap, HashSet};
use std::os::unix::net::UnixDatagram;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use lluav_tests::broker::{BrokerOptions, Mosquitto, Mqtt, vehicle};
use lluav_tests::{Conn, Lluavd, Options, WAIT, lluav_bin, lluavd_bin, test_ca};
use rumqttc::QoS;
use serde_json::Value;

const PASSWORD: &str = "s3cret";

/// A vehicle without a password: allowed on the uplink only when asked.
fn open_vehicle() -> Options {
    Options::default().with_args(&["--allow-no-password"])
}

/// An operator subscribed to its answers from every vehicle.
async fn operator(broker: &Mosquitto, client: &str) -> Mqtt {
    let mut m = Mqtt::connect(broker, client).await;
    m.subscribe(&format!("lluav/+/res/{client}")).await;
    m
}

/// The response inside an answer envelope, its `ts` taken out (so two
/// answers can be compared).
fn without_ts(answer: &Value) -> Value {
    let mut r = answer["response"].clone();
    assert!(r["ts"].is_i64(), "no ts: {answer}");
    r.as_object_mut().expect("an object").remove("ts");
    r
}

fn without_ts_ws(response: &Value) -> Value {
    let mut r = response.clone();
    r.as_object_mut().expect("an object").remove("ts");
    r
}

/// Runs `lluav` with `args` and stdin `input`.
fn lluav(args: &[&str], input: &str) -> Output {
    let mut child = Command::new(lluav_bin())
        .args(args)
        .env_remove("LLUAV_PASSWORD")
        .env_remove("LLUAV_BROKER_PASSWORD")
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lluav runs");
    use std::io::Write as _;
    child
        .stdin
        .take()
        .expect("stdin")
        .write_all(input.as_bytes())
        .expect("stdin written");
    child.wait_with_output().expect("lluav ends")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Waits until `daemon` has said its uplink is down and the broker has
/// seen it try twice more since (no other client connects meanwhile), so
/// that what it logs about a broker that keeps refusing it can be judged.
async fn refused_again_and_again(broker: &Mosquitto, daemon: &Lluavd) {
    let attempts = || broker.log().matches("New connection from").count();
    let start = Instant::now();
    while !daemon.stderr().contains("uplink down") {
        assert!(start.elapsed() < WAIT, "never down:\n{}", daemon.stderr());
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let seen = attempts();
    while attempts() < seen + 2 {
        assert!(
            start.elapsed() < WAIT,
            "tried no more:\n{}\n{}",
            daemon.stderr(),
            broker.log()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// Waits until `state.uplink` over WebSocket says `want`.
async fn wait_uplink(daemon: &Lluavd, ws: &mut Conn, want: &str) {
    let start = Instant::now();
    loop {
        let r = ws.request("state").await;
        if r["state"]["uplink"] == want {
            return;
        }
        assert!(
            start.elapsed() < WAIT,
            "uplink never {want}: {r}\n{}",
            daemon.stderr()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

#[tokio::test]
async fn answers_through_the_broker_are_what_a_websocket_session_gets() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", Options::password(PASSWORD)).await;
    let mut op = operator(&broker, "op").await;
    let mut ws = Conn::connect(&daemon.url).await;
    let frames = [
        "state",
        "login wrong",
        &format!("login {PASSWORD}"),
        "help",
        "set_sp_ned 1:2",
        "bogus 1",
        "get_param takeoff_alt",
        "",
        "login 0315",
        "state",
    ];
    for (n, frame) in frames.iter().enumerate() {
        let answer = op.request("v1", "op", &format!("r{n}"), frame).await;
        assert_eq!(answer["id"], format!("r{n}"));
        let over_ws = ws.request(frame).await;
        assert_eq!(without_ts(&answer), without_ts_ws(&over_ws), "{frame:?}");
    }
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn gates_and_sessions_are_per_client_id() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        sim_speed: Some(10.0),
        ..Options::password(PASSWORD)
    };
    let daemon = vehicle(dir.path(), &broker, "v1", options).await;
    let mut a = operator(&broker, "alice").await;
    let mut b = operator(&broker, "bob").await;
    let ret = |v: &Value| v["response"]["ret"].clone();
    let msg = |v: &Value| v["response"]["msg"].clone();

    let login = a.request("v1", "alice", "1", &format!("login {PASSWORD}")).await;
    assert_eq!(login["response"]["logged_in"], true);
    assert_eq!(ret(&a.request("v1", "alice", "2", "takeoff").await), 0);
    // Bob is another session: not logged in because Alice is.
    assert_eq!(msg(&b.request("v1", "bob", "1", "land").await), "Login first!");
    // The armed gate reads the vehicle, whoever asks.
    let refused = a.request("v1", "alice", "3", "reboot_node").await;
    assert_eq!(msg(&refused), "Not allow when vehicle is ARMED!");
    // Admin is per session: Bob locks, Alice is refused what lock mode
    // forbids, Bob (admin) is not.
    assert_eq!(
        b.request("v1", "bob", "2", "login 1025").await["response"]["admin"],
        true
    );
    assert_eq!(ret(&b.request("v1", "bob", "3", "admin_lock").await), 0);
    let locked = a.request("v1", "alice", "4", "unlock_plan").await;
    assert_eq!(msg(&locked), "CMD not permitted to run in LOCK mode!");
    assert_eq!(
        msg(&a.request("v1", "alice", "5", "admin_unlock").await),
        "Admin only!"
    );
    assert_eq!(ret(&b.request("v1", "bob", "4", "admin_unlock").await), 0);
    // Logging out ends Alice's session; Bob's is untouched.
    assert_eq!(ret(&a.request("v1", "alice", "6", "login 0315").await), 0);
    assert_eq!(msg(&a.request("v1", "alice", "7", "land").await), "Login first!");
    assert_eq!(ret(&b.request("v1", "bob", "5", "land").await), 0);
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn wrong_passwords_are_throttled_per_client_id() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", Options::password(PASSWORD)).await;
    let mut eve = operator(&broker, "eve").await;
    let mut op = operator(&broker, "op").await;
    for n in 0..5 {
        let r = eve.request("v1", "eve", &format!("w{n}"), "login guess").await;
        assert_eq!(r["response"]["msg"], "Wrong password!");
    }
    // The fifth ended Eve's session; her next session is locked out, even
    // with the right password, and the operator's is not.
    let locked = eve.request("v1", "eve", "w5", &format!("login {PASSWORD}")).await;
    assert_eq!(locked["response"]["msg"], "Too many wrong passwords, retry later");
    let ok = op.request("v1", "op", "1", &format!("login {PASSWORD}")).await;
    assert_eq!(ok["response"]["ret"], 0);
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn uplink_clients_and_websocket_addresses_share_one_guessing_budget() {
    const THROTTLED: &str = "Too many wrong passwords, retry later";
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options::password(PASSWORD).with_args(&["--login-addresses", "4", "--login-rate", "1000"]);
    let daemon = vehicle(dir.path(), &broker, "v1", options).await;
    // Four client ids, four wrong passwords each: every record the login
    // lockout keeps now matters.
    for c in 0..4 {
        let client = format!("eve{c}");
        let mut eve = operator(&broker, &client).await;
        for n in 0..4 {
            let r = eve.request("v1", &client, &format!("w{n}"), "login guess").await;
            assert_eq!(r["response"]["msg"], "Wrong password!", "{client}");
        }
        eve.close().await;
    }
    // So nobody new is checked: not an address over WebSocket, not another
    // client id, even with the right password.
    let mut ws = Conn::connect(&daemon.url).await;
    assert_eq!(ws.request(&format!("login {PASSWORD}")).await["msg"], THROTTLED);
    let mut op = operator(&broker, "op").await;
    let r = op.request("v1", "op", "1", &format!("login {PASSWORD}")).await;
    assert_eq!(r["response"]["msg"], THROTTLED);
    // A client id with a record still is.
    let mut eve = operator(&broker, "eve0").await;
    let r = eve
        .request("v1", "eve0", "ok", &format!("login {PASSWORD}"))
        .await;
    assert_eq!(r["response"]["ret"], 0, "{r}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn a_repeated_id_is_answered_from_memory_and_never_run_twice() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", open_vehicle()).await;
    let mut op = operator(&broker, "op").await;
    let syncs = |v: &Value| v["response"]["siyi"]["syncs"].as_u64().expect("syncs");
    let first = op.request("v1", "op", "s1", "siyi_sync").await;
    assert_eq!(syncs(&first), 1);
    // The same id again, even with another frame: the stored answer, byte
    // for byte (same ts), and nothing runs.
    assert_eq!(op.request("v1", "op", "s1", "siyi_sync").await, first);
    assert_eq!(op.request("v1", "op", "s1", "reboot_node").await, first);
    // Another client's "s1" is its own.
    let mut other = operator(&broker, "other").await;
    assert_eq!(syncs(&other.request("v1", "other", "s1", "siyi_sync").await), 2);
    // A burst of copies of new ids (QoS 1 redelivery, retries): each id
    // runs once and every copy is answered.
    for _ in 0..3 {
        for n in 0..20 {
            let envelope = serde_json::json!({"id": format!("b{n}"), "frame": "siyi_sync"}).to_string();
            op.publish("lluav/v1/req/op", envelope, QoS::AtLeastOnce, false)
                .await;
        }
    }
    let mut answers: HashMap<String, Vec<u64>> = HashMap::new();
    while answers.values().map(Vec::len).sum::<usize>() < 60 {
        let Some(p) = op.next_within(Duration::from_secs(5)).await else {
            break;
        };
        let v: Value = serde_json::from_slice(&p.payload).expect("JSON");
        answers
            .entry(v["id"].as_str().expect("id").to_owned())
            .or_default()
            .push(syncs(&v));
    }
    assert_eq!(answers.len(), 20, "{answers:?}");
    for (id, counts) in &answers {
        assert!(!counts.is_empty(), "{id} unanswered");
        assert!(
            counts.iter().all(|c| *c == counts[0]),
            "{id} ran more than once: {counts:?}"
        );
    }
    let last = op.request("v1", "op", "s-last", "siyi_sync").await;
    assert_eq!(syncs(&last), 23, "2 before, 20 ids, this one");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn unreadable_envelopes_are_answered_and_stray_topics_ignored() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = open_vehicle().with_args(&["--max-message", "4096"]);
    let daemon = vehicle(dir.path(), &broker, "v1", options).await;
    let mut op = operator(&broker, "op").await;
    let long_id = "x".repeat(65);
    let cases: Vec<(Vec<u8>, Value, &str)> = vec![
        (b"not json".to_vec(), Value::Null, "not JSON"),
        (vec![0xff, 0xfe], Value::Null, "not JSON"),
        (b"[1,2]".to_vec(), Value::Null, "not a JSON object"),
        (
            br#"{"frame":"state"}"#.to_vec(),
            Value::Null,
            "\"id\" must be a string of 1-64 characters",
        ),
        (
            br#"{"id":12,"frame":"state"}"#.to_vec(),
            Value::Null,
            "\"id\" must be a string of 1-64 characters",
        ),
        (
            format!(r#"{{"id":"{long_id}","frame":"state"}}"#).into_bytes(),
            Value::Null,
            "\"id\" must be a string of 1-64 characters",
        ),
        (
            br#"{"id":"f","frame":null}"#.to_vec(),
            "f".into(),
            "\"frame\" must be a string",
        ),
        (
            format!(r#"{{"id":"big","frame":"{}"}}"#, "a".repeat(5000)).into_bytes(),
            "big".into(),
            "larger than 4096 bytes",
        ),
    ];
    for (payload, id, why) in cases {
        op.publish("lluav/v1/req/op", payload, QoS::AtLeastOnce, false)
            .await;
        let (_, answer) = op.json().await;
        assert_eq!(answer["id"], id, "{answer}");
        let r = &answer["response"];
        assert_eq!(
            (r["ret"].clone(), r["cmd"].clone()),
            (Value::from(-2), Value::from(0)),
            "{answer}"
        );
        assert!(r["ts"].is_i64());
        assert_eq!(r["msg"], format!("Invalid request envelope: {why}"));
    }
    // The empty frame is a frame.
    let empty = op.request("v1", "op", "e", "").await;
    assert_eq!(empty["response"]["msg"], "Empty command");
    // Client ids outside the alphabet get nothing (nowhere safe to answer);
    // the vehicle carries on.
    let mut odd = Mqtt::connect(&broker, "odd").await;
    odd.subscribe("lluav/v1/res/#").await;
    let envelope = r#"{"id":"1","frame":"state"}"#;
    odd.publish("lluav/v1/req/bad.id", envelope, QoS::AtLeastOnce, false)
        .await;
    assert!(odd.next_within(Duration::from_millis(500)).await.is_none());
    assert_eq!(
        op.request("v1", "op", "after", "state").await["response"]["ret"],
        0
    );
    // An envelope beyond what the connection reads at all costs one
    // reconnection, not the vehicle.
    op.publish("lluav/v1/req/op", vec![b'x'; 64 * 1024], QoS::AtLeastOnce, false)
        .await;
    let start = Instant::now();
    loop {
        let envelope = serde_json::json!({"id": "again", "frame": "state"}).to_string();
        op.publish("lluav/v1/req/op", envelope, QoS::AtLeastOnce, false)
            .await;
        if let Some(p) = op.next_within(Duration::from_secs(1)).await {
            let v: Value = serde_json::from_slice(&p.payload).expect("JSON");
            if v["id"] == "again" {
                break;
            }
        }
        assert!(
            start.elapsed() < WAIT,
            "the vehicle never came back:\n{}",
            daemon.stderr()
        );
    }
    let log = daemon.stderr();
    assert_eq!(log.matches("ignored").count(), 1, "logged once:\n{log}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn nothing_sent_while_the_vehicle_was_away_runs_late() {
    let broker = Mosquitto::start();
    let mut op = operator(&broker, "op").await;
    // A plain request and a retained one, before the vehicle is there.
    for (id, retain) in [("early", false), ("kept", true)] {
        let envelope = serde_json::json!({"id": id, "frame": "siyi_sync"}).to_string();
        op.publish("lluav/v1/req/op", envelope, QoS::AtLeastOnce, retain)
            .await;
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", open_vehicle()).await;
    let now = op.request("v1", "op", "now", "siyi_sync").await;
    assert_eq!(now["response"]["siyi"]["syncs"], 1, "neither ran: {now}");
    assert!(
        op.next_within(Duration::from_millis(500)).await.is_none(),
        "no answer to either"
    );
    assert!(
        daemon.stderr().contains("a retained request"),
        "{}",
        daemon.stderr()
    );
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn a_flood_from_one_client_is_bounded_and_every_request_answered() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", open_vehicle()).await;
    let mut op = operator(&broker, "flood").await;
    let mut calm = operator(&broker, "calm").await;
    // save_param 1 writes and syncs a file: far slower to run than to
    // receive, so the 32 in flight fill up.
    const N: usize = 600;
    for n in 0..N {
        let envelope = serde_json::json!({"id": n.to_string(), "frame": "save_param 1"}).to_string();
        op.publish("lluav/v1/req/flood", envelope, QoS::AtLeastOnce, false)
            .await;
    }
    let (mut ran, mut refused) = (0, 0);
    let mut seen = HashSet::new();
    while seen.len() < N {
        let Some(p) = op.next_within(WAIT).await else {
            panic!("{} of {N} answered:\n{}", seen.len(), daemon.stderr());
        };
        let v: Value = serde_json::from_slice(&p.payload).expect("JSON");
        let id = v["id"].as_str().expect("id").to_owned();
        assert!(seen.insert(id.clone()), "{id} answered twice");
        let r = &v["response"];
        assert_eq!(r["cmd"], u8::from(lluav_core::CommandId::SaveParam), "{v}");
        if r["ret"] == 0 {
            ran += 1;
        } else {
            assert_eq!(
                (r["ret"].clone(), r["msg"].clone()),
                (Value::from(-1), "Too many requests in flight".into())
            );
            refused += 1;
        }
    }
    assert!(ran >= 32 && refused > 0, "{ran} ran, {refused} refused");
    // Another client was served meanwhile and after.
    assert_eq!(
        calm.request("v1", "calm", "1", "state").await["response"]["ret"],
        0
    );
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn status_is_retained_with_a_will_and_offline_on_a_clean_stop() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let clean = vehicle(&dir.path().join("a"), &broker, "clean", open_vehicle()).await;
    let crash = vehicle(&dir.path().join("b"), &broker, "crash", open_vehicle()).await;
    let mut watch = Mqtt::connect(&broker, "watch").await;
    watch.subscribe("lluav/+/status").await;
    let mut retained = HashMap::new();
    for _ in 0..2 {
        let p = watch.next().await;
        assert!(p.retain, "status is retained");
        let v: Value = serde_json::from_slice(&p.payload).expect("JSON");
        retained.insert(p.topic, v);
    }
    let online = &retained["lluav/clean/status"];
    assert_eq!(
        (online["vehicle"].clone(), online["online"].clone()),
        ("clean".into(), true.into())
    );
    assert!(online["version"].is_string() && online["ts"].is_i64(), "{online}");

    assert_eq!(clean.terminate().code(), Some(0));
    let (topic, v) = watch.json().await;
    assert_eq!(
        (topic.as_str(), v),
        (
            "lluav/clean/status",
            serde_json::json!({"vehicle":"clean","online":false})
        )
    );
    // Killed: the broker's will says it.
    crash.signal("KILL");
    let _ = crash.wait();
    let (topic, v) = watch.json().await;
    assert_eq!(
        (topic.as_str(), v),
        (
            "lluav/crash/status",
            serde_json::json!({"vehicle":"crash","online":false})
        )
    );
    // Both stay retained for whoever looks later.
    let mut later = Mqtt::connect(&broker, "later").await;
    later.subscribe("lluav/+/status").await;
    for _ in 0..2 {
        let p = later.next().await;
        assert!(p.retain);
        assert_eq!(
            serde_json::from_slice::<Value>(&p.payload).expect("JSON")["online"],
            false
        );
    }
}

/// State messages of `vehicle` within `window`.
async fn states(watch: &mut Mqtt, window: Duration) -> Vec<Value> {
    let mut got = Vec::new();
    let end = Instant::now() + window;
    while let Some(p) = watch
        .next_within(end.saturating_duration_since(Instant::now()))
        .await
    {
        got.push(serde_json::from_slice(&p.payload).expect("JSON"));
    }
    got
}

#[tokio::test]
async fn state_is_published_at_the_rate_and_at_once_on_a_change() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let fast = vehicle(
        &dir.path().join("fast"),
        &broker,
        "fast",
        Options::password(PASSWORD).with_args(&["--uplink-state-hz", "5"]),
    )
    .await;
    let quiet = vehicle(
        &dir.path().join("quiet"),
        &broker,
        "quiet",
        Options {
            sim_speed: Some(10.0),
            ..open_vehicle().with_args(&["--uplink-state-hz", "0"])
        },
    )
    .await;
    let mut watch = Mqtt::connect(&broker, "watch-fast").await;
    watch.subscribe("lluav/fast/state").await;
    let seen = states(&mut watch, Duration::from_secs(3)).await;
    // About 15 in 3 s (5 Hz, the first retained one included); a loaded
    // machine may lose a few ticks, never add any.
    assert!(
        (8..=17).contains(&seen.len()),
        "{} states in 3 s at 5 Hz",
        seen.len()
    );
    for s in &seen {
        // The whole state response, even though the vehicle has a password.
        assert_eq!((s["ret"].clone(), s["cmd"].clone()), (0.into(), 2.into()), "{s}");
        assert_eq!(s["state"]["uplink"], "up");
    }

    let mut watch = Mqtt::connect(&broker, "watch-quiet").await;
    watch.subscribe("lluav/quiet/state").await;
    let first = states(&mut watch, Duration::from_secs(2)).await;
    assert_eq!(first.len(), 1, "only the retained one at 0 Hz: {first:?}");
    let mut op = operator(&broker, "op").await;
    assert_eq!(
        op.request("quiet", "op", "1", "takeoff").await["response"]["ret"],
        0
    );
    // Every change of fsm is published (takeoff, then hover at 10x speed).
    let start = Instant::now();
    let mut fsms = vec![first[0]["state"]["fsm"].clone()];
    while fsms.last() != Some(&Value::from("hover")) {
        assert!(start.elapsed() < WAIT, "never saw hover: {fsms:?}");
        let (_, s) = watch.json().await;
        fsms.push(s["state"]["fsm"].clone());
    }
    assert_eq!(fsms.first(), Some(&Value::from("disarmed")));
    assert!(fsms.contains(&Value::from("takeoff")), "{fsms:?}");
    let changes = fsms.windows(2).filter(|w| w[0] != w[1]).count();
    assert_eq!(changes + 1, fsms.len(), "published on changes only: {fsms:?}");
    assert_eq!(fast.terminate().code(), Some(0));
    assert_eq!(quiet.terminate().code(), Some(0));
}

#[tokio::test]
async fn the_vehicle_comes_back_after_the_broker_restarts_and_websocket_never_waits() {
    let mut broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(
        dir.path(),
        &broker,
        "v1",
        open_vehicle().with_args(&["--uplink-state-hz", "10"]),
    )
    .await;
    let mut ws = Conn::connect(&daemon.url).await;
    wait_uplink(&daemon, &mut ws, "up").await;

    // Frozen: connections open, nothing moves. WebSocket goes on.
    broker.signal("STOP");
    for _ in 0..20 {
        assert_eq!(ws.request("state").await["ret"], 0);
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    broker.signal("CONT");

    // Stopped while requests are in flight, then back on the same port.
    let op = operator(&broker, "op").await;
    for n in 0..20 {
        let envelope = serde_json::json!({"id": format!("i{n}"), "frame": "siyi_sync"}).to_string();
        op.publish("lluav/v1/req/op", envelope, QoS::AtLeastOnce, false)
            .await;
    }
    broker.stop();
    wait_uplink(&daemon, &mut ws, "down").await;
    tokio::time::sleep(Duration::from_secs(2)).await;
    broker.run();
    wait_uplink(&daemon, &mut ws, "up").await;
    // The same ids again: each ran at most once, whatever the broker lost.
    let mut op = operator(&broker, "op").await;
    let mut counts = HashSet::new();
    for n in 0..20 {
        let answer = op.request("v1", "op", &format!("i{n}"), "siyi_sync").await;
        let c = answer["response"]["siyi"]["syncs"].as_u64();
        assert!(c.is_none() || counts.insert(c), "two ids share a run: {answer}");
    }
    let after = op.request("v1", "op", "after", "siyi_sync").await;
    let total = after["response"]["siyi"]["syncs"].as_u64().expect("syncs");
    assert_eq!(total, counts.len() as u64 + 1, "every id ran exactly once");
    // Retained status is back on the fresh broker.
    let mut watch = Mqtt::connect(&broker, "watch").await;
    watch.subscribe("lluav/v1/status").await;
    assert_eq!(watch.json().await.1["online"], true);
    let log = daemon.stderr();
    assert_eq!(
        log.matches("uplink down").count(),
        1,
        "once per change of state:\n{log}"
    );
    assert_eq!(log.matches("uplink up").count(), 2, "{log}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn mqtts_with_a_private_ca() {
    let broker = Mosquitto::with(&BrokerOptions {
        tls: true,
        ..BrokerOptions::default()
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let ca = test_ca().ca_file();
    let ca = ca.to_str().expect("UTF-8 path");
    let trusting = Lluavd::start(
        &dir.path().join("a"),
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--uplink-cafile",
            ca,
            "--vehicle-id",
            "tls",
        ]),
    );
    let system_roots = Lluavd::start(
        &dir.path().join("b"),
        &open_vehicle().with_args(&["--uplink", &broker.url, "--vehicle-id", "plain"]),
    );
    let mut ws = Conn::connect(&trusting.url).await;
    wait_uplink(&trusting, &mut ws, "up").await;
    let out = lluav(
        &[
            "--broker",
            &broker.url,
            "--broker-cafile",
            ca,
            "--vehicle",
            "tls",
            "state",
        ],
        "",
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("\"uplink\": \"up\""));
    // The system's roots do not know the test CA: down, said once however
    // often it tries again.
    let mut ws = Conn::connect(&system_roots.url).await;
    refused_again_and_again(&broker, &system_roots).await;
    assert_eq!(ws.request("state").await["state"]["uplink"], "down");
    let log = system_roots.stderr();
    assert_eq!(log.matches("uplink down").count(), 1, "{log}");
    assert!(
        log.contains("certificate") || log.contains("Certificate"),
        "{log}"
    );
    let refused = lluav(&["--broker", &broker.url, "fleet"], "");
    assert!(!refused.status.success());
    // A CA file that is not one is refused at start.
    let bad = Lluavd::try_start(
        &dir.path().join("c"),
        &open_vehicle().with_args(&["--uplink", &broker.url, "--uplink-cafile", "/dev/null"]),
        &[],
    );
    let Err((status, stderr)) = bad else {
        panic!("started with an empty CA file")
    };
    assert_eq!(status.and_then(|s| s.code()), Some(2), "{stderr}");
    assert_eq!(trusting.terminate().code(), Some(0));
    assert_eq!(system_roots.terminate().code(), Some(0));
}

#[tokio::test]
async fn broker_credentials_from_flags_the_environment_and_a_password_file() {
    let broker = Mosquitto::with(&BrokerOptions {
        users: vec![
            ("drone".into(), "fly-s4fe".into()),
            ("ops".into(), "0ps-pw".into()),
        ],
        ..BrokerOptions::default()
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let by_flag = Lluavd::start(
        &dir.path().join("a"),
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--uplink-user",
            "drone",
            "--uplink-password",
            "fly-s4fe",
            "--vehicle-id",
            "a",
        ]),
    );
    let wrong = Lluavd::start(
        &dir.path().join("b"),
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--uplink-user",
            "drone",
            "--uplink-password",
            "nope",
            "--vehicle-id",
            "b",
        ]),
    );
    let mut ws = Conn::connect(&by_flag.url).await;
    wait_uplink(&by_flag, &mut ws, "up").await;
    let out = lluav(
        &[
            "--broker",
            &broker.url,
            "--broker-user",
            "ops",
            "--vehicle",
            "a",
            "ver",
        ],
        "",
    );
    assert!(!out.status.success(), "no password: refused by the broker");
    assert!(
        text(&out.stderr).contains("cannot connect to the broker"),
        "{}",
        text(&out.stderr)
    );
    let mut cli = Command::new(lluav_bin());
    cli.args([
        "--broker",
        &broker.url,
        "--broker-user",
        "ops",
        "--vehicle",
        "a",
        "ver",
    ])
    .env("LLUAV_BROKER_PASSWORD", "0ps-pw");
    let out = cli.output().expect("lluav runs");
    assert!(out.status.success(), "{}", text(&out.stderr));
    let mut ws = Conn::connect(&wrong.url).await;
    refused_again_and_again(&broker, &wrong).await;
    assert_eq!(ws.request("state").await["state"]["uplink"], "down");
    assert_eq!(
        wrong.stderr().matches("uplink down").count(),
        1,
        "{}",
        wrong.stderr()
    );
    assert_eq!(by_flag.terminate().code(), Some(0));
    assert_eq!(wrong.terminate().code(), Some(0));
}

#[tokio::test]
async fn an_operator_on_a_bridged_broker_reaches_the_vehicle() {
    let site = Mosquitto::start();
    let office = Mosquitto::with(&BrokerOptions {
        extra: Mosquitto::bridge_to(&site),
        ..BrokerOptions::default()
    });
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &site, "far", Options::password(PASSWORD)).await;
    let start = Instant::now();
    loop {
        let out = lluav(&["--broker", &office.url, "--json", "fleet"], "");
        assert!(out.status.success(), "{}", text(&out.stderr));
        let fleet: Value = serde_json::from_slice(&out.stdout).expect("JSON");
        if fleet["far"]["online"] == true && fleet["far"]["state"]["ret"] == 0 {
            break;
        }
        assert!(
            start.elapsed() < WAIT,
            "never seen across the bridge: {fleet}\n{}",
            office.log()
        );
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    let out = lluav(
        &[
            "--broker",
            &office.url,
            "--vehicle",
            "far",
            "--password",
            PASSWORD,
            "takeoff",
        ],
        "",
    );
    assert!(out.status.success(), "{}{}", text(&out.stdout), text(&out.stderr));
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn three_vehicles_at_once_through_the_command_line() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let mut vehicles = Vec::new();
    for id in ["v1", "v2", "v3"] {
        vehicles.push(vehicle(&dir.path().join(id), &broker, id, Options::password(PASSWORD)).await);
    }
    let url = broker.url.as_str();
    let out = lluav(
        &[
            "--broker",
            url,
            "--vehicle",
            "v1,v2,v3",
            "--password",
            PASSWORD,
            "ver",
        ],
        "",
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let lines: Vec<String> = text(&out.stdout).lines().map(str::to_owned).collect();
    assert_eq!(lines.len(), 3, "{lines:?}");
    for (line, id) in lines.iter().zip(["v1", "v2", "v3"]) {
        let json = line
            .strip_prefix(&format!("{id}: "))
            .expect("one line per vehicle, in order");
        let r: Value = serde_json::from_str(json).expect("JSON");
        assert_eq!((r["ret"].clone(), r["cmd"].clone()), (0.into(), 5.into()));
    }
    // Without the password each is refused: exit 1, three lines.
    let out = lluav(&["--broker", url, "--vehicle", "v1,v2,v3", "state"], "");
    assert_eq!(out.status.code(), Some(1));
    assert_eq!(text(&out.stdout).matches("Login first!").count(), 3);

    let table = lluav(&["--broker", url, "fleet"], "");
    let table = text(&table.stdout);
    assert!(table.starts_with("VEHICLE  ONLINE  FSM"), "{table}");
    for id in ["v1", "v2", "v3"] {
        assert!(
            table
                .lines()
                .any(|l| l.starts_with(id) && l.contains("yes") && l.contains("disarmed")),
            "{table}"
        );
    }
    let v3 = vehicles.pop().expect("v3");
    assert_eq!(v3.terminate().code(), Some(0));
    let json = lluav(&["--broker", url, "fleet", "--json"], "");
    let fleet: Value = serde_json::from_slice(&json.stdout).expect("JSON");
    assert_eq!(fleet["v3"]["online"], false);
    assert_eq!(fleet["v1"]["online"], true);
    assert!(fleet["v1"]["age_s"].as_f64().is_some_and(|a| a < 30.0), "{fleet}");
    // An offline vehicle fails after --timeout, the others still answer.
    let out = lluav(
        &[
            "--broker",
            url,
            "--vehicle",
            "v1,v3",
            "--password",
            PASSWORD,
            "--timeout",
            "1",
            "ver",
        ],
        "",
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stdout).starts_with("v1: {"), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).contains("vehicle v3 is offline"),
        "{}",
        text(&out.stderr)
    );
    // A malformed request is caught before anything is sent.
    let out = lluav(&["--broker", url, "--vehicle", "v1", "set_sp_ned", "1:2"], "");
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("usage: set_sp_ned x:y:z:yaw"),
        "{}",
        text(&out.stderr)
    );
    // The interactive session through the broker.
    let out = lluav(
        &["--broker", url, "--vehicle", "v2", "--password", PASSWORD],
        "state\nbogus\ntakeoff\n",
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(stdout.contains("connected to vehicle v2 through"), "{stdout}");
    assert!(
        stdout.contains("\"fsm\": \"disarmed\"") && stdout.contains("\"cmd\": 18"),
        "{stdout}"
    );
    assert!(
        text(&out.stderr).contains("Unsupported command: bogus"),
        "{}",
        text(&out.stderr)
    );
    for v in vehicles {
        assert_eq!(v.terminate().code(), Some(0));
    }
}

#[tokio::test]
async fn idle_uplink_sessions_end_and_websocket_shows_the_uplink_off_without_one() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options::password(PASSWORD).with_args(&["--idle-timeout", "1"]);
    let daemon = vehicle(&dir.path().join("a"), &broker, "v1", options).await;
    let mut op = operator(&broker, "op").await;
    assert_eq!(
        op.request("v1", "op", "1", &format!("login {PASSWORD}")).await["response"]["ret"],
        0
    );
    assert_eq!(op.request("v1", "op", "2", "state").await["response"]["ret"], 0);
    tokio::time::sleep(Duration::from_millis(2500)).await;
    assert_eq!(
        op.request("v1", "op", "3", "state").await["response"]["msg"],
        "Login first!"
    );
    let plain = Lluavd::start(&dir.path().join("b"), &Options::default());
    let mut ws = Conn::connect(&plain.url).await;
    assert_eq!(ws.request("state").await["state"]["uplink"], "off");
    assert_eq!(daemon.terminate().code(), Some(0));
    assert_eq!(plain.terminate().code(), Some(0));
}

/// The `STATUS=` lines lluavd sends to `socket` until one is `want`.
fn status_until(socket: &UnixDatagram, want: &str) -> Vec<String> {
    socket.set_read_timeout(Some(WAIT)).expect("timeout set");
    let mut seen = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = socket
            .recv(&mut buf)
            .unwrap_or_else(|e| panic!("no {want:?} ({e}); saw {seen:?}"));
        let text = String::from_utf8_lossy(buf.get(..n).unwrap_or_default()).into_owned();
        seen.extend(
            text.lines()
                .filter_map(|l| l.strip_prefix("STATUS="))
                .map(str::to_owned),
        );
        if seen.last().is_some_and(|l| l == want) {
            return seen;
        }
    }
}

#[tokio::test]
async fn the_service_status_line_says_whether_the_uplink_is_up() {
    let mut broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let socket_path = dir.path().join("notify");
    let socket = UnixDatagram::bind(&socket_path).expect("notify socket");
    let mut daemon = Command::new(lluavd_bin())
        .args([
            "--bind",
            "127.0.0.1:0",
            "--allow-no-password",
            "--vehicle-id",
            "v1",
        ])
        .args(["--uplink", &broker.url, "--data-dir"])
        .arg(dir.path().join("data"))
        .env("NOTIFY_SOCKET", &socket_path)
        .env_remove("WATCHDOG_PID")
        .env_remove("LLUAV_PASSWORD")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("lluavd spawns");
    status_until(&socket, "0 sessions; simulated vehicle; uplink up");
    broker.stop();
    status_until(&socket, "0 sessions; simulated vehicle; uplink down");
    broker.run();
    status_until(&socket, "0 sessions; simulated vehicle; uplink up");
    let _ = Command::new("kill")
        .args(["-TERM", &daemon.id().to_string()])
        .status();
    assert_eq!(daemon.wait().expect("lluavd ends").code(), Some(0));
}

#[test]
fn bad_uplink_settings_are_refused_at_start() {
    let dir = tempfile::tempdir().expect("temp dir");
    for args in [
        &["--uplink", "http://broker"][..],
        &["--uplink", "mqtt://broker", "--vehicle-id", "a/b"],
        &["--uplink", "mqtt://broker", "--uplink-state-hz", "11"],
        &["--uplink", "mqtt://broker", "--uplink-cafile", "ca.pem"],
    ] {
        let started = Lluavd::try_start(&dir.path().join("x"), &open_vehicle().with_args(args), &[]);
        let Err((status, stderr)) = started else {
            panic!("started with {args:?}")
        };
        assert_eq!(status.and_then(|s| s.code()), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains("--uplink") || stderr.contains("--vehicle-id"),
            "{stderr}"
        );
    }
    // No password: anyone who may publish to the vehicle's requests could
    // fly it. Refused unless allowed, like listening beyond loopback.
    for password in [None, Some(PASSWORD)] {
        let options = Options {
            password: password.map(str::to_owned),
            ..Options::default().with_args(&["--uplink", "mqtt://127.0.0.1:1", "--vehicle-id", "v"])
        };
        match Lluavd::try_start(&dir.path().join("y"), &options, &[]) {
            Ok(daemon) => {
                assert!(password.is_some(), "started without a password");
                assert_eq!(daemon.terminate().code(), Some(0));
            }
            Err((status, stderr)) => {
                assert!(password.is_none(), "{stderr}");
                assert_eq!(status.and_then(|s| s.code()), Some(2));
                assert!(stderr.contains("--allow-no-password"), "{stderr}");
            }
        }
    }
}

/// The README's Mosquitto ACL, as written.
fn readme_acl() -> String {
    let readme =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../README.md")).expect("README");
    let start = readme
        .find("```text\n# /etc/mosquitto/lluav.acl")
        .expect("the ACL block");
    let block = &readme[start + "```text\n".len()..];
    block[..block.find("```").expect("its end")].to_owned()
}

#[tokio::test]
async fn the_readme_acl_lets_each_operator_and_vehicle_use_only_its_own_topics() {
    let dir = tempfile::tempdir().expect("temp dir");
    let acl = dir.path().join("lluav.acl");
    std::fs::write(&acl, readme_acl()).expect("ACL written");
    let broker = Mosquitto::with(&BrokerOptions {
        users: vec![
            ("alice".into(), "a-pw".into()),
            ("mallory".into(), "m-pw".into()),
            ("drone-1".into(), "d-pw".into()),
        ],
        extra: format!("acl_file {}\n", acl.display()),
        ..BrokerOptions::default()
    });
    let daemon = Lluavd::start(
        &dir.path().join("v"),
        &Options::password(PASSWORD).with_args(&[
            "--uplink",
            &broker.url,
            "--vehicle-id",
            "drone-1",
            "--uplink-user",
            "drone-1",
            "--uplink-password",
            "d-pw",
        ]),
    );
    let login = |user: &str, password: &str| {
        let mut o = rumqttc::MqttOptions::new(user, "127.0.0.1", broker.port);
        o.set_credentials(user, password);
        o
    };
    let mut alice = Mqtt::with(login("alice", "a-pw")).await.expect("alice connects");
    alice.subscribe("lluav/+/status").await;
    loop {
        let (_, status) = alice.json().await;
        if status["online"] == true {
            break;
        }
    }
    alice.subscribe("lluav/+/res/alice").await;
    let syncs = |v: &Value| v["response"]["siyi"]["syncs"].clone();
    assert_eq!(
        alice
            .request("drone-1", "alice", "0", &format!("login {PASSWORD}"))
            .await["response"]["ret"],
        0
    );
    // Alice may not speak as anyone else, nor forge the vehicle's status;
    // Mallory, with no lines in the ACL, may do nothing at all.
    let as_bob = r#"{"id":"x","frame":"siyi_sync"}"#;
    alice
        .publish("lluav/drone-1/req/bob", as_bob, QoS::AtLeastOnce, false)
        .await;
    let forged = r#"{"vehicle":"drone-1","online":false}"#;
    alice
        .publish("lluav/drone-1/status", forged, QoS::AtLeastOnce, true)
        .await;
    let mallory = Mqtt::with(login("mallory", "m-pw"))
        .await
        .expect("mallory connects");
    mallory
        .publish("lluav/drone-1/req/mallory", as_bob, QoS::AtLeastOnce, false)
        .await;
    assert_eq!(
        syncs(&alice.request("drone-1", "alice", "1", "siyi_sync").await),
        1,
        "nothing else ran"
    );
    tokio::time::sleep(Duration::from_millis(300)).await;
    let again = alice.request("drone-1", "alice", "2", "siyi_sync").await;
    assert_eq!(syncs(&again), 2, "nor later");
    let mut later = Mqtt::with(login("alice", "a-pw")).await.expect("alice again");
    later.subscribe("lluav/drone-1/status").await;
    assert_eq!(
        later.json().await.1["online"],
        true,
        "the retained status is the vehicle's"
    );
    assert_eq!(daemon.terminate().code(), Some(0));
}
