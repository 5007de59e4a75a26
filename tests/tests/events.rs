//! The `/events` stream over real sockets (DESIGN.md, "Events"): a whole
//! flight told in order, login first, push only, a gap for a subscriber
//! that stops reading while the vehicle goes on answering.

use std::time::Duration;

use lluav_tests::{Conn, Lluavd, Options, Received, WAIT, wait_for_state};
use serde_json::{Value, json};

const PASSWORD: &str = "s3cret";

fn events_url(daemon: &Lluavd) -> String {
    format!("{}/events", daemon.url)
}

/// A subscriber logged in on `/events`.
async fn subscriber(daemon: &Lluavd) -> Conn {
    let mut sub = Conn::connect(&events_url(daemon)).await;
    let r = sub.request(&format!("login {PASSWORD}")).await;
    assert_eq!(r["ret"], 0, "{r}");
    sub
}

/// The next event, parsed.
async fn event(sub: &mut Conn) -> Value {
    match sub.recv().await {
        Received::Text(t) => serde_json::from_str(&t).unwrap_or_else(|e| panic!("not JSON ({e}): {t}")),
        other => panic!("expected an event, got {other:?}"),
    }
}

/// What identifies an event in the expected sequence: its name and the
/// fields that say what happened.
fn gist(e: &Value) -> Value {
    let mut g = json!({"event": e["event"]});
    for key in [
        "from", "to", "armed", "status", "wp", "index", "count", "ext_id", "by", "reason",
    ] {
        if let Some(v) = e.get(key) {
            g[key] = v.clone();
        }
    }
    g
}

#[tokio::test]
async fn a_mission_flight_with_a_take_over_and_a_landing_is_told_in_order() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(
        dir.path(),
        &Options::password(PASSWORD).with_args(&["--sim-speed", "10"]),
    );
    let mut sub = subscriber(&daemon).await;
    let mut a = Conn::login(&daemon.url, PASSWORD).await;
    let mut b = Conn::login(&daemon.url, PASSWORD).await;
    let label = |c: &Value| c["control"]["by"].as_str().expect("a label").to_owned();
    assert_eq!(a.request("takeoff").await["ret"], 0);
    let pilot_a = label(&a.request("control").await);
    wait_for_state(&mut a, "hovering", |s| s["fsm"] == "hover").await;
    let mission = r#"mission 7:{"waypoints":[{"id":11,"x":2,"y":0,"z":-2},{"id":12,"x":2,"y":2,"z":-2},{"id":13,"x":0,"y":2,"z":-2}]}"#;
    assert_eq!(a.request(mission).await["ret"], 0);
    assert_eq!(a.request("mw_exec 7:11,12,13").await["ret"], 0);
    wait_for_state(&mut a, "done with the mission", |s| s["fsm"] == "hover").await;
    let taken = b.request("control_take").await;
    assert_eq!(taken["ret"], 0);
    let pilot_b = label(&taken);
    assert_eq!(b.request("land").await["ret"], 0);
    wait_for_state(&mut b, "landed", |s| s["armed"] == false).await;

    let expected = [
        json!({"event": "control", "by": pilot_a, "from": null}),
        json!({"event": "fsm", "from": "disarmed", "to": "takeoff"}),
        json!({"event": "armed", "armed": true}),
        json!({"event": "fsm", "from": "takeoff", "to": "hover"}),
        json!({"event": "mission", "ext_id": 7, "status": "started"}),
        json!({"event": "fsm", "from": "hover", "to": "mission"}),
        json!({"event": "mission", "ext_id": 7, "status": "reached", "wp": 11, "index": 1, "count": 3}),
        json!({"event": "mission", "ext_id": 7, "status": "reached", "wp": 12, "index": 2, "count": 3}),
        json!({"event": "mission", "ext_id": 7, "status": "reached", "wp": 13, "index": 3, "count": 3}),
        json!({"event": "mission", "ext_id": 7, "status": "completed"}),
        json!({"event": "fsm", "from": "mission", "to": "hover"}),
        json!({"event": "control", "by": pilot_b, "from": pilot_a}),
        json!({"event": "fsm", "from": "hover", "to": "landing"}),
        json!({"event": "fsm", "from": "landing", "to": "armed"}),
        json!({"event": "fsm", "from": "armed", "to": "disarmed"}),
        json!({"event": "armed", "armed": false}),
    ];
    let mut seen = Vec::new();
    let mut last_seq = 0;
    let mut boot = None;
    while seen.len() < expected.len() {
        let e = event(&mut sub).await;
        assert_eq!(e["seq"], last_seq + 1, "seq counts on: {e}");
        last_seq = e["seq"].as_u64().expect("seq");
        assert!(e["ts"].is_i64(), "{e}");
        let b = e["boot"].as_str().expect("boot").to_owned();
        assert_eq!(boot.get_or_insert(b.clone()), &b, "one boot");
        // Battery and log events may come between: this flight's
        // expectations are about the rest.
        if !matches!(e["event"].as_str(), Some("battery" | "log")) {
            seen.push(gist(&e));
        }
    }
    assert_eq!(seen, expected);
    assert_eq!(daemon.terminate().code(), Some(0));
}

#[tokio::test]
async fn the_events_endpoint_wants_a_login_first_and_only_sends() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    // Anything but a login first: closed with 1008.
    let mut rude = Conn::connect(&events_url(&daemon)).await;
    rude.send("state").await;
    assert_eq!(rude.close_code().await, Some(1008));
    // A wrong password is answered like on the command socket and sends
    // no events.
    let mut wrong = Conn::connect(&events_url(&daemon)).await;
    assert_eq!(wrong.request("login nope").await["msg"], "Wrong password!");
    let mut pilot = Conn::login(&daemon.url, PASSWORD).await;
    assert_eq!(pilot.request("takeoff").await["ret"], 0);
    let mut sub = subscriber(&daemon).await;
    assert_eq!(pilot.request("land").await["ret"], 0);
    let e = event(&mut sub).await;
    assert_eq!(e["event"], "fsm", "{e}");
    // Only the subscriber that logged in got it: the other one still has
    // nothing, and a message closes it.
    wrong.send("login nope").await;
    assert_eq!(
        wrong.response().await["msg"],
        "Wrong password!",
        "no event came first"
    );
    // After the login, any message closes the subscriber.
    sub.send("state").await;
    loop {
        match sub.recv().await {
            Received::Text(_) => continue,
            Received::Close(code) => {
                assert_eq!(code, Some(1008));
                break;
            }
            other => panic!("{other:?}"),
        }
    }
}

#[tokio::test]
async fn wrong_passwords_on_the_events_endpoint_count_towards_the_lockout() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut sub = Conn::connect(&events_url(&daemon)).await;
    for _ in 0..4 {
        assert_eq!(sub.request("login guess").await["msg"], "Wrong password!");
    }
    let mut c = Conn::connect(&daemon.url).await;
    assert_eq!(c.request("login guess").await["msg"], "Wrong password!");
    // The fifth wrong password from this address: locked out.
    assert_eq!(
        c.request(&format!("login {PASSWORD}")).await["msg"],
        "Too many wrong passwords, retry later"
    );
}

#[tokio::test]
async fn without_a_password_events_come_at_once() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::default());
    let mut sub = Conn::connect(&events_url(&daemon)).await;
    let mut c = Conn::connect(&daemon.url).await;
    // The subscription is in place once the upgrade is answered; the
    // takeoff is answered before its events go out.
    assert_eq!(c.request("takeoff").await["ret"], 0);
    let e = event(&mut sub).await;
    assert_eq!(
        (e["event"].clone(), e["seq"].clone()),
        (json!("control"), json!(1))
    );
}

#[tokio::test]
async fn a_warning_in_the_log_is_told_as_a_log_event() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::default());
    let mut sub = Conn::connect(&events_url(&daemon)).await;
    let mut c = Conn::connect(&daemon.url).await;
    // The simulator logs its autopilot's reboot as a warning.
    assert_eq!(c.request("reboot_ap").await["ret"], 0);
    let e = event(&mut sub).await;
    assert_eq!(
        (&e["event"], &e["level"], &e["msg"]),
        (
            &json!("log"),
            &json!("warning"),
            &json!("simulated autopilot reboot")
        ),
        "{e}"
    );
    // What showmsg shows, with its time and level in front.
    let shown = c.request("showmsg").await;
    let lines = shown["msgs"].as_array().expect("msgs");
    assert!(
        lines.iter().any(|l| l
            .as_str()
            .is_some_and(|l| l.ends_with(" WARN lluav_host::sim: simulated autopilot reboot"))),
        "{shown}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_subscriber_that_stops_reading_gets_a_gap_and_the_vehicle_goes_on_answering() {
    use futures_util::StreamExt;
    use tokio_tungstenite::tungstenite::Message;

    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::default());
    // A subscriber with a small receive buffer that reads nothing for a
    // while: its socket fills, then its queue.
    let socket = tokio::net::TcpSocket::new_v4().expect("socket");
    socket.set_recv_buffer_size(1024).expect("small buffer");
    let tcp = socket.connect(daemon.addr).await.expect("connect");
    let (mut slow, _) = tokio_tungstenite::client_async(format!("ws://{}/events", daemon.addr), tcp)
        .await
        .expect("upgrade");
    // Two sessions passing control back and forth: two events a round,
    // far more than the socket and the subscriber's queue (256) hold.
    // Bounded in time too: a subscriber silent for the 10 s a write may
    // take is dropped, not lagging.
    let (mut a, mut b) = (Conn::connect(&daemon.url).await, Conn::connect(&daemon.url).await);
    let start = std::time::Instant::now();
    let mut rounds = 0;
    while rounds < 3000 && start.elapsed() < Duration::from_secs(5) {
        assert_eq!(a.request("control_take").await["ret"], 0);
        assert_eq!(b.request("control_take").await["ret"], 0);
        rounds += 1;
    }
    // It reads again: among what it gets, a gap says how many it missed,
    // and the events after the gap go on with later seqs.
    let mut last_seq = 0;
    let mut missed = 0;
    while missed == 0 || last_seq < 2 * rounds {
        assert!(
            missed > 0 || last_seq < 2 * rounds,
            "all {last_seq} events came and no gap: the subscriber was never behind"
        );
        let next = tokio::time::timeout(WAIT, slow.next())
            .await
            .expect("events in time");
        let text = match next {
            Some(Ok(Message::Text(text))) => text,
            Some(Ok(Message::Ping(_) | Message::Pong(_))) => continue,
            other => panic!("after {rounds} rounds, at seq {last_seq} ({missed} missed): {other:?}"),
        };
        let e: Value = serde_json::from_str(text.as_str()).expect("JSON");
        if e["event"] == "gap" {
            assert!(e["missed"].as_u64() > Some(0), "{e}");
            assert!(e.get("seq").is_none(), "a gap has no seq of its own: {e}");
            missed += e["missed"].as_u64().unwrap_or(0);
            continue;
        }
        let seq = e["seq"].as_u64().expect("seq");
        assert!(seq > last_seq, "in order: {seq} after {last_seq}");
        if missed == 0 {
            assert_eq!(seq, last_seq + 1, "nothing lost before a gap");
        }
        last_seq = seq;
    }
    assert!(missed > 0 && rounds > 500, "{rounds} rounds, {missed} missed");
}
