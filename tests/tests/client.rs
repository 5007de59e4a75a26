//! The client side against the real lluavd: the typed library
//! (`lluav_host::client`) and the `lluav` command line, one-shot and REPL.

use std::io::Write as _;
use std::process::{Command, Output, Stdio};

use lluav_core::{Args, CommandId, Pose, TABLE};
use lluav_host::client::{Client, ClientError};
use lluav_tests::{Lluavd, Options, WAIT, lluav_bin};

const PASSWORD: &str = "s3cret";

#[tokio::test]
async fn typed_client_flies_a_short_session() {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        sim_speed: Some(10.0),
        ..Options::password(PASSWORD)
    };
    let daemon = Lluavd::start(dir.path(), &options);
    let mut client = Client::connect(&daemon.url).await.expect("connects");

    let refused = client.state().await.expect("answered");
    assert_eq!((refused.ret, refused.msg()), (-1, Some("Login first!")));
    assert!(matches!(refused.check(), Err(ClientError::Failed(r)) if r.command() == Some(CommandId::State)));

    let login = client
        .login(PASSWORD)
        .await
        .expect("answered")
        .check()
        .expect("logged in");
    assert_eq!(login.fields["logged_in"], true);
    let takeoff = client.takeoff().await.expect("answered");
    assert_eq!((takeoff.ret, takeoff.command()), (0, Some(CommandId::Takeoff)));
    let pose = Pose {
        x: 1.0,
        y: 2.0,
        z: -3.0,
        yaw: 0.5,
    };
    assert_eq!(client.set_sp_ned(pose).await.expect("answered").ret, 0);
    let reboot = client.bare(CommandId::RebootNode).await.expect("answered");
    assert_eq!(reboot.msg(), Some("Not allow when vehicle is ARMED!"));
    assert_eq!(client.land().await.expect("answered").ret, 0);

    // Arguments are checked before anything is sent.
    let bad = client.call(CommandId::Ara8Pitch, Args::Angle(120.0)).await;
    assert!(
        matches!(bad, Err(ClientError::InvalidArgs(CommandId::Ara8Pitch, _))),
        "{bad:?}"
    );
    let typo = client.send_line("stat").await;
    assert!(
        matches!(&typo, Err(ClientError::Parse(m)) if m == "Unsupported command: stat"),
        "{typo:?}"
    );

    // Every command of the table is reachable through the typed client.
    let help = client.bare(CommandId::Help).await.expect("answered");
    let listed = help.fields["commands"].as_array().map_or(0, Vec::len);
    assert_eq!(listed, TABLE.len());
    client.close().await.expect("clean close");
}

fn lluav(args: &[&str], stdin: Option<&str>, home: &std::path::Path) -> Output {
    let mut child = Command::new(lluav_bin())
        .args(args)
        .env_remove("LLUAV_PASSWORD")
        .env("HOME", home)
        .env_remove("XDG_STATE_HOME")
        .env_remove("XDG_DATA_HOME")
        .stdin(if stdin.is_some() {
            Stdio::piped()
        } else {
            Stdio::null()
        })
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("lluav starts");
    if let (Some(text), Some(mut pipe)) = (stdin, child.stdin.take()) {
        pipe.write_all(text.as_bytes()).expect("stdin written");
    }
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(child.wait_with_output());
    });
    rx.recv_timeout(WAIT)
        .expect("lluav finishes in time")
        .expect("lluav output")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

#[test]
fn lluav_one_shot_prints_pretty_json_and_exits_by_ret() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(&dir.path().join("data"), &Options::password(PASSWORD));
    let url = daemon.url.as_str();
    let home = dir.path();

    let out = lluav(&["--url", url, "--password", PASSWORD, "state"], None, home);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    assert!(
        stdout.starts_with("{\n  \"ret\": 0,\n  \"cmd\": 2,\n  \"ts\": "),
        "{stdout}"
    );
    let state: serde_json::Value = serde_json::from_str(&stdout).expect("JSON on stdout");
    assert_eq!(state["state"]["armed"], false);

    let out = lluav(&["--url", url, "state"], None, home);
    assert_eq!(out.status.code(), Some(1), "ret < 0 fails");
    assert!(
        text(&out.stderr).contains("Login first!"),
        "{}",
        text(&out.stderr)
    );

    let out = lluav(&["--url", url, "--password", "wrong", "state"], None, home);
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("Wrong password!"),
        "{}",
        text(&out.stderr)
    );

    let out = lluav(
        &["--url", url, "--password", PASSWORD, "set_sp_ned", "1:2"],
        None,
        home,
    );
    assert_eq!(out.status.code(), Some(2));
    assert!(
        text(&out.stderr).contains("usage: set_sp_ned x:y:z:yaw"),
        "{}",
        text(&out.stderr)
    );

    // Setpoints are for a vehicle in the air.
    let out = lluav(&["--url", url, "--password", PASSWORD, "takeoff"], None, home);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let out = lluav(
        &["--url", url, "--password", PASSWORD, "set_sp_ned", "1:2:-3:0.5"],
        None,
        home,
    );
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
}

#[test]
fn lluav_reports_an_unreachable_daemon() {
    let dir = tempfile::tempdir().expect("temp dir");
    // A port that was free a moment ago: nothing listens there.
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let url = format!("ws://127.0.0.1:{port}");
    let out = lluav(&["--url", &url, "state"], None, dir.path());
    assert_eq!(out.status.code(), Some(1));
    let stderr = text(&out.stderr);
    assert!(
        stderr.contains("cannot connect") && stderr.contains("is lluavd running?"),
        "{stderr}"
    );
}

#[test]
fn lluav_repl_runs_commands_and_local_help() {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(&dir.path().join("data"), &Options::password(PASSWORD));
    let script = "help\nhelp set_sp_ned\nstate\nbogus\nquit\n";
    let out = lluav(
        &["--url", &daemon.url, "--password", PASSWORD],
        Some(script),
        dir.path(),
    );
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    let stdout = text(&out.stdout);
    for spec in &TABLE {
        assert!(stdout.contains(spec.usage), "help lists `{}`", spec.usage);
    }
    assert!(stdout.contains("Set the NED setpoint"), "{stdout}");
    assert!(stdout.contains("\"fsm\": \"disarmed\""), "{stdout}");
    assert!(
        text(&out.stderr).contains("Unsupported command: bogus"),
        "{}",
        text(&out.stderr)
    );
    let history =
        std::fs::read_to_string(dir.path().join(".local/state/lluav/repl-history")).expect("history kept");
    assert!(
        history.contains("help set_sp_ned") && history.contains("state"),
        "{history}"
    );
}
