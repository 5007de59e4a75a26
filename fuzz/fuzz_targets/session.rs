//! Sequences of messages through the full entry point, over several
//! connections at once from a few client addresses, with a vehicle whose
//! armed state, failsafe and mission the input sets and a clock the input
//! moves. Every text message gets exactly one JSON object with integer
//! ret, cmd and ts (at once, or through `resume` when the vehicle waits),
//! or a close code; the gates hold; every `login` is answered as
//! DESIGN.md's throttling rules say (per address, a table that drops no
//! record that still matters, a budget across all addresses), written out
//! plainly in `Logins`; and flight authority holds, written out plainly in
//! `Authority`: who is in control after every message is what the rules
//! say, a command that steers reaches the vehicle only from the session in
//! control or while control is free and never while a failsafe holds, the
//! conservative commands are never refused by the control gate nor by the
//! failsafe gate (except `rtl`/`mrtl` while a failsafe lands the
//! vehicle), and while armed no failsafe is left by anything but
//! `control_take failsafe`.
//!
//! Input: the first byte's low bit sets a password (`pw`); the rest is split
//! at `\n` into messages, except these control lines: `\x01arm` and
//! `\x01disarm` flip the vehicle's armed state, `\x01failsafe` starts a
//! returning failsafe and `\x01landing` a landing one, `\x01mission`
//! starts or ends a mission, `\x01binary` sends a binary message,
//! `\x01useN` switches to connection `N % 3` (three are open at once),
//! `\x01connN` closes the current connection and opens a new one from
//! address `N % 8` (the throttle's table holds [`SLOTS`]), `\x01wait` moves
//! the clock 20 s on (past the control timeout), `\x01tick` 200 ms; every
//! line moves it 1 ms (so no two records are touched at the same
//! millisecond). A connection the server closed is reopened from the same
//! address. The vehicle waits for an "autopilot" on `takeoff` and answers
//! it through `resume`. Seeds are therefore readable scripts (see
//! `seeds/session`).
#![no_main]
// `!(armed && !run_on_arm)` reads as the gate rule it checks.
#![allow(clippy::nonminimal_bool)]

use std::cell::Cell;
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr};
use std::rc::Rc;

use libfuzzer_sys::fuzz_target;
use lluav_core::{
    Action, Args, Auth, Backend, Class, CloseCode, Command, CommandId, Context, Failsafe, Failure, Fields,
    Message, Outcome, Role, Server, Session, SessionId, Step, Ticket,
    error::messages,
    parse,
    parse::split,
    table::lookup,
    throttle::{MAX_WRONG_PASSWORDS, Slot, Throttle},
};

const LOCKOUT_MS: u32 = 30_000;
const MAX_LOCKOUT_MS: u32 = 15 * 60_000;
const WAIT_MS: i64 = 20_000;
const TICK_MS: i64 = 200;
/// Records the throttle's table holds: half the addresses.
const SLOTS: usize = 4;
/// Wrong passwords checked per second across all addresses.
const RATE: u16 = 8;
/// The vehicle's control timeout: shorter than a `\x01wait`.
const CONTROL_TIMEOUT_MS: u32 = 10_000;
/// Connections open at once.
const CLIENTS: usize = 3;

enum Line<'a> {
    Text(&'a [u8]),
    Binary,
    Arm(bool),
    Failsafe(Failsafe),
    Mission,
    Use(usize),
    Connect(u8),
    Wait,
    Tick,
}

const RETURNING: Failsafe = Failsafe::new("battery_low", Action::Rtl);
const LANDING: Failsafe = Failsafe::new("battery_empty", Action::Land);

fn lines(data: &[u8]) -> impl Iterator<Item = Line<'_>> {
    data.split(|&b| b == b'\n').map(|line| match line {
        b"\x01arm" => Line::Arm(true),
        b"\x01disarm" => Line::Arm(false),
        b"\x01failsafe" => Line::Failsafe(RETURNING),
        b"\x01landing" => Line::Failsafe(LANDING),
        b"\x01mission" => Line::Mission,
        b"\x01binary" => Line::Binary,
        b"\x01wait" => Line::Wait,
        b"\x01tick" => Line::Tick,
        other => match (other.strip_prefix(b"\x01conn"), other.strip_prefix(b"\x01use")) {
            (Some(n), _) => Line::Connect(n.first().copied().unwrap_or(0) % 8),
            (_, Some(n)) => Line::Use(usize::from(n.first().copied().unwrap_or(0)) % CLIENTS),
            _ => Line::Text(other),
        },
    })
}

/// What the gates knew just before a message.
#[derive(Clone, Copy)]
struct Before {
    gated: bool,
    role: Role,
    armed: bool,
    locked: bool,
    session: SessionId,
    now: i64,
    /// Who is in control as [`Authority`] says, once this message's
    /// request was heard.
    pilot: Option<SessionId>,
}

impl Before {
    fn admin(&self) -> bool {
        self.role == Role::Admin
    }
}

/// A deterministic vehicle that checks, on every execution, that the gates
/// let through only what they may.
struct Vehicle {
    armed: bool,
    failsafe: Option<Failsafe>,
    mission_running: bool,
    before: Option<Before>,
    waiting: Option<Ticket>,
    tickets: u32,
}

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let b = self.before.expect("execute runs only inside a message");
        let flags = cmd.id().spec().flags;
        assert!(!b.gated, "{:?} ran before login", cmd.id());
        assert!(
            !(b.armed && !flags.run_on_arm()),
            "{:?} ran while armed",
            cmd.id()
        );
        assert!(
            !(b.locked && !b.admin() && !flags.run_in_lock()),
            "{:?} ran in lock mode",
            cmd.id()
        );
        assert!(
            !flags.admin_only() || b.admin(),
            "{:?} ran without admin",
            cmd.id()
        );
        assert_eq!(
            (ctx.role, ctx.lock_mode, ctx.session, ctx.now_ms),
            (b.role, b.locked, b.session, b.now)
        );
        let class = cmd.id().spec().class;
        let steers = class.steers(|| self.mission_running);
        let holds = self.failsafe.filter(|f| !f.overridden);
        assert!(
            !steers || b.pilot.is_none_or(|p| p == b.session),
            "{:?} steered from a session not in control",
            cmd.id()
        );
        assert!(
            !(steers && holds.is_some()),
            "{:?} steered in a failsafe",
            cmd.id()
        );
        assert!(
            !(class == Class::Return && holds.is_some_and(|f| f.landing())),
            "{:?} climbed in a landing failsafe",
            cmd.id()
        );
        match cmd.id() {
            CommandId::Takeoff => {
                self.tickets += 1;
                let ticket = Ticket(self.tickets);
                self.waiting = Some(ticket);
                return Ok(Step::Pending(ticket));
            }
            CommandId::Land | CommandId::Disarm => {
                // On the ground, disarmed: the failsafe is over.
                self.armed = false;
                self.failsafe = None;
            }
            CommandId::Capture => return Err(Failure::system("camera unplugged")),
            CommandId::Sysinfo => {
                return Err(out.fail(lluav_core::Ret::SystemCall, format_args!("sysinfo(): {}", "EIO")));
            }
            _ => {}
        }
        out.str("echo", cmd.id().name());
        Ok(Step::Done)
    }

    fn finish(&mut self, ticket: Ticket, _: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        assert_eq!(
            self.waiting.take(),
            Some(ticket),
            "finish of a ticket nobody waits for"
        );
        self.armed = true;
        out.str("echo", "takeoff");
        Ok(Step::Done)
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
        CONTROL_TIMEOUT_MS
    }
}

const SAFETY: [CommandId; 6] = [
    CommandId::Land,
    CommandId::Rtl,
    CommandId::Mrtl,
    CommandId::TetherLand,
    CommandId::Disarm,
    CommandId::SetSpNed,
];

/// DESIGN.md's flight authority, written out plainly: who holds control.
#[derive(Default)]
struct Authority {
    pilot: Option<Pilot>,
}

#[derive(Clone, Copy)]
struct Pilot {
    session: SessionId,
    admin: bool,
    last: i64,
}

impl Authority {
    /// A text message from `session` at `now`: silence lapses control, any
    /// request from the pilot keeps it.
    fn heard(&mut self, session: SessionId, now: i64) {
        if self
            .pilot
            .is_some_and(|p| now - p.last >= i64::from(CONTROL_TIMEOUT_MS))
        {
            self.pilot = None;
        }
        if let Some(p) = self.pilot.as_mut().filter(|p| p.session == session) {
            p.last = now;
        }
    }

    fn give(&mut self, session: SessionId, admin: bool, now: i64) {
        if self.pilot.is_none_or(|p| p.session != session) {
            self.pilot = Some(Pilot {
                session,
                admin,
                last: now,
            });
        }
    }

    /// What a command that answered 0 did to control.
    fn answered(&mut self, id: CommandId, steered: bool, b: &Before) {
        let class = id.spec().class;
        let admin_keeps = b.locked && self.pilot.is_some_and(|p| p.admin && p.session != b.session);
        match id {
            CommandId::ControlTake => self.give(b.session, b.admin(), b.now),
            CommandId::ControlRelease => self.pilot = None,
            _ if steered => self.give(b.session, b.admin(), b.now),
            _ if class.conservative() && !admin_keeps => self.give(b.session, b.admin(), b.now),
            _ => {}
        }
    }

    fn closed(&mut self, session: SessionId) {
        if self.pilot.is_some_and(|p| p.session == session) {
            self.pilot = None;
        }
    }
}

/// The authority rules on a reply: the conservative commands are never
/// refused by the control gate, nor by the failsafe gate except a return
/// while a failsafe lands the vehicle.
fn check_authority(spec: &lluav_core::Spec, msg: &str, holds: Option<Failsafe>) {
    if spec.class.conservative() {
        assert!(!msg.starts_with(messages::FLOWN_BY), "{}: {msg}", spec.name());
        let landing_return = spec.class == Class::Return && holds.is_some_and(|f| f.landing());
        assert!(
            landing_return || !msg.starts_with(messages::FAILSAFE_OPEN),
            "{}: {msg}",
            spec.name()
        );
    }
}

fn check_reply(reply: &str, frame: &str, b: Before) {
    let v: serde_json::Value = serde_json::from_str(reply).expect("a reply is JSON");
    let obj = v.as_object().expect("a reply is an object");
    let ret = obj["ret"].as_i64().expect("integer ret");
    let cmd = obj["cmd"].as_u64().expect("integer cmd");
    assert_eq!(obj["ts"].as_i64(), Some(b.now), "ts is the request's time");
    assert!(reply.starts_with(r#"{"ret":"#));
    let spec = split(frame).and_then(|s| lookup(s.name));
    assert_eq!(cmd, spec.map_or(0, |s| u64::from(u8::from(s.id))));
    let msg = obj.get("msg").and_then(|m| m.as_str()).unwrap_or("");
    if let Some(spec) = spec {
        if ret == 0 {
            // A success the gates should have refused is a breach, also for
            // the commands the core answers itself (passwd, admin_lock, …).
            assert!(
                !(b.gated && spec.id != CommandId::Login),
                "{frame:?} succeeded before login"
            );
            assert!(
                !(spec.flags.admin_only() && !b.admin()),
                "{frame:?} succeeded without admin"
            );
            assert!(
                !(b.armed && !spec.flags.run_on_arm()),
                "{frame:?} succeeded while armed"
            );
            assert!(
                !(b.locked && !b.admin() && !spec.flags.run_in_lock()),
                "{frame:?} succeeded in lock"
            );
        }
        if SAFETY.contains(&spec.id) {
            assert_ne!(msg, messages::ARMED, "{frame:?}");
            assert_ne!(msg, messages::LOCKED, "{frame:?}");
        }
    }
    if b.gated && spec.is_none_or(|s| s.id != CommandId::Login) {
        assert_eq!((ret, msg), (-1, messages::LOGIN_FIRST), "{frame:?}");
    }
}

/// One address's history: wrong passwords in a row, lockouts so far,
/// locked until, the last wrong password.
struct Entry {
    wrong: u8,
    lockouts: u32,
    until: i64,
    last_wrong: i64,
}

/// DESIGN.md's throttling rules, written out plainly: what a `login` must
/// be answered.
struct Logins {
    records: HashMap<u8, Entry>,
    /// The budget as milliseconds of refill banked: a check needs one
    /// interval's worth; at most `RATE` intervals are banked.
    credit: i64,
    at: i64,
}

impl Logins {
    const INTERVAL: i64 = (1000 + RATE as i64 - 1) / RATE as i64;

    fn new(now: i64) -> Logins {
        Logins {
            records: HashMap::new(),
            credit: Logins::INTERVAL * i64::from(RATE),
            at: now,
        }
    }

    /// Whether a record may go to make room for another.
    fn spent(e: &Entry, now: i64) -> bool {
        now >= e.until && now - e.last_wrong >= i64::from(LOCKOUT_MS)
    }

    /// The `msg` a login with `attempt` from `addr` must get ("" for ret 0).
    fn expect(&mut self, addr: u8, attempt: &str, password: Option<&str>, now: i64) -> &'static str {
        self.credit = (self.credit + (now - self.at)).min(Logins::INTERVAL * i64::from(RATE));
        self.at = now;
        let room = self.records.len() < SLOTS || self.records.values().any(|e| Logins::spent(e, now));
        match self.records.get(&addr) {
            Some(e) if now < e.until => return messages::THROTTLED,
            None if !room => return messages::THROTTLED,
            _ if self.credit < Logins::INTERVAL => return messages::THROTTLED,
            _ => {}
        }
        if attempt == "1025" || password == Some(attempt) {
            self.records.remove(&addr);
            return "";
        }
        if attempt == "0315" {
            return "";
        }
        self.credit -= Logins::INTERVAL;
        if !self.records.contains_key(&addr) && self.records.len() == SLOTS {
            let oldest = self
                .records
                .iter()
                .filter(|(_, e)| Logins::spent(e, now))
                .min_by_key(|(_, e)| e.last_wrong)
                .map(|(a, _)| *a)
                .expect("room was checked");
            self.records.remove(&oldest);
        }
        let e = self.records.entry(addr).or_insert(Entry {
            wrong: 0,
            lockouts: 0,
            until: i64::MIN,
            last_wrong: now,
        });
        e.wrong += 1;
        e.last_wrong = now;
        if e.wrong >= MAX_WRONG_PASSWORDS {
            let ms = u64::from(LOCKOUT_MS)
                .checked_shl(e.lockouts)
                .map_or(u64::from(MAX_LOCKOUT_MS), |ms| ms.min(u64::from(MAX_LOCKOUT_MS)));
            e.until = now + i64::try_from(ms).expect("a lockout fits");
            e.lockouts += 1;
            e.wrong = 0;
        }
        messages::WRONG_PASSWORD
    }
}

/// One client connection and where it comes from.
struct Client {
    addr: u8,
    session: Session,
}

/// The reply's `ret` and `msg`, and the command it answers.
fn answer_of(reply: &str, frame: &str) -> (i64, String, Option<&'static lluav_core::Spec>) {
    let v: serde_json::Value = serde_json::from_str(reply).expect("a reply is JSON");
    let ret = v["ret"].as_i64().expect("integer ret");
    let msg = v["msg"].as_str().unwrap_or("").to_owned();
    (ret, msg, split(frame).and_then(|s| lookup(s.name)))
}

fn ip(addr: u8) -> IpAddr {
    IpAddr::V4(Ipv4Addr::new(10, 0, 0, addr))
}

type Fuzzed = Server<Vehicle, Box<dyn Fn() -> i64>, [Slot; SLOTS]>;

/// Sends `bytes` on `client` and checks the answer against the rules and
/// `authority`; returns whether the server closed the connection.
fn exchange(
    server: &mut Fuzzed,
    client: &mut Client,
    logins: &mut Logins,
    authority: &mut Authority,
    bytes: &[u8],
    b: Before,
) -> bool {
    let text = std::str::from_utf8(bytes).ok();
    let login = text.and_then(|t| match parse(t) {
        Ok(c) if c.id() == CommandId::Login => match c.args() {
            Args::Secret(attempt) => Some((*attempt).to_owned()),
            _ => None,
        },
        _ => None,
    });
    let password = server.auth().password().map(str::to_owned);
    let expected = login
        .as_deref()
        .map(|a| logins.expect(client.addr, a, password.as_deref(), b.now));
    let holds = server.backend().failsafe.filter(|f| !f.overridden);
    let steers = text
        .and_then(split)
        .and_then(|s| lookup(s.name))
        .is_some_and(|spec| spec.class.steers(|| server.backend().mission_running));
    let mut out = [0u8; 4096];
    let mut outcome = server.handle(&mut client.session, Message::Text(bytes), &mut out);
    while let Outcome::Pending(ticket, buf) = outcome {
        assert_eq!(server.backend().waiting, Some(ticket));
        outcome = server.resume(&mut client.session, buf);
    }
    if let (Some(reply), Some(frame)) = (outcome.reply(), text) {
        let (ret, msg, spec) = answer_of(reply, frame);
        if let Some(spec) = spec {
            check_authority(spec, &msg, holds);
            if ret == 0 {
                authority.answered(spec.id, steers, &b);
                // DESIGN: control is released when its session ends, and a
                // logout ends what the session may do.
                if login.as_deref() == Some("0315") {
                    authority.closed(b.session);
                }
            }
        }
        // While armed, only `control_take failsafe` leaves a failsafe.
        let left = holds.is_some() && server.backend().failsafe.is_none_or(|f| f.overridden);
        if left && server.backend().armed {
            let overriding = parse(frame).is_ok_and(|c| *c.args() == Args::Override(true));
            assert!(ret == 0 && overriding, "{frame:?} left the failsafe");
        }
    }
    assert_eq!(
        server.control().pilot().map(|p| p.session()),
        authority.pilot.map(|p| p.session),
        "who is in control after {:?}",
        String::from_utf8_lossy(bytes)
    );
    if let (Some(reply), Some(expected)) = (outcome.reply(), expected) {
        let v: serde_json::Value = serde_json::from_str(reply).expect("a reply is JSON");
        assert_eq!(
            v["msg"].as_str().unwrap_or(""),
            expected,
            "login from {}",
            client.addr
        );
    }
    match outcome {
        Outcome::Reply(r) => check_reply(r, text.expect("only UTF-8 is answered"), b),
        Outcome::ReplyThenClose(r, code) => {
            assert_eq!(code, CloseCode::Policy);
            check_reply(r, text.expect("only UTF-8 is answered"), b);
            return true;
        }
        Outcome::Close(code) => {
            assert!(text.is_none(), "a text message got close {code:?}");
            assert_eq!(code, CloseCode::InvalidPayload);
            return true;
        }
        Outcome::Pending(..) => unreachable!("resumed above"),
    }
    false
}

fuzz_target!(|data: &[u8]| {
    let Some((&first, script)) = data.split_first() else {
        return;
    };
    let now = Rc::new(Cell::new(1_700_000_000_000_i64));
    let clock = Rc::clone(&now);
    let throttle = Throttle::new(LOCKOUT_MS, MAX_LOCKOUT_MS)
        .with_table([Slot::EMPTY; SLOTS])
        .with_rate(RATE);
    let auth = Auth::new((first & 1 == 1).then_some("pw"))
        .expect("valid password")
        .with_throttle(throttle);
    let vehicle = Vehicle {
        armed: false,
        failsafe: None,
        mission_running: false,
        before: None,
        waiting: None,
        tickets: 0,
    };
    let mut server: Fuzzed = Server::new(vehicle, Box::new(move || clock.get()), auth);
    let mut logins = Logins::new(now.get());
    let mut authority = Authority::default();
    let mut clients: Vec<Client> = (0..CLIENTS)
        .map(|i| {
            let addr = u8::try_from(i).expect("a few clients");
            Client {
                addr,
                session: server.open(Some(ip(addr).into())),
            }
        })
        .collect();
    let mut active = 0;
    for line in lines(script) {
        now.set(now.get() + 1);
        let client = &mut clients[active];
        if let Line::Text(bytes) = line
            && std::str::from_utf8(bytes).is_ok()
        {
            authority.heard(client.session.id(), now.get());
        }
        let before = Before {
            gated: server.auth().password_required() && !client.session.logged_in(),
            role: client.session.role(),
            armed: server.backend().armed,
            locked: server.auth().lock_mode(),
            session: client.session.id(),
            now: now.get(),
            pilot: authority.pilot.map(|p| p.session),
        };
        server.backend_mut().before = Some(before);
        let reconnect = match line {
            Line::Arm(on) => {
                server.backend_mut().armed = on;
                false
            }
            Line::Failsafe(f) => {
                server.backend_mut().failsafe = Some(f);
                false
            }
            Line::Mission => {
                let running = &mut server.backend_mut().mission_running;
                *running = !*running;
                false
            }
            Line::Wait => {
                now.set(now.get() + WAIT_MS);
                false
            }
            Line::Tick => {
                now.set(now.get() + TICK_MS);
                false
            }
            Line::Use(n) => {
                active = n;
                false
            }
            Line::Connect(addr) => {
                client.addr = addr;
                true
            }
            Line::Binary => {
                let mut out = [0u8; 64];
                let o = server.handle(&mut client.session, Message::Binary(b"state"), &mut out);
                assert_eq!(o, Outcome::Close(CloseCode::Unsupported));
                true
            }
            Line::Text(bytes) => exchange(&mut server, client, &mut logins, &mut authority, bytes, before),
        };
        if reconnect {
            let client = &mut clients[active];
            server.close(&client.session);
            authority.closed(client.session.id());
            client.session = server.open(Some(ip(client.addr).into()));
        }
    }
});
