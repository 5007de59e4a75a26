//! lluavd's MQTT uplink against a real broker (Mosquitto, started here on
//! a free port with its own config): requests and gates per client id,
//! repeats (also across a restart and an eviction), bad input, oversized
//! messages, status and will, state publishing, broker restarts, mqtts,
//! credentials, the README's broker config and ACL, bridged brokers,
//! several vehicles, the `lluav --broker` command line, what its requests
//! did told on the `/events` stream, a flight told alike on `/events` and
//! `lluav/V/events`, the uplink's own up and down as events, the state
//! topic following a change, and a stand-in broker that floods and never
//! reads. Needs `--features broker` (scripts/test-uplink.sh).

use std::collections::{HashMap, HashSet};
use std::os::unix::net::UnixDatagram;
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use lluav_tests::broker::{
    ADMIN, BrokerOptions, Mosquitto, Mqtt, PublishProperties, QoS, topic, vehicle, vehicle_options,
    with_admin,
};
use lluav_tests::flooder::{Flood, Flooder};
use lluav_tests::{Conn, Lluavd, Options, WAIT, lluav_bin, lluavd_bin, memory_kib, test_ca};
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
        b.request("v1", "bob", "2", &format!("login {ADMIN}")).await["response"]["admin"],
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
    // A burst of copies of new ids (QoS 1 redelivery, retries), sent back
    // to back so that copies arrive while their first still runs: each id
    // runs once and every copy gets an answer of its own, the same one.
    for n in 0..20 {
        let envelope = serde_json::json!({"id": format!("b{n}"), "frame": "siyi_sync"}).to_string();
        for _ in 0..3 {
            op.publish("lluav/v1/req/op", envelope.clone(), QoS::AtLeastOnce, false)
                .await;
        }
    }
    // Every answer to those goes out before the answer to a later request
    // of the same client: what comes before this one is all there is.
    let sentinel = serde_json::json!({"id": "after", "frame": "state"}).to_string();
    op.publish("lluav/v1/req/op", sentinel, QoS::AtLeastOnce, false)
        .await;
    let mut answers: HashMap<String, Vec<Value>> = HashMap::new();
    loop {
        let (_, v) = op.json().await;
        let id = v["id"].as_str().expect("id").to_owned();
        if id == "after" {
            break;
        }
        answers.entry(id).or_default().push(v);
    }
    assert_eq!(answers.len(), 20, "{answers:?}");
    let mut runs = HashSet::new();
    for (id, copies) in &answers {
        assert_eq!(copies.len(), 3, "{id}: one answer per copy: {copies:?}");
        assert!(copies.iter().all(|c| *c == copies[0]), "{id}: {copies:?}");
        assert!(runs.insert(syncs(&copies[0])), "two ids share a run");
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
        (
            br#"{"id":"d","frame":"ver","frame":"login 1025"}"#.to_vec(),
            "d".into(),
            "duplicate member \"frame\"",
        ),
        (
            br#"{"id":"d2","id":"d3","frame":"state"}"#.to_vec(),
            Value::Null,
            "duplicate member \"id\"",
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
    // the vehicle carries on. Whatever it sent would come before the
    // answer to a request sent after it.
    let mut odd = Mqtt::connect(&broker, "odd").await;
    odd.subscribe("lluav/v1/res/#").await;
    let envelope = r#"{"id":"1","frame":"state"}"#;
    odd.publish("lluav/v1/req/bad.id", envelope, QoS::AtLeastOnce, false)
        .await;
    let after = odd.request("v1", "odd-ok", "after", "state").await;
    assert_eq!(after["response"]["ret"], 0);
    // A message over the vehicle's Maximum Packet Size never reaches it:
    // the broker drops it, nobody is answered, and the connection holds.
    op.publish("lluav/v1/req/op", vec![b'x'; 64 * 1024], QoS::AtLeastOnce, false)
        .await;
    let next = op.request("v1", "op", "again", "state").await;
    assert_eq!(next["response"]["ret"], 0);
    let log = daemon.stderr();
    assert_eq!(log.matches("ignored").count(), 1, "logged once:\n{log}");
    assert!(!log.contains("uplink down"), "{log}");
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
    // With a Message Expiry, as an operator may send it.
    let envelope = serde_json::json!({"id": "now", "frame": "siyi_sync"}).to_string();
    let expiry = PublishProperties {
        message_expiry_interval: Some(60),
        ..PublishProperties::default()
    };
    op.publish_with("lluav/v1/req/op", envelope, QoS::AtLeastOnce, false, Some(expiry))
        .await;
    let (_, now) = op.json().await;
    assert_eq!(now["id"], "now", "no answer to either before it: {now}");
    assert_eq!(now["response"]["siyi"]["syncs"], 1, "neither ran: {now}");
    // The retained one is still at the broker: Retain Handling 2 kept it
    // away from the vehicle, which never saw it.
    let mut late = Mqtt::connect(&broker, "late").await;
    late.subscribe("lluav/v1/req/op").await;
    let kept = late.next().await;
    assert!(kept.retain && String::from_utf8_lossy(&kept.payload).contains("kept"));
    assert!(!daemon.stderr().contains("retained"), "{}", daemon.stderr());
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
        retained.insert(topic(&p), v);
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
            "--allow-default-admin",
        ]),
    );
    let system_roots = Lluavd::start(
        &dir.path().join("b"),
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--vehicle-id",
            "plain",
            "--allow-default-admin",
        ]),
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
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--uplink-cafile",
            "/dev/null",
            "--allow-default-admin",
        ]),
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
            ("drone-a".into(), "fly-s4fe".into()),
            ("drone-b".into(), "fly-b".into()),
            ("ops".into(), "0ps-pw".into()),
        ],
        ..BrokerOptions::default()
    });
    let dir = tempfile::tempdir().expect("temp dir");
    // The vehicle id is the broker user name.
    let by_flag = Lluavd::start(
        &dir.path().join("a"),
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--uplink-user",
            "drone-a",
            "--uplink-password",
            "fly-s4fe",
            "--allow-default-admin",
        ]),
    );
    let wrong = Lluavd::start(
        &dir.path().join("b"),
        &open_vehicle().with_args(&[
            "--uplink",
            &broker.url,
            "--uplink-user",
            "drone-b",
            "--uplink-password",
            "nope",
            "--allow-default-admin",
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
            "drone-a",
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
        "drone-a",
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
    let mut sub = Conn::connect(&format!("{}/events", daemon.url)).await;
    assert_eq!(sub.request(&format!("login {PASSWORD}")).await["ret"], 0);
    let mut op = operator(&broker, "op").await;
    assert_eq!(
        op.request("v1", "op", "1", &format!("login {PASSWORD}")).await["response"]["ret"],
        0
    );
    // Control makes the session's end visible: it is freed, and told, the
    // moment the idle session ends (its own lapse is 30 s away).
    let take = op.request("v1", "op", "2", "control_take").await;
    assert_eq!(take["response"]["ret"], 0, "{take}");
    let taken = flight_event(&mut sub).await;
    assert_eq!(taken["event"], "control", "{taken}");
    let pilot = taken["by"].clone();
    assert!(pilot.is_string(), "{taken}");
    let freed = flight_event(&mut sub).await;
    assert_eq!(
        (&freed["event"], &freed["by"], &freed["from"]),
        (&"control".into(), &Value::Null, &pilot),
        "the idle session ended: {freed}"
    );
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
        let n = match socket.recv(&mut buf) {
            Ok(n) => n,
            // A signal to this process (a child's exit) cuts a timed wait short.
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => panic!("no {want:?} ({e}); saw {seen:?}"),
        };
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
    let daemon = Command::new(lluavd_bin())
        .args([
            "--bind",
            "127.0.0.1:0",
            "--allow-no-password",
            "--allow-default-admin",
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
    // Killed if the test fails before it stops it.
    let mut daemon = KillOnDrop(daemon);
    status_until(&socket, "0 sessions; simulated vehicle; uplink up");
    broker.stop();
    status_until(&socket, "0 sessions; simulated vehicle; uplink down");
    broker.run();
    status_until(&socket, "0 sessions; simulated vehicle; uplink up");
    let _ = Command::new("kill")
        .args(["-TERM", &daemon.0.id().to_string()])
        .status();
    assert_eq!(daemon.0.wait().expect("lluavd ends").code(), Some(0));
}

/// A child process killed when this goes out of scope.
struct KillOnDrop(std::process::Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

#[test]
fn bad_uplink_settings_are_refused_at_start() {
    let dir = tempfile::tempdir().expect("temp dir");
    for args in [
        &["--uplink", "http://broker"][..],
        &["--uplink", "mqtt://broker", "--vehicle-id", "a/b"],
        &["--uplink", "mqtt://broker", "--uplink-state-hz", "11"],
        &["--uplink", "mqtt://broker", "--uplink-cafile", "ca.pem"],
        // The broker account is the vehicle's identity.
        &[
            "--uplink",
            "mqtt://broker",
            "--uplink-user",
            "drone-1",
            "--vehicle-id",
            "drone-2",
        ],
        &["--uplink", "mqtt://broker", "--uplink-user", "drone.1"],
    ] {
        let options = open_vehicle()
            .with_args(args)
            .with_args(&["--allow-default-admin"]);
        let started = Lluavd::try_start(&dir.path().join("x"), &options, &[]);
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
            ..Options::default().with_args(&[
                "--uplink",
                "mqtt://127.0.0.1:1",
                "--vehicle-id",
                "v",
                "--allow-default-admin",
            ])
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

/// `lluavd --check-config` with `args`: exit status and stderr.
fn check_config(args: &[&str]) -> (Option<i32>, String) {
    let out = Command::new(lluavd_bin())
        .arg("--check-config")
        .args(args)
        .env_remove("LLUAV_PASSWORD")
        .env_remove("LLUAV_UPLINK_PASSWORD")
        .output()
        .expect("lluavd runs");
    (out.status.code(), text(&out.stderr))
}

#[tokio::test]
async fn the_public_admin_value_is_refused_with_an_uplink_unless_replaced_or_allowed() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let data = dir.path().join("v");
    let data = data.to_str().expect("UTF-8 path");
    // Bound to loopback, as the README's example is: the broker's users are
    // not, and 1025 is in the public spec.
    let args = [
        "--password",
        PASSWORD,
        "--uplink",
        &broker.url,
        "--vehicle-id",
        "v1",
    ];
    let refused = Lluavd::try_start(dir.path(), &Options::default().with_args(&args), &[]);
    let Err((status, stderr)) = refused else {
        panic!("lluavd served the public admin value through the broker")
    };
    assert_eq!(status.and_then(|s| s.code()), Some(2), "{stderr}");
    for says in ["--uplink", "1025", "admin_password", "--allow-default-admin"] {
        assert!(stderr.contains(says), "the refusal says {says}: {stderr}");
    }
    let args = [&["--bind", "127.0.0.1:0", "--data-dir", data][..], &args].concat();
    // --check-config says the same, and why.
    let (code, stderr) = check_config(&args);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(
        stderr.contains("admin_password") && stderr.contains("--allow-default-admin"),
        "{stderr}"
    );
    let config = dir.path().join("admin.toml");
    std::fs::write(&config, format!("admin_password = \"{ADMIN}\"\n")).expect("config");
    let config = config.to_str().expect("UTF-8 path");
    let (code, stderr) = check_config(&[&args[..], &["--config", config]].concat());
    assert_eq!(code, Some(0), "{stderr}");
    // With an admin value of its own, 1025 is a wrong password like any.
    let daemon = vehicle(
        &dir.path().join("own"),
        &broker,
        "v1",
        Options::password(PASSWORD),
    )
    .await;
    let mut op = operator(&broker, "op").await;
    let r = op.request("v1", "op", "1", "login 1025").await;
    assert_eq!(r["response"]["msg"], "Wrong password!", "{r}");
    let r = op.request("v1", "op", "2", "admin_lock").await;
    assert_eq!(r["response"]["msg"], "Login first!", "{r}");
    let r = op.request("v1", "op", "3", &format!("login {ADMIN}")).await;
    assert_eq!(r["response"]["admin"], true, "{r}");
    assert_eq!(daemon.terminate().code(), Some(0));
    // Allowed: it starts, and says what it allows.
    let allowed = Lluavd::start(
        &dir.path().join("allowed"),
        &Options::password(PASSWORD).with_args(&[
            "--uplink",
            &broker.url,
            "--vehicle-id",
            "v2",
            "--allow-default-admin",
        ]),
    );
    let start = Instant::now();
    while !allowed.stderr().contains("admin_password") {
        assert!(start.elapsed() < WAIT, "no warning: {}", allowed.stderr());
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(allowed.terminate().code(), Some(0));
}

/// An MQTT client logged in as `user` with its own user name as client id,
/// subscribed to its answers, or why it could not connect.
async fn account(broker: &Mosquitto, user: &str, password: &str) -> Mqtt {
    let mut m = Mqtt::login(broker, user, user, password)
        .await
        .unwrap_or_else(|e| panic!("{user} cannot connect: {e}"));
    m.subscribe(&format!("lluav/+/res/{user}")).await;
    m
}

#[tokio::test]
async fn the_readme_broker_config_makes_each_account_one_identity() {
    let broker = Mosquitto::recommended(&[("alice", "a-pw"), ("mallory", "m-pw"), ("drone-1", "d-pw")]);
    let dir = tempfile::tempdir().expect("temp dir");
    let data = dir.path().join("v");
    // The vehicle id and client id are its account's user name.
    let options = vehicle_options(&data, &broker, Options::password(PASSWORD)).with_args(&[
        "--uplink-user",
        "drone-1",
        "--uplink-password",
        "d-pw",
    ]);
    let daemon = Lluavd::start(&data, &options);
    // One account is one identity: a second connection of alice, whatever
    // client id it asks for, pushes her first one off.
    let first = account(&broker, "alice", "a-pw").await;
    let mut alice = Mqtt::login(&broker, "alice-2", "alice", "a-pw")
        .await
        .expect("alice connects again");
    assert!(first.closed_within(WAIT).await, "one connection per account");
    alice.subscribe("lluav/+/res/alice").await;
    alice.subscribe("lluav/+/status").await;
    loop {
        let (t, status) = alice.json().await;
        if t == "lluav/drone-1/status" && status["online"] == true {
            break;
        }
    }
    let syncs = |v: &Value| v["response"]["siyi"]["syncs"].clone();
    let login = alice
        .request("drone-1", "alice", "0", &format!("login {PASSWORD}"))
        .await;
    assert_eq!(login["response"]["ret"], 0, "{login}");
    assert_eq!(
        syncs(&alice.request("drone-1", "alice", "1", "siyi_sync").await),
        1
    );
    // Mallory connects under the vehicle's client id, then under alice's:
    // the broker gives each connection mallory's own, and nobody is pushed
    // off.
    let mut mallory = Vec::new();
    for taken in ["drone-1", "alice"] {
        let m = Mqtt::login(&broker, taken, "mallory", "m-pw")
            .await
            .expect("mallory connects");
        mallory.push(m);
    }
    let mut mallory = mallory.pop().expect("a connection");
    assert!(alice.is_open(), "alice was pushed off");
    // Mallory may not speak as alice, read her answers or the vehicle's
    // requests (logins carry the password), nor forge the vehicle's status.
    let as_alice = r#"{"id":"x","frame":"siyi_sync"}"#;
    mallory
        .publish("lluav/drone-1/req/alice", as_alice, QoS::AtLeastOnce, false)
        .await;
    // Mosquitto grants these and delivers nothing the ACL does not allow.
    for filter in ["lluav/+/res/alice", "lluav/drone-1/req/+", "lluav/+/res/mallory"] {
        mallory.try_subscribe(filter).await;
    }
    let forged = r#"{"vehicle":"drone-1","online":false}"#;
    mallory
        .publish("lluav/drone-1/status", forged, QoS::AtLeastOnce, true)
        .await;
    let seen = alice
        .request("drone-1", "alice", "2", &format!("login {PASSWORD}"))
        .await;
    assert_eq!(seen["response"]["ret"], 0);
    // Mallory is an operator of her own: a session of her own, not logged
    // in; her answer is the first thing she gets, after alice's request
    // and answer went by.
    let envelope = r#"{"id":"m1","frame":"siyi_sync"}"#;
    mallory
        .publish("lluav/drone-1/req/mallory", envelope, QoS::AtLeastOnce, false)
        .await;
    let first = mallory.next().await;
    assert_eq!(topic(&first), "lluav/drone-1/res/mallory");
    let r: Value = serde_json::from_slice(&first.payload).expect("JSON");
    assert_eq!(r["response"]["msg"], "Login first!", "{r}");
    assert_eq!(
        syncs(&alice.request("drone-1", "alice", "3", "siyi_sync").await),
        2,
        "nothing else ran"
    );
    // The vehicle never left, and the retained status is its own.
    let log = daemon.stderr();
    assert_eq!(log.matches("uplink up").count(), 1, "{log}");
    assert!(!log.contains("uplink down"), "{log}");
    let mut later = account(&broker, "alice", "a-pw").await;
    later.subscribe("lluav/drone-1/status").await;
    assert_eq!(later.json().await.1["online"], true);
    later.close().await;
    // The command line: alice's client id is her user name by default.
    let ca = test_ca().ca_file();
    let ca = ca.to_str().expect("UTF-8 path");
    let mut cli = Command::new(lluav_bin());
    cli.args([
        "--broker",
        &broker.url,
        "--broker-user",
        "alice",
        "--broker-cafile",
        ca,
        "--vehicle",
        "drone-1",
        "--password",
        PASSWORD,
        "siyi_sync",
    ])
    .env("LLUAV_BROKER_PASSWORD", "a-pw")
    .env_remove("LLUAV_PASSWORD");
    let out = cli.output().expect("lluav runs");
    assert!(out.status.success(), "{}{}", text(&out.stdout), text(&out.stderr));
    assert!(
        text(&out.stdout).contains("\"syncs\": 3"),
        "{}",
        text(&out.stdout)
    );
    let mut cli = Command::new(lluav_bin());
    cli.args([
        "--broker",
        &broker.url,
        "--broker-user",
        "alice",
        "--broker-cafile",
        ca,
        "--json",
        "fleet",
    ])
    .env("LLUAV_BROKER_PASSWORD", "a-pw");
    let out = cli.output().expect("lluav runs");
    let fleet: Value = serde_json::from_slice(&out.stdout).expect("JSON");
    assert_eq!(fleet["drone-1"]["online"], true, "{fleet}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn no_message_retained_or_live_takes_the_vehicle_off_the_broker() {
    let broker = Mosquitto::start();
    let mut op = operator(&broker, "op").await;
    let mut big = operator(&broker, "big").await;
    // 200 KB retained on a request topic, before the vehicle subscribes.
    let retained = format!(r#"{{"id":"r","frame":"state","pad":"{}"}}"#, "x".repeat(200_000));
    big.publish("lluav/v1/req/big", retained, QoS::AtLeastOnce, true)
        .await;
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", open_vehicle()).await;
    let mut ws = Conn::connect(&daemon.url).await;
    for n in 0..30 {
        if n == 10 {
            // 300 KB live: over the vehicle's Maximum Packet Size, so the
            // broker drops it (and nobody answers it).
            let live = format!(r#"{{"id":"l","frame":"state","pad":"{}"}}"#, "x".repeat(300_000));
            big.publish("lluav/v1/req/big", live, QoS::AtLeastOnce, false)
                .await;
        }
        let r = op.request("v1", "op", &format!("q{n}"), "state").await;
        assert_eq!(r["response"]["ret"], 0, "{r}");
    }
    // Nothing for either big one came before the answer to a request sent
    // after both.
    let after = serde_json::json!({"id": "after", "frame": "state"}).to_string();
    big.publish("lluav/v1/req/big", after, QoS::AtLeastOnce, false)
        .await;
    let (_, first) = big.json().await;
    assert_eq!(first["id"], "after", "{first}");
    assert_eq!(ws.request("state").await["state"]["uplink"], "up");
    let log = daemon.stderr();
    assert_eq!(log.matches("uplink up").count(), 1, "{log}");
    assert!(!log.contains("uplink down"), "{log}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn a_repeat_after_a_restart_gets_the_first_answer_and_never_runs_again() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let data = dir.path().join("v");
    let options = || Options {
        sim_speed: Some(10.0),
        ..Options::password(PASSWORD)
    };
    let daemon = vehicle(&data, &broker, "v1", options()).await;
    let mut op = operator(&broker, "op").await;
    let login = op.request("v1", "op", "l1", &format!("login {PASSWORD}")).await;
    assert_eq!(login["response"]["ret"], 0);
    let takeoff = op.request("v1", "op", "t1", "takeoff").await;
    assert_eq!(takeoff["response"]["ret"], 0, "{takeoff}");
    let sync = op.request("v1", "op", "s1", "siyi_sync").await;
    let state = op.request("v1", "op", "st1", "state").await;
    assert_eq!(daemon.terminate().code(), Some(0));
    // A request that was running when lluavd stopped, as the store keeps
    // it (written and synced before the command runs, DESIGN "Uplink"): a
    // file of a run that died before answering it.
    let now = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .expect("after 1970")
        .as_millis();
    let cut = data.join("uplink").join(format!("answers-{now}.jsonl"));
    std::fs::write(
        &cut,
        format!("{{\"t\":{now},\"c\":\"op\",\"i\":\"t2\",\"start\":18}}\n"),
    )
    .expect("written");
    let daemon = vehicle(&data, &broker, "v1", options()).await;
    // Sessions end with the run: log in again.
    let login = op.request("v1", "op", "l2", &format!("login {PASSWORD}")).await;
    assert_eq!(login["response"]["ret"], 0);
    // The same ids: the first answers, byte for byte (their ts too).
    assert_eq!(op.request("v1", "op", "t1", "takeoff").await, takeoff);
    assert_eq!(op.request("v1", "op", "s1", "siyi_sync").await, sync);
    let interrupted = op.request("v1", "op", "t2", "takeoff").await;
    let r = &interrupted["response"];
    assert_eq!(
        (r["ret"].clone(), r["cmd"].clone(), r["msg"].clone()),
        (
            Value::from(-3),
            Value::from(18),
            "Interrupted by a restart; check state".into()
        ),
        "{interrupted}"
    );
    assert_eq!(op.request("v1", "op", "t2", "takeoff").await, interrupted);
    // Neither ran again: the vehicle (a new simulator, on the ground) did
    // not take off, and the camera counted no sync.
    let mut ws = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(ws.request("state").await["state"]["fsm"], "disarmed");
    let fresh = op.request("v1", "op", "s2", "siyi_sync").await;
    assert_eq!(fresh["response"]["siyi"]["syncs"], 1, "{fresh}");
    // A request that changes nothing is not kept: it runs again.
    let again = op.request("v1", "op", "st1", "state").await;
    assert_ne!(again["response"]["ts"], state["response"]["ts"]);
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn a_vehicle_killed_in_a_burst_runs_each_request_once_across_the_restart() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let data = dir.path().join("v");
    let daemon = vehicle(&data, &broker, "v1", open_vehicle()).await;
    let mut op = operator(&broker, "op").await;
    const N: usize = 30;
    for n in 0..N {
        let envelope = serde_json::json!({"id": format!("k{n}"), "frame": "siyi_sync"}).to_string();
        op.publish("lluav/v1/req/op", envelope, QoS::AtLeastOnce, false)
            .await;
    }
    // Killed (no clean stop) once the first answers are out.
    let mut seen = HashMap::new();
    while seen.len() < 3 {
        let (_, v) = op.json().await;
        seen.insert(v["id"].as_str().expect("id").to_owned(), v);
    }
    daemon.signal("KILL");
    let _ = daemon.wait();
    let daemon = vehicle(&data, &broker, "v1", open_vehicle()).await;
    // Answers still on their way from the first run come first; the
    // repeats' answers are the ones after.
    let mut syncs = Vec::new();
    for n in 0..N {
        let id = format!("k{n}");
        let answer = op.request("v1", "op", &id, "siyi_sync").await;
        if let Some(first) = seen.get(&id) {
            assert_eq!(&answer, first, "{id}: the answer given before the kill");
        }
        let r = &answer["response"];
        let run = match (r["ret"].as_i64(), r["siyi"]["syncs"].as_u64()) {
            (Some(0), Some(count)) => count,
            (Some(-3), _) => 0,
            _ => panic!("{answer}"),
        };
        syncs.push(run);
    }
    // The first run's answers (its counter from 1), at most the one that
    // was running when it died (-3), then the second run's (from 1): each
    // id ran once, in order, in one of the two runs.
    let counted_from_one = |run: &[u64]| run.iter().enumerate().all(|(i, c)| *c == i as u64 + 1);
    let first_run = syncs
        .iter()
        .enumerate()
        .take_while(|(i, c)| **c == *i as u64 + 1)
        .count();
    let rest = &syncs[first_run..];
    let second_run = rest.strip_prefix(&[0]).unwrap_or(rest);
    assert!(counted_from_one(second_run), "{syncs:?}");
    assert!(first_run >= 3, "{syncs:?}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn a_client_that_lost_its_session_to_a_crowd_still_gets_its_answer_and_nothing_reruns() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", open_vehicle()).await;
    let mut victim = operator(&broker, "victim").await;
    let first = victim.request("v1", "victim", "e1", "siyi_sync").await;
    assert_eq!(first["response"]["siyi"]["syncs"], 1);
    // 1,100 other client ids: more than the 1,024 sessions, so the
    // victim's session (idle, not logged in) gives up its seat.
    let mut crowd = Mqtt::connect(&broker, "crowd").await;
    crowd.subscribe("lluav/v1/res/+").await;
    const CROWD: usize = 1100;
    for n in 0..CROWD {
        let envelope = serde_json::json!({"id": "c", "frame": "state"}).to_string();
        crowd
            .publish(&format!("lluav/v1/req/c{n}"), envelope, QoS::AtLeastOnce, false)
            .await;
    }
    let mut answered = HashSet::new();
    while answered.len() < CROWD {
        let p = crowd.next().await;
        let v: Value = serde_json::from_slice(&p.payload).expect("JSON");
        assert_eq!(v["response"]["ret"], 0, "{v}");
        answered.insert(topic(&p));
    }
    assert_eq!(victim.request("v1", "victim", "e1", "siyi_sync").await, first);
    let next = victim.request("v1", "victim", "e2", "siyi_sync").await;
    assert_eq!(next["response"]["siyi"]["syncs"], 2, "e1 ran once: {next}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

/// The next event on a `/events` subscriber, battery and log events
/// left out (they come whenever they come); within [`WAIT`] (the
/// stream's pings keep the connection itself from waiting that long).
async fn flight_event(sub: &mut Conn) -> Value {
    let next = async {
        loop {
            let e = match sub.recv().await {
                lluav_tests::Received::Text(t) => {
                    serde_json::from_str::<Value>(&t).expect("an event is JSON")
                }
                other => panic!("expected an event, got {other:?}"),
            };
            if !matches!(e["event"].as_str(), Some("battery" | "log")) {
                return e;
            }
        }
    };
    tokio::time::timeout(WAIT, next).await.expect("an event in time")
}

#[tokio::test]
async fn what_an_uplink_request_did_is_told_on_the_events_stream_once_answered() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", Options::password(PASSWORD)).await;
    let mut sub = Conn::connect(&format!("{}/events", daemon.url)).await;
    assert_eq!(sub.request(&format!("login {PASSWORD}")).await["ret"], 0);
    let mut op = operator(&broker, "op").await;
    let login = op.request("v1", "op", "1", &format!("login {PASSWORD}")).await;
    assert_eq!(login["response"]["ret"], 0, "{login}");
    let takeoff = op.request("v1", "op", "2", "takeoff").await;
    assert_eq!(takeoff["response"]["ret"], 0, "{takeoff}");
    let control = op.request("v1", "op", "3", "control").await;
    let pilot = control["response"]["control"]["by"].clone();
    assert!(pilot.is_string(), "{control}");
    // The uplink session stays open (idle sessions end after minutes):
    // the takeoff's events are held only until its answer is published,
    // not until the session ends.
    let control_event = flight_event(&mut sub).await;
    assert_eq!(control_event["event"], "control", "{control_event}");
    assert_eq!(control_event["by"], pilot, "{control_event}");
    let fsm = flight_event(&mut sub).await;
    assert_eq!(
        (&fsm["event"], &fsm["from"], &fsm["to"]),
        (&"fsm".into(), &"disarmed".into(), &"takeoff".into()),
        "{fsm}"
    );
    let armed = flight_event(&mut sub).await;
    assert_eq!(
        (&armed["event"], &armed["armed"]),
        (&"armed".into(), &true.into()),
        "{armed}"
    );
    // Events after them (a WebSocket session taking over) follow.
    let mut ws = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(ws.request("control_take").await["ret"], 0);
    let taken = loop {
        let e = flight_event(&mut sub).await;
        if e["event"] != "fsm" {
            break e;
        }
        // The vehicle may reach its hover meanwhile.
        assert_eq!(
            (&e["from"], &e["to"]),
            (&"takeoff".into(), &"hover".into()),
            "{e}"
        );
    };
    assert_eq!(
        (&taken["event"], &taken["from"]),
        (&"control".into(), &pilot),
        "{taken}"
    );
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn the_fleet_listing_escapes_what_a_vehicle_wrote() {
    let broker = Mosquitto::start();
    let forger = Mqtt::connect(&broker, "forger").await;
    let status = r#"{"vehicle":"evil","online":true}"#;
    forger
        .publish("lluav/evil/status", status, QoS::AtLeastOnce, true)
        .await;
    // Clear the screen, set the window title, a C1 control sequence
    // introducer and a right-to-left override, in a retained state.
    let fsm = "\u{1b}[2J\u{1b}]0;pwned\u{7}\u{9b}31m\u{202e}dlrow";
    let state = serde_json::json!({"ret": 0, "cmd": 2, "ts": 1, "state": {"fsm": fsm, "armed": "\u{1b}[1A"}});
    forger
        .publish("lluav/evil/state", state.to_string(), QoS::AtMostOnce, true)
        .await;
    for args in [&["fleet"][..], &["--json", "fleet"]] {
        let out = lluav(&[&["--broker", &broker.url][..], args].concat(), "");
        assert!(out.status.success(), "{}", text(&out.stderr));
        let stdout = text(&out.stdout);
        assert!(stdout.contains("evil"), "{stdout}");
        for raw in ['\u{1b}', '\u{7}', '\u{9b}', '\u{202e}'] {
            assert!(!stdout.contains(raw), "{args:?} printed {raw:?} raw: {stdout:?}");
        }
        assert!(
            stdout.contains(r"\u001b[2J") && stdout.contains(r"\u202e"),
            "{stdout}"
        );
        if args[0] == "--json" {
            let fleet: Value = serde_json::from_str(&stdout).expect("still JSON");
            assert_eq!(fleet["evil"]["state"]["state"]["fsm"], fsm, "the same value");
        }
    }
}

/// The uplink's documented memory bound (DESIGN.md, "Uplink").
const UPLINK_BOUND_KIB: u64 = 32 << 10;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_that_floods_and_never_reads_cannot_grow_lluavd_or_stop_its_websocket() {
    const FLOOD: u64 = 256 << 20;
    let flooder = Flooder::start(
        "v1",
        Flood {
            bytes: FLOOD,
            // 64 Ki requests: enough to fill the id store, the sessions
            // and the bytes in flight.
            message: 4 << 10,
            clients: 16 << 10,
        },
    );
    let dir = tempfile::tempdir().expect("temp dir");
    let options =
        with_admin(dir.path(), open_vehicle()).with_args(&["--uplink", &flooder.url(), "--vehicle-id", "v1"]);
    let daemon = Lluavd::start(dir.path(), &options);
    flooder.wait_subscribed();
    let mut ws = Conn::connect(&daemon.url).await;
    assert_eq!(ws.request("state").await["ret"], 0);
    let (before, _) = memory_kib(daemon.pid());
    flooder.go();
    // The WebSocket side answers all along; the flood ends when all of it
    // went in, or when lluavd gave up on a broker that never answers its
    // pings (after two keep-alives).
    let mut answered = 0;
    while !flooder.ended() {
        let r = tokio::time::timeout(WAIT, ws.request("state"))
            .await
            .expect("the WebSocket side answered in time");
        assert_eq!(r["ret"], 0, "{r}");
        answered += 1;
    }
    let (after, peak) = memory_kib(daemon.pid());
    let sent = flooder.sent();
    eprintln!(
        "flood: {} MiB in; lluavd VmRSS {before} KiB before, {after} KiB after, peak {peak} KiB; \
         {answered} WebSocket round trips meanwhile",
        sent >> 20
    );
    assert!(
        sent >= 2 * (UPLINK_BOUND_KIB << 10),
        "only {sent} bytes went in:\n{}",
        daemon.stderr()
    );
    assert!(
        peak.saturating_sub(before) <= UPLINK_BOUND_KIB,
        "VmRSS {before} KiB before, {after} KiB after, peak {peak} KiB, with {sent} bytes flooded"
    );
    assert!(answered > 0);
    assert_eq!(ws.request("state").await["ret"], 0);
    assert_eq!(daemon.terminate().code(), Some(0));
}

/// One pilot across the transports (DESIGN.md, "Flight authority"): a
/// WebSocket session flying keeps an operator through the broker from
/// steering, and the operator's landing runs and hands it control.
#[tokio::test]
async fn one_session_flies_across_websocket_and_the_uplink() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        sim_speed: Some(10.0),
        ..Options::password(PASSWORD)
    };
    let daemon = vehicle(dir.path(), &broker, "v1", options).await;
    let mut ws = Conn::login(&daemon.url, PASSWORD).await;
    let mut op = operator(&broker, "op").await;
    let login = op.request("v1", "op", "1", &format!("login {PASSWORD}")).await;
    assert_eq!(login["response"]["ret"], 0, "{login}");

    assert_eq!(ws.request("takeoff").await["ret"], 0);
    lluav_tests::wait_for_state(&mut ws, "hovering", |s| s["fsm"] == "hover").await;
    assert_eq!(ws.request("set_sp_ned 1:0:-2:0").await["ret"], 0);
    let mine = ws.request("control").await["control"].clone();
    assert_eq!(mine["you"], true, "{mine}");
    let ws_label = mine["by"].as_str().expect("a label").to_owned();
    assert!(ws_label.starts_with("ws 127.0.0.1:"), "{ws_label}");

    // The operator is refused motion and told who flies and how to take over.
    let refused = op.request("v1", "op", "2", "set_sp_ned 2:0:-2:0").await["response"].clone();
    assert_eq!(refused["ret"], -1, "{refused}");
    let why = refused["msg"].as_str().unwrap_or_default();
    assert!(
        why.starts_with(&format!("Vehicle is flown by {ws_label} since ")),
        "{refused}"
    );
    assert!(why.ends_with(": control_take to take over"), "{refused}");
    let seen = op.request("v1", "op", "3", "control").await["response"].clone();
    assert_eq!(
        (&seen["control"]["by"], &seen["control"]["you"]),
        (&ws_label.as_str().into(), &false.into()),
        "{seen}"
    );

    // A landing is never refused by the control gate; it hands control over.
    let land = op.request("v1", "op", "4", "land").await["response"].clone();
    assert_eq!(land["ret"], 0, "{land}");
    let now = ws.request("control").await["control"].clone();
    assert_eq!(
        (&now["by"], &now["you"]),
        (&"mqtt op".into(), &false.into()),
        "{now}"
    );
    let held = ws.request("set_sp_ned 1:0:-2:0").await;
    assert!(
        held["msg"]
            .as_str()
            .is_some_and(|m| m.starts_with("Vehicle is flown by mqtt op since ")),
        "{held}"
    );

    // Released through the broker, control is free for the WebSocket session.
    let released = op.request("v1", "op", "5", "control_release").await["response"].clone();
    assert_eq!(
        (&released["ret"], &released["control"]),
        (&0.into(), &Value::Null),
        "{released}"
    );
    assert_eq!(ws.request("control").await["control"], Value::Null);
    assert_eq!(daemon.terminate().code(), Some(0));
}

/// The next event on `lluav/V/events` of `watch`, as JSON: never retained.
async fn broker_event(watch: &mut Mqtt) -> Value {
    let p = watch.next().await;
    assert!(!p.retain, "events are not retained");
    assert!(topic(&p).ends_with("/events"), "{}", topic(&p));
    serde_json::from_slice(&p.payload).expect("an event is JSON")
}

/// The next event on a `/events` subscriber, whatever it is.
async fn any_event(sub: &mut Conn) -> Value {
    match sub.recv().await {
        lluav_tests::Received::Text(t) => serde_json::from_str(&t).expect("an event is JSON"),
        other => panic!("expected an event, got {other:?}"),
    }
}

/// What identifies a flight event: its name and the fields that say what
/// happened (labels, FSM states, mission progress).
fn gist(e: &Value) -> Value {
    let mut g = serde_json::json!({"event": e["event"]});
    for key in [
        "from", "to", "armed", "status", "wp", "index", "count", "ext_id", "by",
    ] {
        if let Some(v) = e.get(key) {
            g[key] = v.clone();
        }
    }
    g
}

/// Asserts that `events` count on one by one.
fn consecutive(events: &[Value]) {
    for pair in events.windows(2) {
        assert_eq!(
            pair[1]["seq"].as_u64(),
            pair[0]["seq"].as_u64().map(|s| s + 1),
            "seq counts on: {} then {}",
            pair[0],
            pair[1]
        );
    }
}

#[tokio::test]
async fn a_flight_is_told_alike_on_the_events_endpoint_and_the_broker() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options::password(PASSWORD).with_args(&["--sim-speed", "10"]);
    let daemon = vehicle(dir.path(), &broker, "v1", options).await;
    let mut sub = Conn::connect(&format!("{}/events", daemon.url)).await;
    assert_eq!(sub.request(&format!("login {PASSWORD}")).await["ret"], 0);
    let mut watch = Mqtt::connect(&broker, "watch-events").await;
    watch.subscribe("lluav/v1/events").await;

    // A WebSocket pilot takes off and flies a three-waypoint mission; an
    // operator through the broker takes over and lands.
    let mut a = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(a.request("takeoff").await["ret"], 0);
    let pilot_a = a.request("control").await["control"]["by"].clone();
    lluav_tests::wait_for_state(&mut a, "hovering", |s| s["fsm"] == "hover").await;
    let mission = r#"mission 7:{"waypoints":[{"id":11,"x":2,"y":0,"z":-2},{"id":12,"x":2,"y":2,"z":-2},{"id":13,"x":0,"y":2,"z":-2}]}"#;
    assert_eq!(a.request(mission).await["ret"], 0);
    assert_eq!(a.request("mw_exec 7:11,12,13").await["ret"], 0);
    lluav_tests::wait_for_state(&mut a, "done with the mission", |s| s["fsm"] == "hover").await;
    let mut op = operator(&broker, "op").await;
    let login = op.request("v1", "op", "1", &format!("login {PASSWORD}")).await;
    assert_eq!(login["response"]["ret"], 0, "{login}");
    let taken = op.request("v1", "op", "2", "control_take").await;
    assert_eq!(taken["response"]["ret"], 0, "{taken}");
    let pilot_op = taken["response"]["control"]["by"].clone();
    assert_eq!(op.request("v1", "op", "3", "land").await["response"]["ret"], 0);

    // The /events stream until the motors stop: the landing is over.
    let mut told = Vec::new();
    while told
        .last()
        .is_none_or(|e: &Value| e["event"] != "armed" || e["armed"] != false)
    {
        told.push(any_event(&mut sub).await);
    }
    consecutive(&told);
    let flight: Vec<Value> = told
        .iter()
        .filter(|e| !matches!(e["event"].as_str(), Some("battery" | "log")))
        .map(gist)
        .collect();
    let reached = |wp: u32, index: u32| serde_json::json!({"event": "mission", "ext_id": 7, "status": "reached", "wp": wp, "index": index, "count": 3});
    let expected = [
        serde_json::json!({"event": "control", "by": pilot_a, "from": null}),
        serde_json::json!({"event": "fsm", "from": "disarmed", "to": "takeoff"}),
        serde_json::json!({"event": "armed", "armed": true}),
        serde_json::json!({"event": "fsm", "from": "takeoff", "to": "hover"}),
        serde_json::json!({"event": "mission", "ext_id": 7, "status": "started"}),
        serde_json::json!({"event": "fsm", "from": "hover", "to": "mission"}),
        reached(11, 1),
        reached(12, 2),
        reached(13, 3),
        serde_json::json!({"event": "mission", "ext_id": 7, "status": "completed"}),
        serde_json::json!({"event": "fsm", "from": "mission", "to": "hover"}),
        serde_json::json!({"event": "control", "by": pilot_op, "from": pilot_a}),
        serde_json::json!({"event": "fsm", "from": "hover", "to": "landing"}),
        serde_json::json!({"event": "fsm", "from": "landing", "to": "armed"}),
        serde_json::json!({"event": "fsm", "from": "armed", "to": "disarmed"}),
        serde_json::json!({"event": "armed", "armed": false}),
    ];
    assert_eq!(flight, expected);

    // The broker carried the very same objects, in the same order.
    let mut carried = Vec::new();
    while carried.len() < told.len() {
        carried.push(broker_event(&mut watch).await);
    }
    assert_eq!(carried, told, "the same objects on both");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn the_state_topic_follows_a_takeoff_at_once_however_slow_its_rate() {
    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    // Every 100 s: any state but the first within the test came from a
    // change, not from the rate.
    let options = open_vehicle().with_args(&["--uplink-state-hz", "0.01"]);
    let daemon = vehicle(dir.path(), &broker, "v1", options).await;
    let mut watch = Mqtt::connect(&broker, "watch-state").await;
    watch.subscribe("lluav/v1/state").await;
    let (_, first) = watch.json().await;
    assert_eq!(first["state"]["fsm"], "disarmed", "{first}");
    let mut ws = Conn::connect(&daemon.url).await;
    let asked = Instant::now();
    assert_eq!(ws.request("takeoff").await["ret"], 0);
    let (_, next) = watch.json().await;
    let took = asked.elapsed();
    assert_eq!(
        (&next["state"]["fsm"], &next["state"]["armed"]),
        (&"takeoff".into(), &true.into()),
        "{next}"
    );
    // Published on the takeoff's events, not found by reading the state
    // on a timer: within a couple of seconds even on a loaded machine.
    assert!(took < Duration::from_secs(2), "{took:?}");
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn the_uplink_tells_its_own_down_and_up_and_its_stream_goes_on_after_a_restart() {
    let mut broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = vehicle(dir.path(), &broker, "v1", open_vehicle()).await;
    let mut sub = Conn::connect(&format!("{}/events", daemon.url)).await;
    let is = |e: &Value, state: &str| e["event"] == "uplink" && e["state"] == state;
    // Its down, the warnings it logs while it reconnects (told as `log`
    // events too), then its up: one stream, seqs consecutive.
    broker.stop();
    let mut told = vec![any_event(&mut sub).await];
    while !told.last().is_some_and(|e| is(e, "down")) {
        told.push(any_event(&mut sub).await);
    }
    broker.run();
    while !told.last().is_some_and(|e| is(e, "up")) {
        told.push(any_event(&mut sub).await);
    }
    consecutive(&told);
    let uplink: Vec<&Value> = told.iter().filter(|e| e["event"] != "log").collect();
    assert!(
        uplink.len() == 2 && is(uplink[0], "down") && is(uplink[1], "up"),
        "{told:?}"
    );
    // The broker's stream goes on with the next seq: the down was not
    // carried, the up was (before anyone here could listen again).
    let mut watch = Mqtt::connect(&broker, "watch-events").await;
    watch.subscribe("lluav/v1/events").await;
    let mut ws = Conn::connect(&daemon.url).await;
    assert_eq!(ws.request("takeoff").await["ret"], 0);
    let mut on_ws = any_event(&mut sub).await;
    while on_ws["event"] == "log" {
        told.push(on_ws);
        on_ws = any_event(&mut sub).await;
    }
    told.push(on_ws.clone());
    consecutive(&told);
    assert_eq!(on_ws["event"], "control", "{on_ws}");
    let mut carried = broker_event(&mut watch).await;
    while carried["event"] == "log" {
        carried = broker_event(&mut watch).await;
    }
    assert_eq!(carried, on_ws);
    assert_eq!(daemon.terminate().code(), Some(0));
}

/// `lluav --broker URL events`: every vehicle's events (`lluav/+/events`)
/// as `V: {json}` lines, in order; `--vehicle V` only V's, as lines for a
/// person.
#[tokio::test]
async fn lluav_broker_events_follows_every_vehicle_or_one() {
    use lluav_tests::Following;
    use lluav_tests::wait_for_state;

    let broker = Mosquitto::start();
    let dir = tempfile::tempdir().expect("temp dir");
    let options = || Options::password(PASSWORD).with_args(&["--sim-speed", "10"]);
    let v1 = vehicle(&dir.path().join("v1"), &broker, "v1", options()).await;
    let v2 = vehicle(&dir.path().join("v2"), &broker, "v2", options()).await;
    let url = broker.url.as_str();
    let all = Following::start(&["--broker", url, "events", "--json"]);
    let only_v2 = Following::start(&["--broker", url, "--vehicle", "v2", "events"]);
    // Said once the broker granted the subscription.
    all.stderr_until("following the events");
    only_v2.stderr_until("following the events");

    for daemon in [&v1, &v2] {
        let mut pilot = Conn::login(&daemon.url, PASSWORD).await;
        assert_eq!(pilot.request("takeoff").await["ret"], 0);
        wait_for_state(&mut pilot, "hovering", |s| s["fsm"] == "hover").await;
    }
    let takeoff = [
        ("control", None, None),
        ("fsm", Some("disarmed"), Some("takeoff")),
        ("armed", None, None),
        ("fsm", Some("takeoff"), Some("hover")),
    ];
    tokio::task::spawn_blocking(move || {
        let mut seen: HashMap<String, Vec<Value>> = HashMap::new();
        let enough = |seen: &HashMap<String, Vec<Value>>| {
            ["v1", "v2"]
                .iter()
                .all(|v| seen.get(*v).map_or(0, Vec::len) >= takeoff.len())
        };
        while !enough(&seen) {
            let line = all.line().expect("a line");
            let (v, json) = line.split_once(": ").expect("V: {json}");
            let e: Value = serde_json::from_str(json).unwrap_or_else(|e| panic!("not JSON ({e}): {line}"));
            if !matches!(e["event"].as_str(), Some("battery" | "log" | "uplink")) {
                seen.entry(v.to_owned()).or_default().push(e);
            }
        }
        for (v, events) in &seen {
            for (e, (name, from, to)) in events.iter().zip(takeoff) {
                assert_eq!(e["event"], name, "{v}: {events:?}");
                if let (Some(from), Some(to)) = (from, to) {
                    assert_eq!(
                        (e["from"].as_str(), e["to"].as_str()),
                        (Some(from), Some(to)),
                        "{v}"
                    );
                }
            }
            for pair in events.windows(2) {
                let (a, b) = (pair[0]["seq"].as_u64(), pair[1]["seq"].as_u64());
                assert!(a < b, "{v}: seq goes up: {events:?}");
            }
        }
        let mut lines = Vec::new();
        while lines.len() < takeoff.len() {
            let line = only_v2.line().expect("a line");
            assert!(line.starts_with("v2: "), "only v2's: {line}");
            if !line.contains(" battery ") && !line.contains(" log ") && !line.contains(" uplink ") {
                lines.push(line);
            }
        }
        assert!(lines[1].ends_with(" fsm from=disarmed to=takeoff"), "{lines:?}");
        assert_eq!(all.interrupt().code(), Some(0));
        assert_eq!(only_v2.interrupt().code(), Some(0));
    })
    .await
    .expect("the checks");
    assert_eq!(v1.terminate().code(), Some(0));
    assert_eq!(v2.terminate().code(), Some(0));
}
