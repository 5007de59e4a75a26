//! lluavd's life: start-up refusals, the one stdout line, configuration,
//! persistence across restarts and graceful shutdown under load.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

use futures_util::future::join_all;
use lluav_tests::{Conn, Lluavd, Options, Received, parse_response};
use serde_json::Value;

const PASSWORD: &str = "s3cret";

/// The value `get_param` reports for `name` (`{"param":{name:value},...}`).
fn param_value(r: &Value, name: &str) -> Value {
    r["param"][name].clone()
}

#[test]
fn listening_beyond_loopback_without_a_password_is_refused() {
    let dir = tempfile::tempdir().expect("temp dir");
    let refused = Lluavd::try_start(dir.path(), &Options::default(), &["--bind", "0.0.0.0:0"]);
    match refused {
        Ok(_) => panic!("lluavd listened on 0.0.0.0 without a password"),
        Err((status, stderr)) => {
            assert_eq!(status.and_then(|s| s.code()), Some(2), "{stderr}");
            assert!(
                stderr.contains("--allow-no-password"),
                "the refusal says what to do: {stderr}"
            );
        }
    }
}

#[tokio::test]
async fn sigint_stops_the_daemon_cleanly_after_exactly_one_stdout_line() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let r = c.request("state").await;
    assert_eq!(r["ret"], 0, "{r}");
    daemon.signal("INT");
    assert_eq!(
        c.close_code().await,
        Some(1001),
        "open sessions are told the server goes away"
    );
    let more = daemon.more_stdout();
    assert!(
        more.is_empty(),
        "stdout has only the listening line, not {more:?}"
    );
    assert!(daemon.wait().success());
}

#[tokio::test]
async fn config_file_supplies_the_password() {
    let dir = tempfile::tempdir().expect("temp dir");
    let config = dir.path().join("lluavd.toml");
    std::fs::write(&config, "password = \"fromfile\"\nsim_speed = 2.0\n").expect("config written");
    let options = Options {
        args: vec!["--config".into(), config.display().to_string()],
        ..Options::default()
    };
    let daemon = Lluavd::start(&dir.path().join("data"), &options);
    let mut c = Conn::connect(&daemon.url).await;
    assert_eq!(c.request("state").await["msg"], "Login first!");
    assert_eq!(c.request("login fromfile").await["ret"], 0);
}

#[tokio::test]
async fn saved_parameters_and_the_password_survive_a_restart() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::default());
    let mut c = Conn::login(&daemon.url, "1025").await;
    let r = c.request("set_param autosleep_after:1234").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = c.request("save_param 1").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = c.request("passwd n3wpass").await;
    assert_eq!(r["ret"], 0, "{r}");
    c.close().await;
    assert!(daemon.terminate().success());

    // No --password this time: the one set by passwd is in force.
    let daemon = Lluavd::start(dir.path(), &Options::default());
    let mut c = Conn::connect(&daemon.url).await;
    assert_eq!(c.request("state").await["msg"], "Login first!");
    let r = c.request("login n3wpass").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = c.request("get_param autosleep_after").await;
    assert_eq!(param_value(&r, "autosleep_after"), 1234, "{r}");
}

/// Sends `request`, asserting it succeeds; returns the answer.
async fn ok(c: &mut Conn, request: &str) -> Value {
    let r = c.request(request).await;
    assert_eq!(r["ret"], 0, "{request}: {r}");
    r
}

/// Starts the daemon over `dir` and reads, as a user, lock mode, map
/// localisation and the map in use.
async fn kept_state(dir: &std::path::Path) -> (Lluavd, (Value, Value, Value)) {
    let daemon = Lluavd::start(dir, &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let state = ok(&mut c, "state").await["state"].clone();
    let map = ok(&mut c, "get_submap_info").await["kfs"]["map_id"].clone();
    c.close().await;
    (
        daemon,
        (state["lock_mode"].clone(), state["map_locate"].clone(), map),
    )
}

#[tokio::test]
async fn lock_mode_the_map_in_use_and_map_localisation_survive_a_restart_and_a_crash() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut admin = Conn::login(&daemon.url, "1025").await;
    for request in [
        "savemap site_a",
        "set_mappath site_a",
        "set_maplocate 1",
        "admin_lock",
    ] {
        ok(&mut admin, request).await;
    }
    admin.close().await;
    assert!(daemon.terminate().success());

    let (daemon, kept) = kept_state(dir.path()).await;
    assert_eq!(kept, (Value::Bool(true), Value::Bool(true), "site_a".into()));
    let mut user = Conn::login(&daemon.url, PASSWORD).await;
    let r = user.request("set_param takeoff_alt:3").await;
    assert_eq!(r["msg"], "CMD not permitted to run in LOCK mode!", "{r}");
    // Saved when answered, not at shutdown: kill -9 keeps each change.
    let mut admin = Conn::login(&daemon.url, "1025").await;
    // The map in use cannot be removed: another one replaces it first.
    for request in [
        "admin_unlock",
        "set_maplocate 0",
        "savemap site_b",
        "set_mappath site_b",
        "rm_map site_a",
    ] {
        ok(&mut admin, request).await;
    }
    daemon.signal("KILL");
    assert!(!daemon.wait().success());
    let (daemon, kept) = kept_state(dir.path()).await;
    assert_eq!(kept, (Value::Bool(false), Value::Bool(false), "site_b".into()));
    let mut admin = Conn::login(&daemon.url, "1025").await;
    ok(&mut admin, "admin_lock").await;
    daemon.signal("KILL");
    assert!(!daemon.wait().success());
    let (_daemon, kept) = kept_state(dir.path()).await;
    assert_eq!(
        kept.0, true,
        "a crash while an admin holds the lock comes back locked"
    );
}

#[tokio::test]
async fn a_password_pinned_by_the_configuration_survives_passwd_and_a_restart() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let r = c.request("passwd n3wpass").await;
    assert_eq!(
        (r["ret"].as_i64(), r["msg"].as_str()),
        (Some(-1), Some("Password is set by the daemon's configuration")),
        "{r}"
    );
    let r = c.request("login n3wpass").await;
    assert_eq!(r["msg"], "Wrong password!", "{r}");
    c.close().await;
    assert!(daemon.terminate().success());
    assert!(!dir.path().join("password").exists(), "nothing was saved");

    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::connect(&daemon.url).await;
    let r = c.request(&format!("login {PASSWORD}")).await;
    assert_eq!(r["ret"], 0, "{r}");
}

#[tokio::test]
async fn sigterm_under_load_loses_no_acknowledged_save() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD).per_ip(32));
    let url = daemon.url.clone();
    let stop = Arc::new(AtomicBool::new(false));
    let answered = Arc::new(AtomicUsize::new(0));

    // Background load: sessions asking for state as fast as they are served.
    let sessions = join_all((0..20).map(|_| Conn::login(&url, PASSWORD))).await;
    let load = join_all(sessions.into_iter().map(|mut c| {
        let (stop, answered) = (Arc::clone(&stop), Arc::clone(&answered));
        async move {
            while !stop.load(Ordering::Relaxed) {
                if !c.try_send("state").await {
                    break;
                }
                match c.recv().await {
                    Received::Text(t) => {
                        parse_response(&t);
                        answered.fetch_add(1, Ordering::Relaxed);
                    }
                    Received::Close(code) => {
                        assert_eq!(code, Some(1001), "load sessions are closed with 1001");
                        break;
                    }
                    Received::Ended => break,
                    Received::Pong(_) => {}
                }
            }
        }
    }));

    // The writer: set and save a new value each round; a value counts as
    // acknowledged once `save_param 1` answered ret 0.
    let writer = async {
        let mut c = Conn::login(&url, "1025").await;
        let mut acked = None;
        let mut sent = 0;
        for value in 10.. {
            let set = format!("set_param autosleep_after:{value}");
            if !c.try_send(&set).await {
                break;
            }
            match c.recv().await {
                Received::Text(t) => assert_eq!(parse_response(&t)["ret"], 0, "{t}"),
                _ => break,
            }
            sent = value;
            if !c.try_send("save_param 1").await {
                break;
            }
            match c.recv().await {
                Received::Text(t) => {
                    assert_eq!(parse_response(&t)["ret"], 0, "{t}");
                    acked = Some(value);
                }
                _ => break,
            }
            if value == 40 {
                // Enough history: pull the plug while everyone is busy.
                daemon.signal("TERM");
            }
        }
        stop.store(true, Ordering::Relaxed);
        (acked, sent)
    };
    let ((acked, sent), ()) = tokio::join!(writer, async {
        load.await;
    });
    assert!(
        answered.load(Ordering::Relaxed) > 0,
        "the load sessions were served"
    );
    assert!(daemon.wait().success(), "SIGTERM exits 0");
    let acked = acked.expect("some saves were acknowledged");
    assert!(acked >= 40, "saves before SIGTERM were acknowledged ({acked})");

    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let r = c.request("get_param autosleep_after").await;
    let kept = param_value(&r, "autosleep_after")
        .as_i64()
        .expect("an integer parameter");
    assert!(
        (acked..=sent).contains(&kept),
        "the last acknowledged save ({acked}) or a later one survives, found {kept} ({r})"
    );
}

#[tokio::test]
async fn sigterm_answers_every_frame_already_received() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &Options::password(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    for _ in 0..100 {
        c.send("state").await;
    }
    daemon.signal("TERM");
    for i in 0..100 {
        match c.recv().await {
            Received::Text(t) => assert_eq!(parse_response(&t)["cmd"], 2, "reply {i}: {t}"),
            other => panic!("reply {i} of 100 is missing: got {other:?}"),
        }
    }
    assert_eq!(c.close_code().await, Some(1001));
    assert!(daemon.wait().success());
}
