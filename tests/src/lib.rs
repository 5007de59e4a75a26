//! Cross-crate integration tests: they drive the real servers over real
//! sockets.
//!
//! This library is the harness: [`Lluavd`] builds and starts the real
//! `lluavd` binary on port 0, reads its `listening on` line and stops it
//! with a real signal; [`Conn`] is a plain tokio-tungstenite client that can
//! also send what a well-behaved client never would (binary, broken UTF-8,
//! fragments). Every wait is bounded by [`WAIT`], generous on purpose: a
//! slow machine makes a test slower, never flaky.

use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use futures_util::{SinkExt, StreamExt};
use serde_json::Value;
use tokio::net::TcpStream;
use tokio_tungstenite::tungstenite::Message;
use tokio_tungstenite::tungstenite::protocol::frame::Frame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::{Data, OpCode};
use tokio_tungstenite::{MaybeTlsStream, WebSocketStream};

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
}

/// A running `lluavd`, killed on drop if still running.
pub struct Lluavd {
    child: Child,
    /// Where it listens.
    pub addr: SocketAddr,
    /// `ws://addr`.
    pub url: String,
    /// Its data directory.
    pub data_dir: PathBuf,
    stderr: Arc<Mutex<String>>,
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
        let mut cmd = Command::new(lluavd_bin());
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
        cmd.args(&options.args)
            .env_remove("LLUAV_PASSWORD")
            .env("RUST_LOG", "info")
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        let mut child = cmd.spawn().expect("lluavd spawns");
        let stderr = Arc::new(Mutex::new(String::new()));
        let mut err_pipe = child.stderr.take().expect("stderr is piped");
        let sink = Arc::clone(&stderr);
        std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n @ 1..) = err_pipe.read(&mut buf) {
                let text = String::from_utf8_lossy(buf.get(..n).unwrap_or_default()).into_owned();
                sink.lock().unwrap_or_else(|p| p.into_inner()).push_str(&text);
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
        let addr = line
            .as_deref()
            .and_then(|l| l.strip_prefix("listening on ws://"))
            .and_then(|a| a.parse::<SocketAddr>().ok());
        match addr {
            Some(addr) => Ok(Lluavd {
                child,
                addr,
                url: format!("ws://{addr}"),
                data_dir: data_dir.to_owned(),
                stderr,
                more_stdout,
            }),
            None => {
                let status = wait_timeout(&mut child, WAIT);
                if status.is_none() {
                    let _ = child.kill();
                    let _ = child.wait();
                }
                let text = stderr.lock().unwrap_or_else(|p| p.into_inner()).clone();
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
        self.stderr.lock().unwrap_or_else(|p| p.into_inner()).clone()
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

fn wait_timeout(child: &mut Child, limit: Duration) -> Option<ExitStatus> {
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

/// One raw WebSocket connection.
pub struct Conn {
    ws: WebSocketStream<MaybeTlsStream<TcpStream>>,
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
    /// Connects to `url`.
    pub async fn connect(url: &str) -> Conn {
        let (ws, _) = tokio::time::timeout(WAIT, tokio_tungstenite::connect_async(url))
            .await
            .expect("connect in time")
            .expect("WebSocket handshake");
        Conn { ws }
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
