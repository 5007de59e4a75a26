//! lluavd as a systemd service, with this test playing systemd: the
//! notification socket (`READY=1` after the listening line, `WATCHDOG=1`
//! every half `WATCHDOG_USEC`, `STATUS=`, `STOPPING=1` on SIGTERM), the
//! journal's stream (`<N>` priority prefixes), `--check-config`, and the
//! packaged config file against the daemon's own defaults.

use std::collections::BTreeMap;
use std::io::{BufRead, BufReader};
use std::os::fd::AsRawFd as _;
use std::os::unix::fs::MetadataExt as _;
use std::os::unix::net::UnixDatagram;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdout, Command, Output, Stdio};
use std::time::{Duration, Instant};

use lluav_tests::{Conn, WAIT, lluavd_bin};

/// What the test sets as `WATCHDOG_USEC`: lluavd should pet every second.
const WATCHDOG: Duration = Duration::from_secs(2);

/// systemd's side of the notification socket.
struct Systemd {
    socket: UnixDatagram,
    path: PathBuf,
    _dir: tempfile::TempDir,
}

impl Systemd {
    fn new() -> Systemd {
        let dir = tempfile::tempdir().expect("temp dir");
        let path = dir.path().join("notify");
        let socket = UnixDatagram::bind(&path).expect("notify socket");
        Systemd {
            socket,
            path,
            _dir: dir,
        }
    }

    /// The next notification, with when it arrived.
    fn next(&self) -> (Instant, String) {
        self.socket.set_read_timeout(Some(WAIT)).expect("timeout set");
        let mut buf = [0u8; 4096];
        let n = loop {
            match self.socket.recv(&mut buf) {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
                other => break other.expect("a notification in time"),
            }
        };
        let text = String::from_utf8_lossy(buf.get(..n).unwrap_or_default()).into_owned();
        (Instant::now(), text)
    }

    /// Notifications until one has a line satisfying `want`; returns it and
    /// every notification seen on the way (itself included).
    fn until(&self, want: impl Fn(&str) -> bool) -> Vec<(Instant, String)> {
        let mut seen = Vec::new();
        loop {
            let (at, text) = self.next();
            let done = text.lines().any(&want);
            seen.push((at, text));
            if done {
                return seen;
            }
        }
    }

    /// Starts lluavd told to notify this socket, with `extra` environment.
    fn start(&self, data: &Path, extra: &[(&str, &str)]) -> Child {
        let mut cmd = Command::new(lluavd_bin());
        cmd.args(["--bind", "127.0.0.1:0", "--data-dir"])
            .arg(data)
            .env("NOTIFY_SOCKET", &self.path)
            .env_remove("WATCHDOG_PID")
            .env_remove("LLUAV_PASSWORD")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::null());
        for (k, v) in extra {
            cmd.env(k, v);
        }
        cmd.spawn().expect("lluavd spawns")
    }
}

/// Whether `stdout` has something to read right now (without reading it).
fn readable_now(stdout: &ChildStdout) -> bool {
    let mut fd = libc::pollfd {
        fd: stdout.as_raw_fd(),
        events: libc::POLLIN,
        revents: 0,
    };
    loop {
        // SAFETY: one valid pollfd, for a descriptor the child handle owns.
        let n = unsafe { libc::poll(&mut fd, 1, 0) };
        let interrupted = std::io::Error::last_os_error().kind() == std::io::ErrorKind::Interrupted;
        if n != -1 || !interrupted {
            return n == 1 && fd.revents & libc::POLLIN != 0;
        }
    }
}

fn sigterm(child: &Child) {
    let status = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status()
        .expect("kill runs");
    assert!(status.success());
}

fn status_lines(seen: &[(Instant, String)]) -> Vec<String> {
    seen.iter()
        .flat_map(|(_, t)| {
            t.lines()
                .filter_map(|l| l.strip_prefix("STATUS="))
                .map(str::to_owned)
        })
        .collect()
}

#[tokio::test]
async fn ready_comes_after_the_listening_line_then_status_watchdog_and_stopping() {
    let systemd = Systemd::new();
    let data = tempfile::tempdir().expect("temp dir");
    let usec = WATCHDOG.as_micros().to_string();
    let mut child = systemd.start(data.path(), &[("WATCHDOG_USEC", &usec)]);
    let stdout = child.stdout.take().expect("stdout piped");

    let before_ready = systemd.until(|l| l == "READY=1");
    assert!(
        readable_now(&stdout),
        "READY=1 arrived before the listening line was written"
    );
    assert!(
        before_ready.iter().all(|(_, t)| !t.contains("WATCHDOG=1")),
        "no petting before READY=1: {before_ready:?}"
    );
    let line = BufReader::new(stdout)
        .lines()
        .next()
        .expect("a line")
        .expect("text");
    let url = line
        .strip_prefix("listening on ")
        .expect("the listening line")
        .to_owned();

    // It accepts connections; STATUS= counts the session, then its end.
    let mut conn = Conn::connect(&url).await;
    assert_eq!(conn.request("state").await["ret"], 0);
    let seen = systemd.until(|l| l == "STATUS=1 session; simulated vehicle");
    drop(conn);
    let mut all = before_ready;
    all.extend(seen);
    all.extend(systemd.until(|l| l == "STATUS=0 sessions; simulated vehicle"));

    // The watchdog's cadence: half of WATCHDOG_USEC, never a gap systemd
    // would kill the service for.
    let start = all.len();
    while all.len() < start + 5 {
        all.push(systemd.next());
    }
    let pets: Vec<Instant> = all
        .iter()
        .filter(|(_, t)| t.lines().any(|l| l == "WATCHDOG=1"))
        .map(|(at, _)| *at)
        .collect();
    let gaps: Vec<Duration> = pets.windows(2).map(|w| w[1] - w[0]).collect();
    assert!(gaps.len() >= 4, "{all:?}");
    assert!(
        gaps.iter().all(|g| *g < WATCHDOG),
        "a gap reached WATCHDOG_USEC: {gaps:?}"
    );
    let mut sorted = gaps.clone();
    sorted.sort();
    let median = sorted[sorted.len() / 2];
    assert!(
        median > WATCHDOG * 2 / 5 && median < WATCHDOG * 3 / 5,
        "pets every {median:?}, not every half WATCHDOG_USEC: {gaps:?}"
    );

    sigterm(&child);
    let stopping = systemd.until(|l| l == "STOPPING=1");
    assert_eq!(
        status_lines(&stopping).last().map(String::as_str),
        Some("stopping")
    );
    assert!(child.wait().expect("exit").success());
}

#[test]
fn another_process_watchdog_is_not_petted_but_status_still_goes() {
    let systemd = Systemd::new();
    let data = tempfile::tempdir().expect("temp dir");
    // WATCHDOG_PID names another process: the variables were inherited.
    let mut child = systemd.start(data.path(), &[("WATCHDOG_USEC", "200000"), ("WATCHDOG_PID", "1")]);
    let mut seen = systemd.until(|l| l == "READY=1");
    seen.extend(systemd.until(|l| l.starts_with("STATUS=0 sessions")));
    let deadline = Instant::now() + Duration::from_millis(800);
    systemd
        .socket
        .set_read_timeout(Some(Duration::from_millis(100)))
        .expect("timeout set");
    let mut buf = [0u8; 4096];
    while Instant::now() < deadline {
        if let Ok(n) = systemd.socket.recv(&mut buf) {
            seen.push((Instant::now(), String::from_utf8_lossy(&buf[..n]).into_owned()));
        }
    }
    assert!(seen.iter().all(|(_, t)| !t.contains("WATCHDOG=1")), "{seen:?}");
    sigterm(&child);
    assert!(child.wait().expect("exit").success());
}

/// Runs lluavd with stderr into a file and `JOURNAL_STREAM` set to that
/// file's identity (or to `stream` when given); returns what it logged.
fn logged_with_journal_stream(stream: Option<&str>) -> String {
    let dir = tempfile::tempdir().expect("temp dir");
    let log_path = dir.path().join("stderr");
    let log = std::fs::File::create(&log_path).expect("log file");
    let meta = log.metadata().expect("metadata");
    let identity = format!("{}:{}", meta.dev(), meta.ino());
    let mut child = Command::new(lluavd_bin())
        .args(["--bind", "127.0.0.1:0", "--data-dir"])
        .arg(dir.path().join("data"))
        .env("JOURNAL_STREAM", stream.unwrap_or(&identity))
        .env("RUST_LOG", "info")
        .env_remove("NOTIFY_SOCKET")
        .stdout(Stdio::piped())
        .stderr(log)
        .spawn()
        .expect("lluavd spawns");
    let stdout = child.stdout.take().expect("stdout piped");
    let line = BufReader::new(stdout).lines().next();
    assert!(line.is_some_and(|l| l.is_ok_and(|l| l.starts_with("listening on "))));
    sigterm(&child);
    assert!(child.wait().expect("exit").success());
    std::fs::read_to_string(&log_path).expect("log read")
}

#[test]
fn under_the_journal_lines_carry_priorities_instead_of_timestamps() {
    let journal = logged_with_journal_stream(None);
    let lines: Vec<&str> = journal.lines().collect();
    assert!(!lines.is_empty());
    assert!(lines.iter().all(|l| l.starts_with("<6>")), "{journal}");
    assert!(lines.iter().any(|l| l.contains("lluavd ready")), "{journal}");
    assert!(!journal.contains("INFO"), "the level word goes: {journal}");
    assert!(!journal.contains('\u{1b}'), "no colours: {journal}");

    // A JOURNAL_STREAM naming another stream (inherited) changes nothing.
    let plain = logged_with_journal_stream(Some("1:1"));
    assert!(plain.lines().all(|l| !l.starts_with('<')), "{plain}");
    assert!(plain.contains(" INFO "), "{plain}");
}

fn check_config(args: &[&str]) -> Output {
    Command::new(lluavd_bin())
        .arg("--check-config")
        .args(args)
        .env_remove("LLUAV_PASSWORD")
        .output()
        .expect("lluavd runs")
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("file written");
    path
}

#[test]
fn check_config_prints_the_effective_settings_with_secrets_masked() {
    let dir = tempfile::tempdir().expect("temp dir");
    let file = write(
        dir.path(),
        "good.toml",
        "bind = \"0.0.0.0:53001\"\npassword = \"hunter22\"\nmax_connections = 64\n\
         mavlink = \"serial:/dev/ttyAMA0:921600\"\nadmin_password = \"9y7x\"\n",
    );
    let out = check_config(&[
        "--config",
        file.to_str().expect("utf-8"),
        "--max-connections",
        "32",
    ]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "{text}{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(text.contains("\nbind = \"0.0.0.0:53001\"\n"), "{text}");
    assert!(text.contains("\npassword = \"********\"\n"), "{text}");
    assert!(!text.contains("hunter22") && !text.contains("9y7x"), "{text}");
    assert!(text.contains("\nmax_connections = 32\n"), "the flag wins: {text}");
    assert!(
        text.contains("\nmavlink = \"serial:/dev/ttyAMA0:921600\"\n"),
        "{text}"
    );
    assert!(
        text.contains("\nidle_timeout = 300\n"),
        "defaults are shown: {text}"
    );
}

#[test]
fn check_config_refuses_what_the_daemon_would_with_exit_status_2() {
    let dir = tempfile::tempdir().expect("temp dir");
    let cases = [
        ("pasword = \"x\"\n", "unknown field `pasword`"),
        ("login_timeout = 0\n", "--login-timeout must be > 0"),
        ("bind = \"nowhere\"\n", "invalid config file"),
        ("mavlink = \"/dev/ttyAMA0\"\n", "--mavlink must be"),
        ("password = \"two words\"\n", "invalid password settings"),
        (
            "bind = \"0.0.0.0:53001\"\npassword = \"hunter22\"\n",
            "the public admin login value 1025",
        ),
        (
            "tls_cert = \"/nonexistent/c.pem\"\ntls_key = \"/nonexistent/k.pem\"\n",
            "cannot serve wss://",
        ),
    ];
    for (i, (text, why)) in cases.iter().enumerate() {
        let file = write(dir.path(), &format!("bad{i}.toml"), text);
        let out = check_config(&["--config", file.to_str().expect("utf-8")]);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{text}: {stderr}");
        assert!(stderr.contains(why), "{text}: wanted {why:?} in {stderr}");
        assert!(out.stdout.is_empty(), "{text}");
    }
    let missing = check_config(&["--config", "/nonexistent/lluavd.toml"]);
    assert_eq!(missing.status.code(), Some(2));
}

/// `key = value` lines of a `--check-config` printout, and the keys it
/// prints as `# key: not set`.
fn printout(text: &str) -> (BTreeMap<String, toml::Value>, Vec<String>) {
    let mut set = BTreeMap::new();
    let mut unset = Vec::new();
    for line in text.lines() {
        if let Some(key) = line.strip_prefix("# ").and_then(|l| l.strip_suffix(": not set")) {
            unset.push(key.to_owned());
        } else if !line.starts_with('#') {
            set.extend(toml::from_str::<toml::Table>(line).expect("a TOML line"));
        }
    }
    (set, unset)
}

#[test]
fn the_packaged_config_file_gives_every_key_with_its_default() {
    let conffile = Path::new(env!("CARGO_MANIFEST_DIR")).join("../host/debian/lluavd.toml");
    let text = std::fs::read_to_string(&conffile).expect("host/debian/lluavd.toml");
    let dir = tempfile::tempdir().expect("temp dir");
    let empty = write(dir.path(), "empty.toml", "");
    let out = check_config(&["--config", empty.to_str().expect("utf-8")]);
    assert_eq!(out.status.code(), Some(0));
    let (defaults, no_default) = printout(&String::from_utf8_lossy(&out.stdout));

    // Settings are `key = value` (set) or `#key = value` (the default,
    // or an example for a key without one); prose is `# ...`.
    let mut given = BTreeMap::new();
    for line in text
        .lines()
        .filter(|l| !l.starts_with("# ") && *l != "#" && !l.is_empty())
    {
        let commented = line.starts_with('#');
        let table: toml::Table = toml::from_str(line.trim_start_matches('#')).expect("a setting line");
        for (key, value) in table {
            assert!(
                given.insert(key.clone(), (commented, value)).is_none(),
                "{key} appears twice"
            );
        }
    }
    let mut missing: Vec<&String> = defaults
        .keys()
        .chain(&no_default)
        .filter(|k| !given.contains_key(*k))
        .collect();
    missing.sort();
    assert!(
        missing.is_empty(),
        "host/debian/lluavd.toml lacks the keys {missing:?}: add each, commented, with its default"
    );
    for (key, (commented, value)) in &given {
        if key == "data_dir" {
            assert!(!commented && value.as_str() == Some("/var/lib/lluav"));
            continue;
        }
        assert!(commented, "{key} is set: only data_dir is");
        match defaults.get(key) {
            Some(default) => assert_eq!(value, default, "{key}: the file's value is not the default"),
            None => assert!(no_default.contains(key), "{key} is not a config key"),
        }
    }

    // The file as shipped passes the check and sets the data directory.
    let shipped = check_config(&["--config", conffile.to_str().expect("utf-8")]);
    assert_eq!(shipped.status.code(), Some(0));
    let (settings, _) = printout(&String::from_utf8_lossy(&shipped.stdout));
    assert_eq!(settings["data_dir"].as_str(), Some("/var/lib/lluav"));
}
