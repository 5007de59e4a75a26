//! lluavd's backend (the companion computer and the simulator) behind
//! lluav-core's real server, driven with text frames and simulated time,
//! for the `sim_*` tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::time::Duration;

use lluav_core::{Auth, Message, Outcome, Server, Session};
use lluav_host::companion::CompanionConfig;
use lluav_host::daemon;
use lluav_host::onboard::Onboard;
use lluav_host::recent_log::RecentLog;
use lluav_host::sim::Simulator;
use serde_json::Value;

/// Wall-clock step used when driving time forward.
pub const STEP: Duration = Duration::from_millis(100);

/// The request time every frame gets (2024-04-27T16:00:00Z).
pub const NOW_MS: i64 = 1_714_233_600_000;

pub struct Harness {
    pub server: Server<Onboard<Simulator>, fn() -> i64>,
    pub session: Session,
    pub log: RecentLog,
    pub dir: PathBuf,
    // Holds the temp directory for the harness's lifetime.
    _tmp: Option<tempfile::TempDir>,
    out: Vec<u8>,
}

fn clock() -> i64 {
    NOW_MS
}

impl Harness {
    /// A simulator at `speed` in a fresh data directory, no password.
    pub fn new(speed: f64) -> Harness {
        let tmp = tempfile::tempdir().expect("temp dir");
        let dir = tmp.path().join("data");
        let mut h = Harness::open(&dir, speed, None);
        h._tmp = Some(tmp);
        h
    }

    /// A simulator over an existing data directory; `password` is the
    /// configured one (pinned: `passwd` must refuse), else the stored one
    /// is in force.
    pub fn open(dir: &Path, speed: f64, password: Option<&str>) -> Harness {
        let log = RecentLog::new(256);
        let companion = CompanionConfig {
            data_dir: dir.to_path_buf(),
            log: log.clone(),
            password_pinned: password.is_some(),
            uplink: None,
        };
        let onboard = daemon::simulated(companion, speed).expect("backend opens");
        let password = password.map(str::to_owned).or_else(|| onboard.stored_password());
        let auth = Auth::new(password.as_deref()).expect("auth");
        let mut server = Server::new(onboard, clock as fn() -> i64, auth);
        let session = server.open(None);
        Harness {
            server,
            session,
            log,
            dir: dir.to_path_buf(),
            _tmp: None,
            out: vec![0u8; 64 * 1024],
        }
    }

    /// Sends one frame and parses the reply, checking `cmd` and `ts`.
    pub fn send(&mut self, frame: &str) -> Value {
        let reply =
            match self
                .server
                .handle(&mut self.session, Message::Text(frame.as_bytes()), &mut self.out)
            {
                Outcome::Reply(r) => r.to_owned(),
                other => panic!("{frame:?}: expected a reply, got {other:?}"),
            };
        let v: Value =
            serde_json::from_str(&reply).unwrap_or_else(|e| panic!("{frame:?}: not JSON ({e}): {reply}"));
        assert!(
            v["ret"].is_i64() && v["cmd"].is_u64() && v["ts"].is_i64(),
            "{frame:?}: {reply}"
        );
        v
    }

    /// Sends a frame that must succeed; returns the reply.
    pub fn ok(&mut self, frame: &str) -> Value {
        let v = self.send(frame);
        assert_eq!(v["ret"], 0, "{frame:?} failed: {v}");
        v
    }

    /// Sends a frame that must fail with `ret`; returns the message.
    pub fn fails(&mut self, frame: &str, ret: i64) -> String {
        let v = self.send(frame);
        assert_eq!(v["ret"], ret, "{frame:?}: {v}");
        v["msg"].as_str().expect("msg").to_owned()
    }

    /// The `state` object.
    pub fn state(&mut self) -> Value {
        self.ok("state")["state"].clone()
    }

    pub fn fsm(&mut self) -> String {
        self.state()["fsm"].as_str().expect("fsm").to_owned()
    }

    /// Advances wall time by `secs` in [`STEP`]s.
    pub fn run_for(&mut self, secs: f64) {
        let steps = (secs / STEP.as_secs_f64()).round() as u64;
        for _ in 0..steps {
            self.server.backend_mut().tick(STEP);
        }
    }

    /// Advances wall time in [`STEP`]s until `fsm` is `want`, for at most
    /// `limit` seconds; returns the wall time it took.
    pub fn run_until_fsm(&mut self, want: &str, limit: f64) -> f64 {
        let mut t = 0.0;
        while self.fsm() != want {
            assert!(
                t <= limit,
                "fsm still {} after {t:.1} s, wanted {want}",
                self.fsm()
            );
            self.server.backend_mut().tick(STEP);
            t += STEP.as_secs_f64();
        }
        t
    }

    /// Persists what is pending, as the daemon does at shutdown.
    pub fn flush(&mut self) {
        self.server.backend_mut().flush().expect("flushed");
    }

    /// The password `passwd` saved, if any.
    pub fn stored_password(&self) -> Option<String> {
        self.server.backend().stored_password()
    }

    /// Takes off and waits until hovering.
    pub fn airborne(&mut self) {
        self.ok("takeoff");
        // takeoff_alt may be up to 120 m at 1 m/s.
        self.run_until_fsm("hover", 200.0);
    }
}
