//! The server the adapter-neutral tests (`tests/mcu.rs`) run against:
//! `lluavd` at the MCU's limits by default, or the firmware on the
//! emulated board when `LLUAV_TEST_BOARD` names the command that starts
//! one (`bash embedded/scripts/qemu-board.sh --port 0 --elf ELF`, run from
//! the repository's root). Every test starts its own, as with lluavd: a
//! board boots in well under a second, and no test sees another's lockouts,
//! lock mode or password.
//!
//! The board's password is the one it was built with:
//! `LLUAV_TEST_BOARD_PASSWORD`, by default qemu-board.sh's `qemu-secret`;
//! lluavd is given the same.

use std::io::{BufRead, BufReader, Read};
use std::net::SocketAddr;
use std::os::unix::process::CommandExt;
use std::path::Path;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::mpsc;
use std::sync::{Arc, Mutex};

use crate::{Lluavd, Options, WAIT, wait_timeout};

/// The message limit the MCU adapter has (DESIGN.md: 4 KiB on MCU); lluavd
/// is started with it.
pub const MCU_FRAME_LIMIT: usize = 4096;

/// The password of qemu-board.sh's build unless LLUAV_PASSWORD says otherwise.
const BOARD_PASSWORD: &str = "qemu-secret";

/// A running server for the adapter-neutral tests.
pub struct Target {
    /// `ws://addr`.
    pub url: String,
    /// Where it listens.
    pub addr: SocketAddr,
    /// The password that logs a user in.
    pub password: String,
    server: Server,
}

enum Server {
    Lluavd(Lluavd, tempfile::TempDir),
    Board(Board),
}

impl Target {
    /// Starts the board `LLUAV_TEST_BOARD` names, or else `lluavd
    /// --max-message 4096` with the board's password.
    pub fn start() -> Target {
        let password =
            std::env::var("LLUAV_TEST_BOARD_PASSWORD").unwrap_or_else(|_| BOARD_PASSWORD.to_owned());
        match std::env::var("LLUAV_TEST_BOARD") {
            Ok(command) => {
                let board = Board::start(&command);
                Target {
                    url: board.url.clone(),
                    addr: board.addr,
                    password,
                    server: Server::Board(board),
                }
            }
            Err(_) => {
                let dir = tempfile::tempdir().expect("temp dir");
                let limit = MCU_FRAME_LIMIT.to_string();
                let options = Options::password(&password).with_args(&["--max-message", &limit]);
                let daemon = Lluavd::start(dir.path(), &options);
                Target {
                    url: daemon.url.clone(),
                    addr: daemon.addr,
                    password,
                    server: Server::Lluavd(daemon, dir),
                }
            }
        }
    }

    /// Whether this is the emulated board.
    pub fn is_board(&self) -> bool {
        matches!(self.server, Server::Board(_))
    }

    /// Stops the server: `Some(report)` for a board (its exit status and
    /// everything it wrote to stderr: its log, and qemu-board.sh's `board:`
    /// lines with the stack's high-water mark).
    pub fn stop(self) -> Option<(ExitStatus, String)> {
        match self.server {
            Server::Lluavd(daemon, _dir) => {
                daemon.terminate();
                None
            }
            Server::Board(board) => Some(board.stop()),
        }
    }
}

/// A board started by a command that prints `listening on ws://ADDR` on
/// stdout once it answers and runs until SIGTERM.
pub struct Board {
    child: Child,
    /// `ws://addr`.
    pub url: String,
    /// Where it listens.
    pub addr: SocketAddr,
    stderr: Arc<Mutex<String>>,
    stderr_reader: Option<std::thread::JoinHandle<()>>,
}

impl Board {
    /// Runs `command` with `sh` from the repository's root and waits for
    /// its listening line.
    pub fn start(command: &str) -> Board {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        // A process group of its own: if the board does not stop on
        // SIGTERM, the whole group (QEMU too) is killed, none left behind.
        let mut child = Command::new("sh")
            .arg("-c")
            .arg(format!("exec {command}"))
            .process_group(0)
            .current_dir(root)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .expect("the board's command spawns");
        let stderr = Arc::new(Mutex::new(String::new()));
        let mut err_pipe = child.stderr.take().expect("stderr is piped");
        let sink = Arc::clone(&stderr);
        let stderr_reader = std::thread::spawn(move || {
            let mut buf = [0u8; 4096];
            while let Ok(n @ 1..) = err_pipe.read(&mut buf) {
                let text = String::from_utf8_lossy(buf.get(..n).unwrap_or_default()).into_owned();
                sink.lock().unwrap_or_else(|p| p.into_inner()).push_str(&text);
            }
        });
        let stdout = child.stdout.take().expect("stdout is piped");
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            let mut lines = BufReader::new(stdout).lines();
            let _ = tx.send(lines.next().and_then(Result::ok));
            // Nothing else is expected; keep the pipe drained.
            for _ in lines {}
        });
        // A cold board may be built first: the build's time counts too.
        let line = rx.recv_timeout(WAIT * 10).ok().flatten();
        let url = line.as_deref().and_then(|l| l.strip_prefix("listening on "));
        let addr = url
            .and_then(|u| u.strip_prefix("ws://"))
            .and_then(|a| a.parse::<SocketAddr>().ok());
        match (url, addr) {
            (Some(url), Some(addr)) => Board {
                child,
                url: url.to_owned(),
                addr,
                stderr,
                stderr_reader: Some(stderr_reader),
            },
            _ => {
                let mut board = Board {
                    child,
                    url: String::new(),
                    addr: SocketAddr::from(([127, 0, 0, 1], 0)),
                    stderr,
                    stderr_reader: None,
                };
                board.terminate();
                panic!("the board did not start (stdout {line:?}):\n{}", board.stderr());
            }
        }
    }

    /// What the board wrote to stderr so far.
    pub fn stderr(&self) -> String {
        self.stderr.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Sends SIGTERM and waits for the exit status; returns it and
    /// everything the board wrote to stderr.
    pub fn stop(mut self) -> (ExitStatus, String) {
        let Some(status) = self.terminate() else {
            panic!("the board did not stop within {WAIT:?}:\n{}", self.stderr());
        };
        // The script waits for its children, so stderr is closed by now.
        if let Some(reader) = self.stderr_reader.take() {
            let _ = reader.join();
        }
        (status, self.stderr())
    }

    /// SIGTERM to the script first (it stops QEMU after reading its
    /// stack), then the exit status; `None` if it did not exit in time,
    /// and then its whole process group is killed.
    fn terminate(&mut self) -> Option<ExitStatus> {
        if let Ok(Some(status)) = self.child.try_wait() {
            return Some(status);
        }
        let pid = self.child.id().to_string();
        let _ = Command::new("kill").args(["-TERM", &pid]).status();
        let status = wait_timeout(&mut self.child, WAIT);
        if status.is_none() {
            let _ = Command::new("kill")
                .args(["-KILL", "--", &format!("-{pid}")])
                .status();
            let _ = self.child.wait();
        }
        status
    }
}

impl Drop for Board {
    /// Stops the board and says how deep its stack went in this test (on
    /// stderr, which the test harness shows with `--nocapture`).
    fn drop(&mut self) {
        self.terminate();
        if let Some(reader) = self.stderr_reader.take() {
            let _ = reader.join();
            let test = std::thread::current().name().unwrap_or("a test").to_owned();
            let stderr = self.stderr();
            if let Some(line) = stderr.lines().find(|l| l.starts_with("board: stack high-water")) {
                eprintln!("{test}: {line}");
            }
        }
    }
}
