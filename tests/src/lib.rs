//! Cross-crate integration tests: they drive the real servers over real
//! sockets.
//!
//! This library is the harness: [`Lluavd`] builds and starts the real
//! `lluavd` binary on port 0, reads its `listening on` line and stops it
//! with a real signal; [`Conn`] is a plain tokio-tungstenite client that can
//! also send what a well-behaved client never would (binary, broken UTF-8,
//! fragments). Every wait is bounded by [`WAIT`], generous on purpose: a
//! slow machine makes a test slower, never flaky.
//!
//! A daemon started with [`Options::tls`] serves `wss://` with a
//! certificate for `localhost` and `127.0.0.1` issued by this process's
//! own test CA ([`test_ca`], made with rcgen); [`Conn`] trusts that CA.
//! [`over_ws_and_wss!`] runs a set of tests both ways.
//!
//! [`target::Target`] is the server of the tests every adapter must pass
//! (`tests/mcu.rs`): lluavd at the MCU's limits, or the firmware on the
//! emulated board when `LLUAV_TEST_BOARD` says how to start one.
//!
//! For the uplink: [`broker`] starts real Mosquittos and speaks MQTT 5 to
//! them; [`flooder`] is a stand-in broker that floods and never reads.

pub mod broker;
pub mod flooder;
pub mod target;

use std::io::{BufRead, BufReader, Read};
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Condvar, Mutex, OnceLock};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use lluav_host::client::{ConnectOptions, Transport};
use serde_json::Value;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::Frame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::{Data, OpCode};

/// Upper bound for any single wait in these tests.
pub const WAIT: Duration = Duration::from_secs(60);

/// The `lluavd` binary, built once per test process with the same profile
/// as the tests (`LLUAVD` overrides it with a ready-made binary).
pub fn lluavd_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| std::env::var_os("LLUAVD").map_or_else(|| build_host_bin("lluavd"), PathBuf::from))
}

/// The `lluav` client binary, built like [`lluavd_bin`] (`LLUAV` overrides).
pub fn lluav_bin() -> &'static Path {
    static BIN: OnceLock<PathBuf> = OnceLock::new();
    BIN.get_or_init(|| std::env::var_os("LLUAV").map_or_else(|| build_host_bin("lluav"), PathBuf::from))
}

/// Builds one of lluav-host's binaries with cargo (a test cannot name
/// another package's binary through `CARGO_BIN_EXE_*`) and returns the path
/// cargo reports.
fn build_host_bin(name: &str) -> PathBuf {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR")).join("../Cargo.toml");
    let mut build = Command::new(cargo);
    build
        .args([
            "build",
            "--quiet",
            "-p",
            "lluav-host",
            "--bin",
            name,
            "--message-format=json",
        ])
        .arg("--manifest-path")
        .arg(&manifest)
        .stderr(Stdio::inherit());
    if !cfg!(debug_assertions) {
        build.arg("--release");
    }
    let output = build.output().expect("cargo runs");
    assert!(output.status.success(), "cargo build of {name} failed");
    String::from_utf8_lossy(&output.stdout)
        .lines()
        .filter_map(|line| serde_json::from_str::<Value>(line).ok())
        .filter(|m| m["reason"] == "compiler-artifact" && m["target"]["name"] == name)
        .find_map(|m| m["executable"].as_str().map(PathBuf::from))
        .unwrap_or_else(|| panic!("cargo reported no executable for {name}"))
}

/// How to start a daemon.
#[derive(Clone, Debug, Default)]
pub struct Options {
    /// `--password`.
    pub password: Option<String>,
    /// `--sim-speed`.
    pub sim_speed: Option<f64>,
    /// Serve `wss://` with a certificate from [`test_ca`].
    pub tls: bool,
    /// Another `lluavd` binary than [`lluavd_bin`] (a baseline build).
    pub binary: Option<PathBuf>,
    /// Any further arguments.
    pub args: Vec<String>,
}

impl Options {
    /// A daemon with this password.
    pub fn password(p: &str) -> Self {
        Options {
            password: Some(p.to_owned()),
            ..Options::default()
        }
    }

    /// These options plus further arguments.
    pub fn with_args(mut self, args: &[&str]) -> Self {
        self.args.extend(args.iter().map(|a| (*a).to_owned()));
        self
    }

    /// Allows `n` sessions and `n` pending handshakes from one address (the
    /// defaults are a handful) and in all, for tests that open many
    /// sessions at once from 127.0.0.1.
    pub fn per_ip(self, n: usize) -> Self {
        let n = n.to_string();
        self.with_args(&[
            "--max-sessions-per-ip",
            &n,
            "--max-handshakes-per-ip",
            &n,
            "--max-handshakes",
            &n,
        ])
    }
}

/// What a daemon wrote to stderr, and a signal for every piece more.
#[derive(Default)]
struct Log {
    text: Mutex<String>,
    grew: Condvar,
}

impl Log {
    fn text(&self) -> std::sync::MutexGuard<'_, String> {
        self.text.lock().unwrap_or_else(|p| p.into_inner())
    }
}

/// A running `lluavd`, killed on drop if still running.
pub struct Lluavd {
    child: Child,
    /// Where it listens.
    pub addr: SocketAddr,
    /// `ws://addr`, or `wss://addr` with TLS.
    pub url: String,
    /// Its data directory.
    pub data_dir: PathBuf,
    stderr: Arc<Log>,
    more_stdout: Arc<Mutex<Vec<String>>>,
}

impl Lluavd {
    /// Starts `lluavd --bind 127.0.0.1:0 --data-dir DIR ...` and waits for
    /// its `listening on` line.
    pub fn start(data_dir: &Path, options: &Options) -> Lluavd {
        match Lluavd::try_start(data_dir, options, &[]) {
            Ok(d) => d,
            Err((status, stderr)) => panic!("lluavd did not start ({status:?}):\n{stderr}"),
        }
    }

    /// Starts a daemon with extra arguments placed first (which may replace
    /// `--bind`); on failure returns its exit status and stderr.
    pub fn try_start(
        data_dir: &Path,
        options: &Options,
        first: &[&str],
    ) -> Result<Lluavd, (Option<ExitStatus>, String)> {
        let mut cmd = Command::new(options.binary.as_deref().unwrap_or_else(|| lluavd_bin()));
        cmd.args(first);
        if !first.contains(&"--bind") {
            cmd.args(["--bind", "127.0.0.1:0"]);
        }
        cmd.arg("--data-dir").arg(data_dir);
        if let Some(p) = &options.password {
            cmd.args(["--password", p]);
        }
        if let Some(s) = options.sim_speed {
            cmd.args(["--sim-speed", &s.to_string()]);
        }
        if options.tls {
            let (cert, key) = test_ca().issue(data_dir);
            cmd.arg("--tls-cert").arg(cert).arg("--tls-key").arg(key);
        }
        cmd.args(&options.args)
            .env_remove("LLUAV_PASSWORD")
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().expect("lluavd spawns");
        let stderr = Arc::new(Log::default());
        let mut err_pipe = child.stderr.take().expect("stderr is piped");
        let sink = Arc::clone(&stderr);
        let stderr_reader = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n @ 1..) = err_pipe.read(&mut buf) {
                let text = String::from_utf8_lossy(buf.get(..n).unwrap_or_default()).into_owned();
                sink.text().push_str(&text);
                sink.grew.notify_all();
            }
        });
        let stdout = child.stdout.take().expect("stdout is piped");
        let (tx, rx) = mpsc::channel();
        let more_stdout = Arc::new(Mutex::new(Vec::new()));
        let more = Arc::clone(&more_stdout);
        std::thread::spawn(move || {
            let mut lines = BufReader::new(stdout).lines();
            let first = lines.next().and_then(Result::ok);
            let _ = tx.send(first);
            for line in lines.map_while(Result::ok) {
                more.lock().unwrap_or_else(|p| p.into_inner()).push(line);
            }
        });
        let line = rx.recv_timeout(WAIT).ok().flatten();
        let url = line.as_deref().and_then(|l| l.strip_prefix("listening on "));
        let addr = url
            .and_then(|u| u.strip_prefix("ws://").or_else(|| u.strip_prefix("wss://")))
            .and_then(|a| a.parse::<SocketAddr>().ok());
        match (url, addr) {
            (Some(url), Some(addr)) => Ok(Lluavd {
                child,
                addr,
                url: url.to_owned(),
                data_dir: data_dir.to_owned(),
                stderr,
                more_stdout,
            }),
            _ => {
                let status = wait_timeout(&mut child, WAIT);
                if status.is_none() {
                    let _ = child.kill();
                    let _ = child.wait();
                }
                // The process is gone: its stderr ends, and the reader with it.
                if status.is_some() {
                    let _ = stderr_reader.join();
                }
                let text = stderr.text().clone();
                Err((status, format!("stdout: {line:?}\nstderr:\n{text}")))
            }
        }
    }

    /// The daemon's process id (for `/proc/PID/status` readings).
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// What the daemon wrote to stderr so far.
    pub fn stderr(&self) -> String {
        self.stderr.text().clone()
    }

    /// Waits (within [`WAIT`]) until the daemon's stderr holds a line with
    /// every one of `parts`; returns that line.
    pub fn log_until(&self, parts: &[&str]) -> String {
        let deadline = Instant::now() + WAIT;
        let mut text = self.stderr.text();
        loop {
            let found = text.lines().find(|l| parts.iter().all(|p| l.contains(p)));
            if let Some(line) = found {
                return line.to_owned();
            }
            let left = deadline.saturating_duration_since(Instant::now());
            assert!(!left.is_zero(), "lluavd never logged {parts:?}:\n{}", *text);
            text = self
                .stderr
                .grew
                .wait_timeout(text, left)
                .unwrap_or_else(|p| p.into_inner())
                .0;
        }
    }

    /// Lines printed to stdout after the `listening on` line (the contract
    /// is that there are none).
    pub fn more_stdout(&self) -> Vec<String> {
        self.more_stdout.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Sends a signal (`TERM`, `INT`, ...) with the system's `kill`.
    pub fn signal(&self, name: &str) {
        let status = Command::new("kill")
            .arg(format!("-{name}"))
            .arg(self.child.id().to_string())
            .status()
            .expect("kill runs");
        assert!(status.success(), "kill -{name} failed");
    }

    /// Sends SIGTERM and waits for the exit status.
    pub fn terminate(self) -> ExitStatus {
        self.signal("TERM");
        self.wait()
    }

    /// Waits for the daemon to exit (after a signal).
    pub fn wait(mut self) -> ExitStatus {
        match wait_timeout(&mut self.child, WAIT) {
            Some(status) => status,
            None => panic!("lluavd did not exit within {WAIT:?}:\n{}", self.stderr()),
        }
    }
}

impl Drop for Lluavd {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}

pub(crate) fn wait_timeout(child: &mut Child, limit: Duration) -> Option<ExitStatus> {
    let start = Instant::now();
    while start.elapsed() < limit {
        match child.try_wait() {
            Ok(Some(status)) => return Some(status),
            Ok(None) => std::thread::sleep(Duration::from_millis(20)),
            Err(_) => return None,
        }
    }
    None
}

/// A certificate authority made for this test process.
pub struct TestCa {
    dir: tempfile::TempDir,
    cert: rcgen::Certificate,
    key: rcgen::KeyPair,
}

/// This process's test CA (made on first use).
pub fn test_ca() -> &'static TestCa {
    static CA: OnceLock<TestCa> = OnceLock::new();
    CA.get_or_init(|| {
        let mut params = rcgen::CertificateParams::new(Vec::<String>::new()).expect("CA parameters");
        params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        params.key_usages = vec![rcgen::KeyUsagePurpose::KeyCertSign];
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, "lluav test CA");
        let key = rcgen::KeyPair::generate().expect("CA key");
        let cert = params.self_signed(&key).expect("CA certificate");
        let dir = tempfile::tempdir().expect("temp dir");
        std::fs::write(dir.path().join("ca.pem"), cert.pem()).expect("CA written");
        TestCa { dir, cert, key }
    })
}

impl TestCa {
    /// The CA's certificate (PEM), what `--cafile` takes.
    pub fn ca_file(&self) -> PathBuf {
        self.dir.path().join("ca.pem")
    }

    /// A server certificate for `localhost` and `127.0.0.1`, written to
    /// `dir` as `server.pem` and `server.key`; returns their paths.
    pub fn issue(&self, dir: &Path) -> (PathBuf, PathBuf) {
        self.issue_with(dir, &["localhost", "127.0.0.1"], |_| {})
    }

    /// A server certificate for `names`, with `customise` applied to its
    /// parameters (validity, CA flag), written like [`TestCa::issue`].
    pub fn issue_with(
        &self,
        dir: &Path,
        names: &[&str],
        customise: impl FnOnce(&mut rcgen::CertificateParams),
    ) -> (PathBuf, PathBuf) {
        let names = names.iter().map(|n| (*n).to_owned()).collect::<Vec<_>>();
        let mut params = rcgen::CertificateParams::new(names).expect("server parameters");
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, "lluavd test server");
        params.extended_key_usages = vec![rcgen::ExtendedKeyUsagePurpose::ServerAuth];
        customise(&mut params);
        let key = rcgen::KeyPair::generate().expect("server key");
        let cert = params
            .signed_by(&key, &self.cert, &self.key)
            .expect("server certificate");
        std::fs::create_dir_all(dir).expect("data dir");
        let (cert_path, key_path) = (dir.join("server.pem"), dir.join("server.key"));
        std::fs::write(&cert_path, cert.pem()).expect("certificate written");
        std::fs::write(&key_path, key.serialize_pem()).expect("key written");
        (cert_path, key_path)
    }

    /// Client options trusting this CA.
    pub fn options(&self) -> ConnectOptions {
        ConnectOptions {
            ca_file: Some(self.ca_file()),
        }
    }
}

/// `ws://` or `wss://`, for tests that run both ways.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scheme {
    /// Plain WebSocket.
    Ws,
    /// WebSocket over TLS.
    Wss,
}

impl Scheme {
    /// Options for a daemon with this password over this scheme.
    pub fn options(self, password: &str) -> Options {
        Options {
            tls: self == Scheme::Wss,
            ..Options::password(password)
        }
    }
}

/// Runs each named `async fn name(scheme: Scheme)` of the calling test
/// file twice: as `over_ws::name` and as `over_wss::name`.
#[macro_export]
macro_rules! over_ws_and_wss {
    ($($name:ident),* $(,)?) => {
        mod over_ws {
            $(
                #[tokio::test]
                async fn $name() {
                    super::$name($crate::Scheme::Ws).await;
                }
            )*
        }
        mod over_wss {
            $(
                #[tokio::test]
                async fn $name() {
                    super::$name($crate::Scheme::Wss).await;
                }
            )*
        }
    };
}

/// A TCP connection to `addr` from the loopback address `source` (any of
/// 127.0.0.0/8), so one test can play many client addresses.
pub async fn tcp_from(source: IpAddr, addr: SocketAddr) -> std::io::Result<TcpStream> {
    let socket = TcpSocket::new_v4()?;
    socket.bind(SocketAddr::new(source, 0))?;
    socket.connect(addr).await
}

/// A WebSocket upgrade request for `addr` with extra header lines (each
/// ending in `\r\n`).
pub fn upgrade_request(addr: SocketAddr, extra: &str) -> String {
    format!(
        "GET / HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n{extra}\r\n"
    )
}

/// Sends `request` over plain TCP and returns the HTTP status code of the
/// answer (0 if the connection ended without one) and the whole answer.
pub async fn http_status(addr: SocketAddr, request: &str) -> (u16, String) {
    let mut tcp = TcpStream::connect(addr).await.expect("TCP connect");
    tcp.write_all(request.as_bytes()).await.expect("request written");
    let mut answer = Vec::new();
    let read = async {
        let mut buf = [0u8; 4096];
        // Up to the end of the head: an upgrade stays open after its 101.
        while !answer.windows(4).any(|w| w == b"\r\n\r\n") {
            match tcp.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => answer.extend_from_slice(buf.get(..n).unwrap_or_default()),
            }
        }
    };
    tokio::time::timeout(WAIT, read).await.expect("an answer in time");
    let text = String::from_utf8_lossy(&answer).into_owned();
    let code = text
        .strip_prefix("HTTP/1.1 ")
        .and_then(|rest| rest.get(..3))
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    (code, text)
}

/// One raw WebSocket connection.
pub struct Conn {
    ws: WebSocketStream<Transport>,
}

/// What came back instead of a text message.
#[derive(Debug, PartialEq)]
pub enum Received {
    /// A text message.
    Text(String),
    /// A pong with this payload.
    Pong(Vec<u8>),
    /// A close frame with this code (None: no code).
    Close(Option<u16>),
    /// The stream ended without a close frame.
    Ended,
}

impl Conn {
    /// Connects to `url` (`wss://` trusts [`test_ca`]).
    pub async fn connect(url: &str) -> Conn {
        match Conn::try_connect(url).await {
            Ok(c) => c,
            Err(e) => panic!("cannot connect to {url}: {e}"),
        }
    }

    /// Connects to `url`, or says why not.
    pub async fn try_connect(url: &str) -> Result<Conn, lluav_host::client::ClientError> {
        let options = if url.starts_with("wss://") {
            test_ca().options()
        } else {
            ConnectOptions::default()
        };
        let ws = tokio::time::timeout(WAIT, lluav_host::client::open(url, &options))
            .await
            .expect("connect in time")?;
        Ok(Conn { ws })
    }

    /// Connects to the `ws://` daemon at `addr` from the loopback address
    /// `source`, or says why not.
    pub async fn connect_from(source: IpAddr, addr: SocketAddr) -> Result<Conn, String> {
        let tcp = tcp_from(source, addr).await.map_err(|e| e.to_string())?;
        let (ws, _) = tokio_tungstenite::client_async(format!("ws://{addr}"), Transport::Plain(tcp))
            .await
            .map_err(|e| e.to_string())?;
        Ok(Conn { ws })
    }

    /// Connects and logs in with `password`, asserting success.
    pub async fn login(url: &str, password: &str) -> Conn {
        let mut c = Conn::connect(url).await;
        let r = c.request(&format!("login {password}")).await;
        assert_eq!(r["ret"], 0, "login {password}: {r}");
        c
    }

    /// Sends a text message.
    pub async fn send(&mut self, text: &str) {
        self.ws.send(Message::text(text)).await.expect("send");
    }

    /// Sends a text message; false if the connection is gone.
    pub async fn try_send(&mut self, text: &str) -> bool {
        self.ws.send(Message::text(text)).await.is_ok()
    }

    /// Sends a raw message (binary, ping, a hand-made frame).
    pub async fn send_raw(&mut self, message: Message) {
        self.ws.send(message).await.expect("send");
    }

    /// Sends one text frame, final or not, with arbitrary bytes.
    pub async fn send_text_frame(&mut self, bytes: &[u8], opcode: Data, fin: bool) {
        let frame = Frame::message(bytes.to_vec(), OpCode::Data(opcode), fin);
        self.ws.send(Message::Frame(frame)).await.expect("send frame");
    }

    /// The next message that is not a ping.
    pub async fn recv(&mut self) -> Received {
        loop {
            let next = tokio::time::timeout(WAIT, self.ws.next())
                .await
                .expect("an answer in time");
            return match next {
                Some(Ok(Message::Text(t))) => Received::Text(t.as_str().to_owned()),
                Some(Ok(Message::Pong(p))) => Received::Pong(p.to_vec()),
                Some(Ok(Message::Close(f))) => Received::Close(f.map(|f| u16::from(f.code))),
                Some(Ok(Message::Ping(_) | Message::Frame(_))) => continue,
                Some(Ok(Message::Binary(b))) => panic!("the server sent a binary message: {b:?}"),
                Some(Err(_)) | None => Received::Ended,
            };
        }
    }

    /// The next response, parsed and checked for `ret`, `cmd` and `ts`.
    pub async fn response(&mut self) -> Value {
        match self.recv().await {
            Received::Text(text) => parse_response(&text),
            other => panic!("expected a response, got {other:?}"),
        }
    }

    /// Sends `text` and returns its response.
    pub async fn request(&mut self, text: &str) -> Value {
        self.send(text).await;
        self.response().await
    }

    /// Waits for the server's close frame, completes the close handshake
    /// and returns the code.
    pub async fn close_code(&mut self) -> Option<u16> {
        loop {
            match self.recv().await {
                Received::Close(code) => {
                    // Reading on sends tungstenite's queued close reply.
                    while let Ok(Some(Ok(_))) = tokio::time::timeout(WAIT, self.ws.next()).await {}
                    return code;
                }
                Received::Text(t) => panic!("expected a close, got a response: {t}"),
                Received::Pong(_) => continue,
                Received::Ended => panic!("the connection ended without a close frame"),
            }
        }
    }

    /// Closes cleanly.
    pub async fn close(mut self) {
        let _ = self.ws.close(None).await;
        while let Ok(Some(Ok(_))) = tokio::time::timeout(WAIT, self.ws.next()).await {}
    }
}

/// The resident memory (`VmRSS`) and its peak (`VmHWM`) of process `pid`,
/// in KiB (0 when unreadable).
pub fn memory_kib(pid: u32) -> (u64, u64) {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    let field = |name: &str| {
        status
            .lines()
            .find_map(|l| l.strip_prefix(name))
            .and_then(|v| v.trim().strip_suffix("kB"))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0)
    };
    (field("VmRSS:"), field("VmHWM:"))
}

/// Parses a response and checks the fields every response has.
pub fn parse_response(text: &str) -> Value {
    let v: Value = serde_json::from_str(text).unwrap_or_else(|e| panic!("not JSON ({e}): {text}"));
    assert!(v.is_object(), "not an object: {text}");
    for key in ["ret", "cmd", "ts"] {
        assert!(v[key].is_i64(), "`{key}` is not an integer: {text}");
    }
    v
}

/// Polls `state` until `done` holds for `state.state`, within [`WAIT`].
pub async fn wait_for_state(conn: &mut Conn, what: &str, done: impl Fn(&Value) -> bool) -> Value {
    let start = Instant::now();
    loop {
        let r = conn.request("state").await;
        assert_eq!(r["ret"], 0, "state: {r}");
        if done(&r["state"]) {
            return r;
        }
        assert!(start.elapsed() < WAIT, "state never became {what}; last: {r}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

/// A valid argument string for each grammar, so that every command reaches
/// the backend.
pub fn sample_args(grammar: lluav_core::Grammar) -> &'static str {
    use lluav_core::Grammar;
    match grammar {
        Grammar::None | Grammar::OptName => "",
        Grammar::Flag => "1",
        Grammar::OptCount => "5",
        Grammar::Pwm => "1500",
        Grammar::Amount => "12.5",
        Grammar::OptAmount => "0",
        Grammar::Angle => "-30",
        Grammar::Name => "sample",
        Grammar::Path => "sample/dir",
        Grammar::Text => "sample text",
        Grammar::TaskName => "sample task",
        Grammar::Secret => "1025",
        Grammar::NewPassword => "n3wpass",
        Grammar::ParamName => "takeoff_alt",
        Grammar::SetParam => "takeoff_alt:3.5",
        Grammar::Setpoint => "1.0:2.0:-3.0:0.5",
        Grammar::Point => "10.0:5.0:-2.0",
        Grammar::Pose => "1.0,2.0,-3.0,0.5",
        Grammar::Zyhk => "1.5,2.0,2.5",
        Grammar::Mission => r#"1001:{"waypoints":[{"x":1,"y":2,"z":-3},{"x":4,"y":5,"z":-3,"yaw":1.5}]}"#,
        Grammar::MwExec => "1001:1,2",
        Grammar::Ai1Mission => "task-1:missions/a.json",
        Grammar::Override => "failsafe",
    }
}

/// A `lluav` that keeps running (`lluav events`): its stdout and stderr
/// read line by line as they come.
pub struct Following {
    child: Child,
    stdout: mpsc::Receiver<String>,
    stderr: mpsc::Receiver<String>,
}

impl Following {
    /// Starts `lluav` with `args` (no password from the environment).
    pub fn start(args: &[&str]) -> Following {
        let mut child = Command::new(lluav_bin())
            .args(args)
            .env_remove("LLUAV_PASSWORD")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("lluav starts");
        let lines = |pipe: Box<dyn Read + Send>| {
            let (tx, rx) = mpsc::channel();
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines() {
                    let Ok(line) = line else { break };
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            });
            rx
        };
        let stdout = lines(Box::new(child.stdout.take().expect("stdout")));
        let stderr = lines(Box::new(child.stderr.take().expect("stderr")));
        Following {
            child,
            stdout,
            stderr,
        }
    }

    /// The next line of stdout, within [`WAIT`]; `None` once it closed.
    pub fn line(&self) -> Option<String> {
        match self.stdout.recv_timeout(WAIT) {
            Ok(line) => Some(line),
            Err(mpsc::RecvTimeoutError::Disconnected) => None,
            Err(e) => panic!("no line from lluav within {WAIT:?}: {e}"),
        }
    }

    /// Waits (within [`WAIT`]) for a line of stderr containing `what`;
    /// returns every stderr line read up to it.
    pub fn stderr_until(&self, what: &str) -> Vec<String> {
        let mut seen = Vec::new();
        loop {
            match self.stderr.recv_timeout(WAIT) {
                Ok(line) => {
                    let done = line.contains(what);
                    seen.push(line);
                    if done {
                        return seen;
                    }
                }
                Err(e) => panic!("lluav never said {what:?} ({e}); stderr: {seen:?}"),
            }
        }
    }

    /// Sends SIGINT (Ctrl-C) and waits, within [`WAIT`], for the exit.
    pub fn interrupt(self) -> ExitStatus {
        let status = Command::new("kill")
            .arg("-INT")
            .arg(self.child.id().to_string())
            .status()
            .expect("kill runs");
        assert!(status.success(), "kill -INT failed");
        self.wait()
    }

    /// Waits, within [`WAIT`], for the exit.
    pub fn wait(mut self) -> ExitStatus {
        let start = Instant::now();
        loop {
            if let Some(status) = self.child.try_wait().expect("lluav status") {
                return status;
            }
            if start.elapsed() > WAIT {
                let _ = self.child.kill();
                panic!("lluav did not exit within {WAIT:?}");
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Drop for Following {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
            let _ = self.child.wait();
        }
    }
}
