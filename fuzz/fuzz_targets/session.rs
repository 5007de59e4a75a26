//! Sequences of messages through the full entry point, over several
//! connections from a few client addresses, with a vehicle whose armed
//! state the input flips and a clock the input moves. Every text message
//! gets exactly one JSON object with integer ret, cmd and ts (at once, or
//! through `resume` when the vehicle waits), or a close code; the gates
//! hold; and every `login` is answered as DESIGN.md's throttling rules say
//! (per address, a table that drops no record that still matters, a budget
//! across all addresses), written out plainly in `Logins`.
//!
//! Input: the first byte's low bit sets a password (`pw`); the rest is split
//! at `\n` into messages, except these control lines: `\x01arm` and
//! `\x01disarm` flip the vehicle's armed state, `\x01binary` sends a binary
//! message, `\x01connN` closes the connection and opens a new one from
//! address `N % 8` (the throttle's table holds [`SLOTS`]), `\x01wait` moves
//! the clock 20 s on, `\x01tick` 200 ms; every line moves it 1 ms (so no
//! two records are touched at the same millisecond). A connection the
//! server closed is reopened from the same address. The vehicle waits for
//! an "autopilot" on `takeoff` and answers it through `resume`. Seeds are
//! therefore readable scripts (see `seeds/session`).
#![no_main]
// `!(armed && !run_on_arm)` reads as the gate rule it checks.
#![allow(clippy::nonminimal_bool)]

use std::cell::Cell;
use std::collections::HashMap;
use std::net::{IpAddr, Ipv4Addr};
use std::rc::Rc;

use libfuzzer_sys::fuzz_target;
use lluav_core::{
    Args, Auth, Backend, CloseCode, Command, CommandId, Context, Failure, Fields, Message, Outcome, Role,
    Server, Session, SessionId, Step, Ticket,
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

enum Line<'a> {
    Text(&'a [u8]),
    Binary,
    Arm(bool),
    Connect(u8),
    Wait,
    Tick,
}

fn lines(data: &[u8]) -> impl Iterator<Item = Line<'_>> {
    data.split(|&b| b == b'\n').map(|line| match line {
        b"\x01arm" => Line::Arm(true),
        b"\x01disarm" => Line::Arm(false),
        b"\x01binary" => Line::Binary,
        b"\x01wait" => Line::Wait,
        b"\x01tick" => Line::Tick,
        other => match other.strip_prefix(b"\x01conn") {
            Some(n) => Line::Connect(n.first().copied().unwrap_or(0) % 8),
            None => Line::Text(other),
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
        assert!(!(b.armed && !flags.run_on_arm), "{:?} ran while armed", cmd.id());
        assert!(
            !(b.locked && !b.admin() && !flags.run_in_lock),
            "{:?} ran in lock mode",
            cmd.id()
        );
        assert!(!flags.admin_only || b.admin(), "{:?} ran without admin", cmd.id());
        assert_eq!(
            (ctx.role, ctx.lock_mode, ctx.session, ctx.now_ms),
            (b.role, b.locked, b.session, b.now)
        );
        match cmd.id() {
            CommandId::Takeoff => {
                self.tickets += 1;
                let ticket = Ticket(self.tickets);
                self.waiting = Some(ticket);
                return Ok(Step::Pending(ticket));
            }
            CommandId::Land | CommandId::Disarm => self.armed = false,
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
}

const SAFETY: [CommandId; 6] = [
    CommandId::Land,
    CommandId::Rtl,
    CommandId::Mrtl,
    CommandId::TetherLand,
    CommandId::Disarm,
    CommandId::SetSpNed,
];

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
                !(spec.flags.admin_only && !b.admin()),
                "{frame:?} succeeded without admin"
            );
            assert!(
                !(b.armed && !spec.flags.run_on_arm),
                "{frame:?} succeeded while armed"
            );
            assert!(
                !(b.locked && !b.admin() && !spec.flags.run_in_lock),
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

fn ip(addr: u8) -> IpAddr {
    IpAddr::V4(Ipv4Addr::new(10, 0, 0, addr))
}

type Fuzzed = Server<Vehicle, Box<dyn Fn() -> i64>, [Slot; SLOTS]>;

/// Sends `bytes` on `client` and checks the answer; returns whether the
/// server closed the connection.
fn exchange(server: &mut Fuzzed, client: &mut Client, logins: &mut Logins, bytes: &[u8], b: Before) -> bool {
    let text = std::str::from_utf8(bytes).ok();
    let login = text.and_then(|t| match parse(t) {
        Ok(c) if c.id() == CommandId::Login => match c.args() {
            Args::Secret(attempt) => Some((*attempt).to_owned()),
            _ => None,
        },
        _ => None,
    });
    let password = server.auth().password().map(str::to_owned);
    let expected = login.map(|a| logins.expect(client.addr, &a, password.as_deref(), b.now));
    let mut out = [0u8; 4096];
    let mut outcome = server.handle(&mut client.session, Message::Text(bytes), &mut out);
    while let Outcome::Pending(ticket, buf) = outcome {
        assert_eq!(server.backend().waiting, Some(ticket));
        outcome = server.resume(&mut client.session, buf);
    }
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
        before: None,
        waiting: None,
        tickets: 0,
    };
    let mut server: Fuzzed = Server::new(vehicle, Box::new(move || clock.get()), auth);
    let mut logins = Logins::new(now.get());
    let mut client = Client {
        addr: 0,
        session: server.open(Some(ip(0).into())),
    };
    for line in lines(script) {
        now.set(now.get() + 1);
        let before = Before {
            gated: server.auth().password_required() && !client.session.logged_in(),
            role: client.session.role(),
            armed: server.backend().armed,
            locked: server.auth().lock_mode(),
            session: client.session.id(),
            now: now.get(),
        };
        server.backend_mut().before = Some(before);
        let reconnect = match line {
            Line::Arm(on) => {
                server.backend_mut().armed = on;
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
            Line::Text(bytes) => exchange(&mut server, &mut client, &mut logins, bytes, before),
        };
        if reconnect {
            server.close(&client.session);
            client.session = server.open(Some(ip(client.addr).into()));
        }
    }
});
