//! lluavd on a hostile network (DESIGN.md, "Security defaults"): the
//! Origin and Host policy against cross-site WebSocket hijacking and DNS
//! rebinding, plain HTTP kept away from the protocol, password guessing
//! throttled per address across connections and across all addresses,
//! `wss://` from the `lluav` command line, and the public admin value
//! (refused beyond loopback unless allowed, then warned about).

use std::net::{IpAddr, Ipv4Addr};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use lluav_tests::{Conn, Lluavd, Options, WAIT, http_status, lluav_bin, test_ca, upgrade_request};

const PASSWORD: &str = "s3cret";
const THROTTLED: &str = "Too many wrong passwords, retry later";

fn daemon(options: &Options) -> (tempfile::TempDir, Lluavd) {
    let dir = tempfile::tempdir().expect("temp dir");
    let daemon = Lluavd::start(dir.path(), options);
    (dir, daemon)
}

#[tokio::test]
async fn an_upgrade_without_origin_or_from_the_servers_own_page_is_accepted() {
    let (_dir, d) = daemon(&Options::password(PASSWORD));
    let (code, answer) = http_status(d.addr, &upgrade_request(d.addr, "")).await;
    assert_eq!(code, 101, "{answer}");
    let own = format!("Origin: http://{}\r\n", d.addr);
    let (code, answer) = http_status(d.addr, &upgrade_request(d.addr, &own)).await;
    assert_eq!(code, 101, "a page served by the vehicle itself: {answer}");
    let localhost = format!("localhost:{}", d.addr.port());
    let request = upgrade_request(d.addr, &format!("Origin: http://{localhost}\r\n"))
        .replace(&format!("Host: {}", d.addr), &format!("Host: {localhost}"));
    let (code, answer) = http_status(d.addr, &request).await;
    assert_eq!(code, 101, "localhost names a loopback server: {answer}");
}

#[tokio::test]
async fn a_foreign_origin_gets_403_and_no_session() {
    let (_dir, d) = daemon(&Options::default());
    for origin in [
        "https://evil.example",
        "null",
        &format!("http://127.0.0.1:{}", d.addr.port() ^ 1),
    ] {
        let request = upgrade_request(d.addr, &format!("Origin: {origin}\r\n"));
        let (code, answer) = http_status(d.addr, &request).await;
        assert_eq!(code, 403, "Origin {origin}: {answer}");
        assert!(
            answer.contains("--allow-origin"),
            "the refusal says what to do: {answer}"
        );
    }
    // Without a password, a hijacked session could have flown the vehicle:
    // the daemon is still untouched.
    let mut c = Conn::connect(&d.url).await;
    let r = c.request("state").await;
    assert_eq!(r["state"]["armed"], false, "{r}");
}

#[tokio::test]
async fn a_rebound_host_name_gets_403_even_when_origin_matches_it() {
    let (_dir, d) = daemon(&Options::default());
    let evil = format!("evil.example:{}", d.addr.port());
    let request = upgrade_request(d.addr, &format!("Origin: http://{evil}\r\n"))
        .replace(&format!("Host: {}", d.addr), &format!("Host: {evil}"));
    let (code, answer) = http_status(d.addr, &request).await;
    assert_eq!(code, 403, "{answer}");
    assert!(answer.contains("--allow-host"), "{answer}");
}

#[tokio::test]
async fn allow_lists_admit_exactly_what_they_name() {
    let options = Options::default().with_args(&[
        "--allow-origin",
        "https://gcs.example:8443",
        "--allow-host",
        "drone.local",
    ]);
    let (_dir, d) = daemon(&options);
    let cases = [
        ("Origin: https://gcs.example:8443\r\n", None, 101),
        ("Origin: https://gcs.example\r\n", None, 403),
        (
            "Origin: http://drone.local:53001\r\n",
            Some("drone.local:53001"),
            101,
        ),
        ("", Some("drone.local"), 101),
        ("", Some("other.local"), 403),
    ];
    for (origin, host, expected) in cases {
        let mut request = upgrade_request(d.addr, origin);
        if let Some(host) = host {
            request = request.replace(&format!("Host: {}", d.addr), &format!("Host: {host}"));
        }
        let (code, answer) = http_status(d.addr, &request).await;
        assert_eq!(code, expected, "{origin:?} {host:?}: {answer}");
    }
    let (_dir, any) = daemon(&Options::default().with_args(&["--allow-origin", "*"]));
    let request = upgrade_request(any.addr, "Origin: https://anything.example\r\n");
    assert_eq!(
        http_status(any.addr, &request).await.0,
        101,
        "* allows any origin"
    );
}

#[tokio::test]
async fn plain_http_requests_never_reach_the_protocol() {
    let (_dir, d) = daemon(&Options::default());
    let host = d.addr;
    for (request, not) in [
        (format!("GET /state HTTP/1.1\r\nHost: {host}\r\n\r\n"), "\"ret\""),
        (
            format!("POST / HTTP/1.1\r\nHost: {host}\r\nContent-Length: 5\r\n\r\nstate"),
            "\"ret\"",
        ),
        (
            format!("GET / HTTP/1.1\r\nHost: {host}\r\nUpgrade: h2c\r\nConnection: Upgrade\r\n\r\n"),
            "\"ret\"",
        ),
    ] {
        let (code, answer) = http_status(d.addr, &request).await;
        assert!((200..500).contains(&code) && code != 101, "{request:?}: {answer}");
        assert!(!answer.contains(not), "{answer}");
    }
    let (code, _) = http_status(d.addr, &format!("POST / HTTP/1.1\r\nHost: {host}\r\n\r\n")).await;
    assert_eq!(code, 405);
}

#[tokio::test]
async fn malformed_upgrades_get_their_http_status() {
    let (_dir, d) = daemon(&Options::default());
    let key = "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==";
    let cases = [
        (
            upgrade_request(d.addr, "").replace("Version: 13", "Version: 7"),
            426,
        ),
        (
            upgrade_request(d.addr, "").replace(key, "Sec-WebSocket-Key: abc"),
            400,
        ),
        (upgrade_request(d.addr, "").replacen("GET", "PUT", 1), 405),
        (
            upgrade_request(d.addr, &format!("X-Junk: {}\r\n", "j".repeat(9000))),
            431,
        ),
        ("GARBAGE\r\n\r\n".to_owned(), 400),
    ];
    for (request, expected) in cases {
        let (code, answer) = http_status(d.addr, &request).await;
        assert_eq!(code, expected, "{answer}");
    }
}

/// Logs in with `attempt` on a fresh connection and returns the answer's
/// message (empty on success).
async fn login_once(url: &str, attempt: &str) -> String {
    let mut c = Conn::connect(url).await;
    let r = c.request(&format!("login {attempt}")).await;
    r["msg"].as_str().unwrap_or("").to_owned()
}

#[tokio::test]
async fn five_wrong_passwords_lock_the_address_out_across_connections_until_the_lockout_ends() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--login-lockout", "2"]));
    for i in 0..5 {
        assert_eq!(login_once(&d.url, "guess").await, "Wrong password!", "guess {i}");
    }
    let locked_at = Instant::now();
    assert_eq!(login_once(&d.url, "guess").await, THROTTLED);
    assert_eq!(login_once(&d.url, PASSWORD).await, THROTTLED, "not even checked");
    // The first lockout lasts --login-lockout (2 s): wait it out.
    loop {
        let msg = login_once(&d.url, PASSWORD).await;
        if msg.is_empty() {
            break;
        }
        assert_eq!(msg, THROTTLED);
        assert!(locked_at.elapsed() < WAIT, "the lockout never ended");
        tokio::time::sleep(Duration::from_millis(200)).await;
    }
    assert!(
        locked_at.elapsed() >= Duration::from_millis(1500),
        "{:?}",
        locked_at.elapsed()
    );
}

#[tokio::test]
async fn a_login_refused_by_the_lockout_says_when_to_retry() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--login-lockout", "30"]));
    for i in 0..5 {
        assert_eq!(login_once(&d.url, "guess").await, "Wrong password!", "guess {i}");
    }
    let mut c = Conn::connect(&d.url).await;
    let r = c.request(&format!("login {PASSWORD}")).await;
    assert_eq!(
        (r["ret"].as_i64(), r["msg"].as_str()),
        (Some(-1), Some(THROTTLED)),
        "{r}"
    );
    let after = r["retry_after_s"].as_u64().expect("retry_after_s");
    assert!(
        (29..=30).contains(&after),
        "the 30 s lockout, in whole seconds: {r}"
    );
    let r = c.request("login guess").await;
    assert!(r["retry_after_s"].as_u64().is_some_and(|s| s <= after), "{r}");
}

#[tokio::test]
async fn the_public_logout_value_does_not_reset_the_count() {
    let (_dir, d) = daemon(&Options::password(PASSWORD));
    let mut c = Conn::connect(&d.url).await;
    for _ in 0..4 {
        assert_eq!(c.request("login guess").await["msg"], "Wrong password!");
    }
    assert_eq!(c.request("login 0315").await["ret"], 0);
    assert_eq!(c.request("login guess").await["msg"], "Wrong password!");
    assert_eq!(
        c.close_code().await,
        Some(1008),
        "the fifth in a row closes the session"
    );
    assert_eq!(login_once(&d.url, PASSWORD).await, THROTTLED);
}

/// Sends `attempts` on one connection from the loopback address `source`;
/// returns how many were checked and found wrong.
async fn guesses_from(d: &Lluavd, source: IpAddr, attempts: &[&str]) -> usize {
    let mut c = Conn::connect_from(source, d.addr).await.expect("connect");
    let mut checked = 0;
    for attempt in attempts {
        let r = c.request(&format!("login {attempt}")).await;
        match r["msg"].as_str() {
            Some("Wrong password!") => checked += 1,
            Some(THROTTLED) => {}
            _ => panic!("login {attempt} from {source}: {r}"),
        }
    }
    c.close().await;
    checked
}

/// 127.0.0.1 locked out, then four wrong passwords from each of 120 other
/// loopback addresses, as fast as they go: how many of those were checked,
/// and how long they took.
async fn lock_then_swarm(d: &Lluavd) -> (usize, Duration) {
    let victim = IpAddr::V4(Ipv4Addr::LOCALHOST);
    assert_eq!(guesses_from(d, victim, &["guess"; 5]).await, 5);
    let start = Instant::now();
    let mut checked = 0;
    for host in 2..122 {
        let source = IpAddr::V4(Ipv4Addr::new(127, 0, 0, host));
        checked += guesses_from(d, source, &["guess"; 4]).await;
    }
    (checked, start.elapsed())
}

#[tokio::test]
async fn many_addresses_guessing_are_held_to_the_budget_and_cannot_unlock_an_address() {
    let (_dir, d) = daemon(&Options::password(PASSWORD).with_args(&["--login-rate", "10"]));
    let (checked, took) = lock_then_swarm(&d).await;
    // A bucket of 10 (5 left after the victim's guesses) refilled at 10
    // per second: a bound that a slower run only loosens.
    let bound = 5 + (took.as_secs_f64() * 10.0).ceil() as usize;
    assert!(
        (5..=bound).contains(&checked),
        "{checked} wrong passwords checked in {took:?}"
    );
    let victim = IpAddr::V4(Ipv4Addr::LOCALHOST);
    let mut c = Conn::connect_from(victim, d.addr).await.expect("connect");
    assert_eq!(c.request(&format!("login {PASSWORD}")).await["msg"], THROTTLED);
}

#[tokio::test]
async fn a_full_lockout_table_keeps_a_locked_address_and_checks_nobody_new() {
    let (_dir, d) =
        daemon(&Options::password(PASSWORD).with_args(&["--login-addresses", "16", "--login-rate", "1000"]));
    let (checked, _) = lock_then_swarm(&d).await;
    // 15 addresses find a free record each and are checked four times;
    // then the table is full of records that matter, and nobody new is.
    assert_eq!(checked, 15 * 4);
    let late = IpAddr::V4(Ipv4Addr::new(127, 0, 0, 200));
    let mut c = Conn::connect_from(late, d.addr).await.expect("connect");
    assert_eq!(c.request(&format!("login {PASSWORD}")).await["msg"], THROTTLED);
    let victim = IpAddr::V4(Ipv4Addr::LOCALHOST);
    let mut c = Conn::connect_from(victim, d.addr).await.expect("connect");
    assert_eq!(c.request(&format!("login {PASSWORD}")).await["msg"], THROTTLED);
    // A recorded address is still checked.
    let known = IpAddr::V4(Ipv4Addr::new(127, 0, 0, 2));
    let mut c = Conn::connect_from(known, d.addr).await.expect("connect");
    assert_eq!(c.request(&format!("login {PASSWORD}")).await["ret"], 0);
}

#[test]
fn lluav_speaks_wss_with_a_cafile_and_refuses_an_unknown_certificate() {
    let dir = tempfile::tempdir().expect("temp dir");
    let options = Options {
        tls: true,
        ..Options::password(PASSWORD)
    };
    let d = Lluavd::start(dir.path(), &options);
    assert!(
        d.url.starts_with("wss://"),
        "the listening line says wss://: {}",
        d.url
    );
    let run = |cafile: Option<&std::path::Path>| {
        let mut cmd = Command::new(lluav_bin());
        cmd.args(["--url", &d.url, "--password", PASSWORD]);
        if let Some(f) = cafile {
            cmd.arg("--cafile").arg(f);
        }
        cmd.args(["state"])
            .env_remove("LLUAV_PASSWORD")
            .env_remove("LLUAV_CAFILE")
            .output()
            .expect("lluav runs")
    };
    let ok = run(Some(&test_ca().ca_file()));
    let stdout = String::from_utf8_lossy(&ok.stdout);
    assert!(
        ok.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&ok.stderr)
    );
    assert!(stdout.contains("\"fsm\""), "{stdout}");
    let refused = run(None);
    let stderr = String::from_utf8_lossy(&refused.stderr);
    assert_eq!(refused.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.to_lowercase().contains("certificate"),
        "says why: {stderr}"
    );
    assert!(stderr.contains("--cafile"), "and what to do: {stderr}");
}

#[test]
fn plain_ws_to_a_wss_port_gets_nothing_and_breaks_nothing() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = Lluavd::start(
        dir.path(),
        &Options {
            tls: true,
            ..Options::password(PASSWORD)
        },
    );
    let plain = d.url.replacen("wss://", "ws://", 1);
    let runtime = tokio::runtime::Runtime::new().expect("runtime");
    runtime.block_on(async {
        assert!(
            Conn::try_connect(&plain).await.is_err(),
            "no WebSocket without TLS"
        );
        let mut c = Conn::login(&d.url, PASSWORD).await;
        assert_eq!(c.request("state").await["ret"], 0);
    });
}

/// The daemon's stderr once its start-up lines are in (the warning comes
/// before `lluavd ready`; stderr is read by another thread).
fn startup_log(d: &Lluavd) -> String {
    let start = Instant::now();
    loop {
        let log = d.stderr();
        if log.contains("lluavd ready") || start.elapsed() > WAIT {
            return log;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn a_public_admin_value_beyond_loopback_is_refused_unless_allowed_and_then_warned_about() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Bound to every interface (the test talks to it over loopback only).
    let every = ["--bind", "0.0.0.0:0"];
    let refused = Lluavd::try_start(dir.path(), &Options::password(PASSWORD), &every);
    let Err((status, stderr)) = refused else {
        panic!("lluavd listened on 0.0.0.0 with the public admin value");
    };
    assert_eq!(status.and_then(|s| s.code()), Some(2), "{stderr}");
    assert!(
        stderr.contains("admin_password") && stderr.contains("--allow-default-admin"),
        "the refusal says what to do: {stderr}"
    );
    let allowed = Options::password(PASSWORD).with_args(&["--allow-default-admin"]);
    let d = Lluavd::try_start(dir.path(), &allowed, &every)
        .unwrap_or_else(|(_, e)| panic!("lluavd did not start: {e}"));
    let stderr = startup_log(&d);
    assert_eq!(stderr.matches("admin_password").count(), 1, "{stderr}");
    drop(d);
    let d = Lluavd::try_start(&dir.path().join("data"), &own_admin_value(dir.path()), &every)
        .unwrap_or_else(|(_, e)| panic!("lluavd did not start: {e}"));
    let stderr = startup_log(&d);
    assert!(!stderr.contains("admin_password"), "{stderr}");
    let (_dir, local) = daemon(&Options::password(PASSWORD));
    assert!(
        !startup_log(&local).contains("admin_password"),
        "no warning on loopback"
    );
}

/// Options with a config file that sets the admin value.
fn own_admin_value(dir: &std::path::Path) -> Options {
    let config = dir.join("lluavd.toml");
    std::fs::write(&config, "admin_password = \"9y7x\"\n").expect("config written");
    Options::password(PASSWORD).with_args(&["--config", config.to_str().expect("UTF-8 path")])
}

#[tokio::test]
async fn with_its_own_admin_value_1025_is_an_ordinary_wrong_password() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = Lluavd::try_start(
        &dir.path().join("data"),
        &own_admin_value(dir.path()),
        &["--bind", "0.0.0.0:0"],
    )
    .unwrap_or_else(|(_, e)| panic!("lluavd did not start: {e}"));
    let url = format!("ws://127.0.0.1:{}", d.addr.port());
    let mut c = Conn::connect(&url).await;
    for _ in 0..2 {
        assert_eq!(c.request("login guess").await["msg"], "Wrong password!");
    }
    assert_eq!(
        c.request("login 1025").await["msg"],
        "Wrong password!",
        "no admin"
    );
    for _ in 0..2 {
        assert_eq!(c.request("login guess").await["msg"], "Wrong password!");
    }
    assert_eq!(
        c.close_code().await,
        Some(1008),
        "1025 counted: the fifth wrong password in a row closes the session"
    );
    assert_eq!(login_once(&url, "1025").await, THROTTLED);
    assert_eq!(
        login_once(&url, "9y7x").await,
        THROTTLED,
        "the address is locked out"
    );
}

/// Starts lluavd serving `wss://` with the certificate and key in `files`
/// and further arguments; on failure its exit status and stderr.
fn start_tls(
    dir: &Path,
    (cert, key): &(PathBuf, PathBuf),
    args: &[&str],
) -> Result<Lluavd, (Option<i32>, String)> {
    let options = Options::password(PASSWORD)
        .with_args(&["--tls-cert", cert.to_str().expect("UTF-8 path")])
        .with_args(&["--tls-key", key.to_str().expect("UTF-8 path")])
        .with_args(args);
    Lluavd::try_start(&dir.join("data"), &options, &[])
        .map_err(|(status, e)| (status.and_then(|s| s.code()), e))
}

#[test]
fn certificates_no_client_accepts_are_refused_at_start_saying_why() {
    let dir = tempfile::tempdir().expect("temp dir");
    let names = ["localhost", "127.0.0.1"];
    let issue = |sub: &str, customise: &dyn Fn(&mut rcgen::CertificateParams)| {
        test_ca().issue_with(&dir.path().join(sub), &names, customise)
    };
    let expired = issue("expired", &|p| {
        (p.not_before, p.not_after) = (rcgen::date_time_ymd(2020, 1, 1), rcgen::date_time_ymd(2021, 1, 1));
    });
    let early = issue("early", &|p| {
        (p.not_before, p.not_after) = (rcgen::date_time_ymd(2090, 1, 1), rcgen::date_time_ymd(2091, 1, 1));
    });
    let ca = issue("ca", &|p| {
        p.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained)
    });
    let (mine, other) = (issue("mine", &|_| {}), issue("other", &|_| {}));
    let mismatched = (mine.0, other.1);
    for (files, why) in [
        (&expired, "expired"),
        (&early, "is not valid before"),
        (&ca, "is a CA certificate"),
        (&mismatched, "is not the key of the certificate"),
    ] {
        match start_tls(dir.path(), files, &[]) {
            Ok(_) => panic!("lluavd served a certificate that {why}"),
            Err((code, stderr)) => {
                assert_eq!(code, Some(2), "{stderr}");
                assert!(stderr.contains(why), "the refusal says `{why}`: {stderr}");
            }
        }
    }
}

#[test]
fn a_certificate_for_none_of_the_daemons_names_is_warned_about() {
    let dir = tempfile::tempdir().expect("temp dir");
    let warning = "names none of the addresses";
    let elsewhere = test_ca().issue_with(&dir.path().join("elsewhere"), &["elsewhere.example"], |_| {});
    let d = start_tls(dir.path(), &elsewhere, &[]).unwrap_or_else(|(_, e)| panic!("did not start: {e}"));
    assert_eq!(startup_log(&d).matches(warning).count(), 1, "{}", d.stderr());
    drop(d);
    let d = start_tls(dir.path(), &elsewhere, &["--allow-host", "elsewhere.example"])
        .unwrap_or_else(|(_, e)| panic!("did not start: {e}"));
    assert!(!startup_log(&d).contains(warning), "{}", d.stderr());
    let own = test_ca().issue(&dir.path().join("own"));
    let d = start_tls(dir.path(), &own, &[]).unwrap_or_else(|(_, e)| panic!("did not start: {e}"));
    assert!(!startup_log(&d).contains(warning), "{}", d.stderr());
}
