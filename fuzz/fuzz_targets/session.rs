//! Sequences of messages through the full entry point, with a vehicle whose
//! armed state the input flips. Every text message gets exactly one JSON
//! object with integer ret, cmd and ts, or a close code; and the gates hold.
//!
//! Input: the first byte's low bit sets a password (`pw`); the rest is split
//! at `\n` into messages, except that the lines `\x01arm`, `\x01disarm`
//! and `\x01binary` flip the vehicle's armed state or send a binary
//! message. Seeds are therefore readable scripts (see `seeds/session`).
#![no_main]
// `!(armed && !run_on_arm)` reads as the gate rule it checks.
#![allow(clippy::nonminimal_bool)]

use libfuzzer_sys::fuzz_target;
use lluav_core::{
    Auth, Backend, CloseCode, Command, CommandId, Context, Failure, Fields, Message, Outcome, Server,
    Session, error::messages, parse::split, table::lookup,
};

enum Step<'a> {
    Text(&'a [u8]),
    Binary,
    Arm(bool),
}

fn steps(data: &[u8]) -> impl Iterator<Item = Step<'_>> {
    data.split(|&b| b == b'\n').map(|line| match line {
        b"\x01arm" => Step::Arm(true),
        b"\x01disarm" => Step::Arm(false),
        b"\x01binary" => Step::Binary,
        other => Step::Text(other),
    })
}

/// What the gates knew just before a message.
#[derive(Clone, Copy)]
struct Before {
    gated: bool,
    admin: bool,
    armed: bool,
    locked: bool,
}

/// A deterministic vehicle that checks, on every execution, that the gates
/// let through only what they may.
struct Vehicle {
    armed: bool,
    before: Option<Before>,
}

impl Backend for Vehicle {
    fn armed(&self) -> bool {
        self.armed
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<(), Failure> {
        let b = self.before.expect("execute runs only inside a message");
        let flags = cmd.id().spec().flags;
        assert!(!b.gated, "{:?} ran before login", cmd.id());
        assert!(!(b.armed && !flags.run_on_arm), "{:?} ran while armed", cmd.id());
        assert!(
            !(b.locked && !b.admin && !flags.run_in_lock),
            "{:?} ran in lock mode",
            cmd.id()
        );
        assert!(!flags.admin_only || b.admin, "{:?} ran without admin", cmd.id());
        assert_eq!((ctx.admin, ctx.lock_mode), (b.admin, b.locked));
        match cmd.id() {
            CommandId::Takeoff => self.armed = true,
            CommandId::Land | CommandId::Disarm => self.armed = false,
            CommandId::Capture => return Err(Failure::system("camera unplugged")),
            _ => {}
        }
        out.str("echo", cmd.id().name());
        Ok(())
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
    obj["ts"].as_i64().expect("integer ts");
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
                !(spec.flags.admin_only && !b.admin),
                "{frame:?} succeeded without admin"
            );
            assert!(
                !(b.armed && !spec.flags.run_on_arm),
                "{frame:?} succeeded while armed"
            );
            assert!(
                !(b.locked && !b.admin && !spec.flags.run_in_lock),
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

fuzz_target!(|data: &[u8]| {
    let Some((&first, script)) = data.split_first() else {
        return;
    };
    let auth = Auth::new((first & 1 == 1).then_some("pw")).expect("valid password");
    let mut server = Server::new(
        Vehicle {
            armed: false,
            before: None,
        },
        || 1_700_000_000_000_i64,
        auth,
    );
    let mut session = Session::new();
    let mut out = [0u8; 4096];
    for step in steps(script) {
        let before = Before {
            gated: server.auth().password_required() && !session.logged_in(),
            admin: session.admin(),
            armed: server.backend().armed,
            locked: server.auth().lock_mode(),
        };
        server.backend_mut().before = Some(before);
        let bytes: &[u8] = match step {
            Step::Arm(on) => {
                server.backend_mut().armed = on;
                continue;
            }
            Step::Binary => {
                let o = server.handle(&mut session, Message::Binary(b"state"), &mut out);
                assert_eq!(o, Outcome::Close(CloseCode::Unsupported));
                continue;
            }
            Step::Text(b) => b,
        };
        let text = std::str::from_utf8(bytes).ok();
        match server.handle(&mut session, Message::Text(bytes), &mut out) {
            Outcome::Reply(r) => check_reply(r, text.expect("only UTF-8 is answered"), before),
            Outcome::ReplyThenClose(r, code) => {
                assert_eq!(code, CloseCode::Policy);
                check_reply(r, text.expect("only UTF-8 is answered"), before);
                break;
            }
            Outcome::Close(code) => {
                assert!(text.is_none(), "a text message got close {code:?}");
                assert_eq!(code, CloseCode::InvalidPayload);
            }
        }
    }
});
