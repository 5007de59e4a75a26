//! A deterministic backend and helpers shared by the core's tests.
#![allow(dead_code)]

use lluav_core::{
    Args, Auth, Backend, Command, CommandId, Context, Failsafe, Failure, Fields, Grammar, Message, Outcome,
    Server, Session, Step,
};

/// Fixed clock value for every response.
pub const TS: i64 = 1_714_233_600_000;

/// A vehicle whose armed state the test sets, and which records what ran.
#[derive(Default)]
pub struct MockVehicle {
    pub armed: bool,
    pub executed: Vec<CommandId>,
    /// Make the next execute fail with this.
    pub fail_with: Option<Failure>,
    /// Make `state` write this many filler bytes.
    pub filler: usize,
    pub saved_password: Option<String>,
    /// The lock mode last persisted through `lock_mode_changed`.
    pub saved_lock_mode: Option<bool>,
    /// Make `lock_mode_changed` fail with this.
    pub lock_save_fails: Option<Failure>,
    /// The failsafe the vehicle reports.
    pub failsafe: Option<Failsafe>,
    /// Whether a mission runs.
    pub mission_running: bool,
    /// `control_timeout`, ms (the core's default when `None`).
    pub control_timeout_ms: Option<u32>,
}

impl Backend for MockVehicle {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        self.executed.push(cmd.id());
        if let Some(f) = self.fail_with.take() {
            out.str("partial", "must be discarded");
            return Err(f);
        }
        match (cmd.id(), cmd.args()) {
            (CommandId::State, _) => {
                out.object("state", |s| {
                    s.bool("armed", self.armed)
                        .str("fsm", "idle")
                        .bool("lock_mode", ctx.lock_mode);
                    ctx.write_authority(s);
                });
                for _ in 0..self.filler {
                    out.str("x", "0123456789");
                }
            }
            (CommandId::SetSpNed, Args::Setpoint(p)) => {
                out.f32("x", p.x).f32("y", p.y).f32("z", p.z).f32("yaw", p.yaw);
            }
            _ => {}
        }
        Ok(Step::Done)
    }

    fn password_changed(&mut self, new: &str) -> Result<(), Failure> {
        self.saved_password = Some(new.to_owned());
        Ok(())
    }

    fn failsafe(&self) -> Option<Failsafe> {
        self.failsafe
    }

    fn override_failsafe(&mut self) -> Result<(), Failure> {
        if let Some(f) = self.failsafe.as_mut() {
            f.overridden = true;
        }
        Ok(())
    }

    fn mission_running(&self) -> bool {
        self.mission_running
    }

    fn control_timeout_ms(&self) -> u32 {
        self.control_timeout_ms
            .unwrap_or(lluav_core::DEFAULT_CONTROL_TIMEOUT_MS)
    }

    fn lock_mode_changed(&mut self, on: bool) -> Result<(), Failure> {
        if let Some(f) = self.lock_save_fails.take() {
            return Err(f);
        }
        self.saved_lock_mode = Some(on);
        Ok(())
    }
}

pub fn clock() -> i64 {
    TS
}

pub type TestServer = Server<MockVehicle, fn() -> i64>;

pub fn server(password: Option<&str>) -> TestServer {
    Server::new(
        MockVehicle::default(),
        clock as fn() -> i64,
        Auth::new(password).unwrap(),
    )
}

/// What the client saw for one frame.
#[derive(Debug, PartialEq)]
pub enum Seen {
    Reply(serde_json::Value),
    ReplyThenClose(serde_json::Value, u16),
    Close(u16),
}

impl Seen {
    pub fn json(&self) -> &serde_json::Value {
        match self {
            Seen::Reply(v) | Seen::ReplyThenClose(v, _) => v,
            Seen::Close(c) => panic!("expected a reply, got close {c}"),
        }
    }
    pub fn ret(&self) -> i64 {
        self.json()["ret"].as_i64().expect("integer ret")
    }
    pub fn cmd(&self) -> i64 {
        self.json()["cmd"].as_i64().expect("integer cmd")
    }
    pub fn msg(&self) -> &str {
        self.json()["msg"].as_str().unwrap_or("")
    }
}

/// Parses a reply as exactly one JSON object with integer ret, cmd and ts.
pub fn checked_json(reply: &str) -> serde_json::Value {
    let v: serde_json::Value =
        serde_json::from_str(reply).unwrap_or_else(|e| panic!("not JSON ({e}): {reply:?}"));
    let obj = v.as_object().unwrap_or_else(|| panic!("not an object: {reply}"));
    assert!(obj["ret"].is_i64(), "ret: {reply}");
    assert!(obj["cmd"].is_u64(), "cmd: {reply}");
    assert!(obj["ts"].is_i64(), "ts: {reply}");
    let (r, c, t) = (
        reply.find(r#""ret":"#),
        reply.find(r#","cmd":"#),
        reply.find(r#","ts":"#),
    );
    assert!(
        r == Some(1) && c > r && t > c,
        "ret, cmd and ts lead, in that order: {reply}"
    );
    v
}

pub fn send_bytes(server: &mut TestServer, session: &mut Session, msg: Message<'_>) -> Seen {
    let mut out = vec![0u8; 64 * 1024];
    match server.handle(session, msg, &mut out) {
        Outcome::Reply(r) => Seen::Reply(checked_json(r)),
        Outcome::ReplyThenClose(r, c) => Seen::ReplyThenClose(checked_json(r), c.code()),
        Outcome::Close(c) => Seen::Close(c.code()),
        Outcome::Pending(t, _) => panic!("the mock vehicle never pends, yet got {t:?}"),
    }
}

pub fn send(server: &mut TestServer, session: &mut Session, frame: &str) -> Seen {
    send_bytes(server, session, Message::Text(frame.as_bytes()))
}

/// Valid argument strings per grammar (`None` = no arguments).
pub fn valid_args(g: Grammar) -> Vec<Option<String>> {
    let s = |v: &[&str]| v.iter().map(|a| Some(a.to_string())).collect::<Vec<_>>();
    match g {
        Grammar::None => vec![None],
        Grammar::Flag => s(&["0", "1"]),
        Grammar::OptCount => [vec![None], s(&["0", "7", "4294967295"])].concat(),
        Grammar::Pwm => s(&["0", "1500", "65535"]),
        Grammar::Amount => s(&["0", "12.5", "1e-3", "24", "-0", "-0.000e7", "1e+2"]),
        Grammar::OptAmount => [vec![None], s(&["0", "2.5"])].concat(),
        Grammar::Angle => s(&["-90", "90", "0.5", "-45.25", "90.000000000000000000000", "-9e1"]),
        Grammar::Name => s(&["map_1", "a b", "x.y", "a..", "é", "日本", &"n".repeat(128)]),
        Grammar::OptName => [vec![None], s(&["start.sh"])].concat(),
        Grammar::Path => s(&["a", "dir/file.json", "a b/c..d"]),
        Grammar::Text => s(&[
            "survey-7",
            "anything: {goes} here",
            " leading space kept",
            "عربي",
            &"p".repeat(4096),
        ]),
        Grammar::TaskName => s(&["inspection east", "日本", &"t".repeat(256)]),
        Grammar::Secret => s(&["pw", "with space"]),
        Grammar::NewPassword => s(&["n3w!Pass", &"x".repeat(32), "10250", "315"]),
        Grammar::ParamName => s(&["MPC_XY_VEL_MAX", "a.b-c"]),
        Grammar::SetParam => s(&["takeoff_alt:2.5", "name:a:b", "x:hello world"]),
        Grammar::Setpoint => s(&["1.0:2.0:-3.0:0.5", "1:2:-3:4", "-1e-3:2:-.5:5.", "0:0:-1e-45:0"]),
        Grammar::Point => s(&["10.0:5.0:-2.0", "0:0:0"]),
        Grammar::Pose => s(&["1,2,3,0.5", "-1.5,0,2e1,3.14"]),
        Grammar::Zyhk => s(&["1.5,2.0,2.5", "1.5 0,0,0", "1", &vec!["1"; 32].join(",")]),
        Grammar::Mission => s(&[
            r#"1001:{"waypoints":[{"x":1,"y":2,"z":-3}]}"#,
            "1001:[]",
            r#"7:{ "a" : [ true, false, null, -0.5e+3, "\u00e9\n" ] }"#,
            "7:missions/a.json",
        ]),
        Grammar::MwExec => s(&["1001:1,2,3,5", "0:0", &format!("1:{}", vec!["9"; 64].join(","))]),
        Grammar::Ai1Mission => s(&["task-1:missions/a.json", "T_2:f"]),
        Grammar::Override => [vec![None], s(&["failsafe"])].concat(),
    }
}

/// The frame for `name` with optional arguments.
pub fn frame(name: &str, args: &Option<String>) -> String {
    match args {
        Some(a) => format!("{name} {a}"),
        None => name.to_string(),
    }
}
