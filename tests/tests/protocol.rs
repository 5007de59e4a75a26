//! The protocol as a client sees it from lluavd: login and gates, a whole
//! flight of the simulated vehicle, and every command of the table; each
//! over `ws://` and over `wss://`.

use lluav_core::{CommandId, TABLE};
use lluav_tests::{Conn, Lluavd, Options, Scheme, sample_args, wait_for_state};
use serde_json::Value;

const PASSWORD: &str = "s3cret";

lluav_tests::over_ws_and_wss!(
    login_and_gates_follow_the_design,
    a_whole_flight_takes_off_follows_setpoints_and_lands,
    every_command_of_the_table_gets_exactly_one_valid_response,
    showmsg_shows_the_daemons_own_log_lines,
    a_new_password_applies_to_every_session,
);

fn msg(r: &Value) -> &str {
    r["msg"].as_str().unwrap_or("")
}

async fn login_and_gates_follow_the_design(scheme: Scheme) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &scheme.options(PASSWORD));
    let mut user = Conn::connect(&daemon.url).await;

    let r = user.request("state").await;
    assert_eq!(
        (r["ret"].as_i64(), r["cmd"].as_i64(), msg(&r)),
        (Some(-1), Some(2), "Login first!")
    );
    let r = user.request("no_such_command").await;
    assert_eq!(
        (r["cmd"].as_i64(), msg(&r)),
        (Some(0), "Login first!"),
        "login gate comes first"
    );
    let r = user.request("login wrong").await;
    assert_eq!((r["ret"].as_i64(), msg(&r)), (Some(-1), "Wrong password!"));
    let r = user.request(&format!("login {PASSWORD}")).await;
    assert_eq!(
        (r["ret"].as_i64(), &r["logged_in"], &r["admin"]),
        (Some(0), &Value::Bool(true), &Value::Bool(false))
    );
    let r = user.request("admin_lock").await;
    assert_eq!((r["ret"].as_i64(), msg(&r)), (Some(-1), "Admin only!"));

    let mut admin = Conn::connect(&daemon.url).await;
    let r = admin.request("login 1025").await;
    assert_eq!((r["ret"].as_i64(), &r["admin"]), (Some(0), &Value::Bool(true)));
    let r = admin.request("admin_lock").await;
    assert_eq!(
        (r["ret"].as_i64(), &r["lock_mode"]),
        (Some(0), &Value::Bool(true))
    );

    // Lock mode is vehicle-wide: the user's session sees it too.
    let r = user.request("set_param takeoff_alt:3").await;
    assert_eq!(
        (r["ret"].as_i64(), msg(&r)),
        (Some(-1), "CMD not permitted to run in LOCK mode!")
    );
    let r = user.request("state").await;
    assert_eq!(r["state"]["lock_mode"], true, "{r}");
    let r = admin.request("set_param takeoff_alt:3").await;
    assert_eq!(r["ret"], 0, "admins skip the lock gate: {r}");

    let r = admin.request("admin_unlock").await;
    assert_eq!(
        (r["ret"].as_i64(), &r["lock_mode"]),
        (Some(0), &Value::Bool(false))
    );
    let r = user.request("set_param takeoff_alt:4").await;
    assert_eq!(r["ret"], 0, "{r}");

    let r = user.request("login 0315").await;
    assert_eq!(
        (r["ret"].as_i64(), &r["logged_in"]),
        (Some(0), &Value::Bool(false))
    );
    let r = user.request("state").await;
    assert_eq!(msg(&r), "Login first!");
    user.close().await;
    admin.close().await;
}

async fn a_whole_flight_takes_off_follows_setpoints_and_lands(scheme: Scheme) {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        sim_speed: Some(10.0),
        ..scheme.options(PASSWORD)
    };
    let daemon = Lluavd::start(dir.path(), &options);
    let mut c = Conn::login(&daemon.url, PASSWORD).await;

    let r = c.request("state").await;
    assert_eq!(
        (&r["state"]["armed"], &r["state"]["fsm"]),
        (&Value::Bool(false), &Value::from("disarmed"))
    );
    let r = c.request("takeoff").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = c.request("state").await;
    assert_eq!(r["state"]["armed"], true, "takeoff arms at once: {r}");
    wait_for_state(&mut c, "hover", |s| s["fsm"] == "hover").await;

    let r = c.request("set_sp_ned 1.0:2.0:-3.0:0.5").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = c.request("show_sp").await;
    assert_eq!(r["ret"], 0, "{r}");

    let r = c.request("reboot_node").await;
    assert_eq!(
        (r["ret"].as_i64(), r["cmd"].as_i64(), msg(&r)),
        (Some(-1), Some(69), "Not allow when vehicle is ARMED!")
    );
    let r = c.request("takeoff").await;
    assert_eq!(msg(&r), "Not allow when vehicle is ARMED!");

    let r = c.request("land").await;
    assert_eq!(r["ret"], 0, "{r}");
    wait_for_state(&mut c, "landed and disarmed", |s| s["armed"] == false).await;
    let r = c.request("disarm").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = c.request("state").await;
    assert_eq!(r["state"]["fsm"], "disarmed", "{r}");
    let r = c.request("reboot_node").await;
    assert_ne!(msg(&r), "Not allow when vehicle is ARMED!", "disarmed again: {r}");
    c.close().await;
}

async fn every_command_of_the_table_gets_exactly_one_valid_response(scheme: Scheme) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &scheme.options(PASSWORD));
    let mut c = Conn::login(&daemon.url, "1025").await;
    for spec in &TABLE {
        let args = sample_args(spec.grammar);
        let frame = if args.is_empty() {
            spec.name().to_owned()
        } else {
            format!("{} {args}", spec.name())
        };
        assert!(
            lluav_core::parse(&frame).is_ok(),
            "the sample `{frame}` must be valid"
        );
        let r = c.request(&frame).await;
        assert_eq!(
            r["cmd"].as_i64(),
            Some(i64::from(u8::from(spec.id))),
            "`{frame}`: {r}"
        );
        // The grammar holds; the vehicle may still refuse a value (a map
        // that does not exist is `Invalid arguments: <reason>`).
        assert!(!msg(&r).starts_with("Invalid arguments, usage"), "`{frame}`: {r}");
        assert_ne!(r["ret"], -100, "`{frame}` hit a fault in the simulator: {r}");
        if spec.id == CommandId::Help {
            let names: Vec<&str> = TABLE.iter().map(|s| s.name()).collect();
            assert_eq!(r["commands"], serde_json::json!(names), "help lists the table");
        }
        if spec.id == CommandId::State {
            for key in ["armed", "fsm", "lock_mode"] {
                assert!(!r["state"][key].is_null(), "state has `{key}`: {r}");
            }
        }
        // Keep the vehicle on the ground and awake so that the next command
        // reaches the backend instead of a gate.
        let s = c.request("state").await;
        if s["state"]["armed"] == true {
            let r = c.request("disarm").await;
            assert_eq!(r["ret"], 0, "{r}");
        }
        if s["state"]["fsm"] == "sleep" {
            let r = c.request("wakeup").await;
            assert_eq!(r["ret"], 0, "{r}");
        }
    }
    // Nothing more arrives: one response per request.
    let r = c.request("ver").await;
    assert_eq!(r["cmd"], u8::from(CommandId::Ver), "{r}");
    c.close().await;
}

async fn showmsg_shows_the_daemons_own_log_lines(scheme: Scheme) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), &scheme.options(PASSWORD));
    let mut c = Conn::login(&daemon.url, PASSWORD).await;
    let r = c.request("showmsg 50").await;
    assert_eq!(r["ret"], 0, "{r}");
    let lines: Vec<&str> = r["msgs"]
        .as_array()
        .map(|a| a.iter().filter_map(Value::as_str).collect())
        .unwrap_or_default();
    assert!(
        lines.iter().any(|l| l.contains("lluavd ready")),
        "the start-up log line reaches showmsg: {r}"
    );
}

async fn a_new_password_applies_to_every_session(scheme: Scheme) {
    let dir = tempfile::tempdir().expect("temp dir");
    // A saved password, not a configured one: passwd may change it.
    std::fs::write(dir.path().join("password"), PASSWORD).expect("password saved");
    let daemon = Lluavd::start(
        dir.path(),
        &Options {
            tls: scheme == Scheme::Wss,
            ..Options::default()
        },
    );
    let mut a = Conn::login(&daemon.url, PASSWORD).await;
    let mut b = Conn::connect(&daemon.url).await;
    let r = a.request("passwd changed1").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = b.request(&format!("login {PASSWORD}")).await;
    assert_eq!(r["msg"], "Wrong password!", "the old password is gone: {r}");
    let r = b.request("login changed1").await;
    assert_eq!(r["ret"], 0, "{r}");
    let r = a.request("state").await;
    assert_eq!(r["ret"], 0, "the session that changed it stays logged in: {r}");
}
