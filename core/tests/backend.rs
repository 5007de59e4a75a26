//! The backend contract: what a backend is told, commands that wait for
//! something outside, whole failure messages, and the close policy.

mod common;

use std::net::{IpAddr, Ipv4Addr};

use common::{TS, checked_json, clock};
use lluav_core::{
    Auth, Backend, CloseCode, Command, CommandId, Context, Failure, Fields, Message, Outcome, Peer, Ret,
    Role, Server, SessionId, Step, Ticket,
};

/// A vehicle that records what it was told, waits for an "autopilot" on
/// `takeoff`, and fails `ver` with a long message written by `Fields::fail`.
#[derive(Default)]
struct Recorder {
    /// What each command was told (the pilot left out: it borrows).
    contexts: Vec<(CommandId, Context<'static>)>,
    closed: Vec<SessionId>,
    /// Tickets `finish` still considers not ready.
    not_ready: u32,
    /// What `finish` does once ready.
    finish_fails: bool,
}

const LONG_REASON: &str = "cannot read maps/a-rather-long-map-name-that-would-not-fit-in-ninety-six-bytes/\
                           keyframes.bin: \"permission\" denied";

impl Backend for Recorder {
    fn armed(&self) -> bool {
        false
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        self.contexts.push((cmd.id(), Context { pilot: None, ..*ctx }));
        match cmd.id() {
            CommandId::Takeoff => Ok(Step::Pending(Ticket(7))),
            CommandId::Ver => {
                out.str("partial", "discarded");
                Err(out.fail(Ret::SystemCall, format_args!("{LONG_REASON}")))
            }
            CommandId::Sysinfo => {
                let mut failure = None;
                out.object("sysinfo", |o| {
                    o.u64("uptime", 1);
                    failure = Some(o.fail(Ret::SystemCall, format_args!("sysinfo() failed: {}", "EPERM")));
                    o.u64("after", 2);
                });
                Err(failure.unwrap_or_else(Failure::unhandled))
            }
            _ => Ok(Step::Done),
        }
    }

    fn finish(&mut self, ticket: Ticket, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        assert_eq!(ticket, Ticket(7));
        self.contexts
            .push((CommandId::Takeoff, Context { pilot: None, ..*ctx }));
        if self.not_ready > 0 {
            self.not_ready -= 1;
            return Ok(Step::Pending(ticket));
        }
        if self.finish_fails {
            return Err(Failure::failed("MAV_RESULT_DENIED"));
        }
        out.str("fsm", "takeoff");
        Ok(Step::Done)
    }

    fn session_closed(&mut self, session: SessionId) {
        self.closed.push(session);
    }
}

fn server() -> Server<Recorder, fn() -> i64> {
    Server::new(
        Recorder::default(),
        clock as fn() -> i64,
        Auth::new(None).unwrap(),
    )
}

fn reply(outcome: Outcome<'_>) -> serde_json::Value {
    checked_json(outcome.reply().unwrap_or_else(|| panic!("a reply: {outcome:?}")))
}

#[test]
fn open_hands_out_distinct_sessions_that_remember_their_peer() {
    let mut s = server();
    let addr = IpAddr::from(Ipv4Addr::new(10, 0, 0, 1));
    let a = s.open(Some(addr.into()));
    let b = s.open(None);
    let c = s.open(Some(Peer::Client([7; 16])));
    assert_ne!(a.id(), b.id());
    assert_ne!(a.id(), SessionId(0), "0 is for sessions made without a server");
    assert_eq!(a.peer(), Some(Peer::Address(addr)));
    assert_eq!(b.peer(), None);
    assert_eq!(c.peer(), Some(Peer::Client([7; 16])));
    assert_eq!(a.role(), Role::Anonymous);
}

#[test]
fn close_tells_the_backend_which_session_ended() {
    let mut s = server();
    let a = s.open(None);
    let b = s.open(None);
    s.close(&b);
    s.close(&a);
    assert_eq!(s.backend().closed, vec![b.id(), a.id()]);
}

#[test]
fn the_backend_is_told_the_request_time_role_lock_mode_and_session() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; 4096];
    let _ = s.handle(&mut session, Message::Text(b"state"), &mut out);
    let _ = s.handle(&mut session, Message::Text(b"login 1025"), &mut out);
    let _ = s.handle(&mut session, Message::Text(b"admin_lock"), &mut out);
    let _ = s.handle(&mut session, Message::Text(b"state"), &mut out);
    let seen: Vec<_> = s.backend().contexts.iter().map(|(_, c)| *c).collect();
    let at = |role, lock_mode| Context::new(TS, lock_mode, role, session.id());
    assert_eq!(seen, vec![at(Role::Anonymous, false), at(Role::Admin, true)]);
}

#[test]
fn a_pending_command_is_answered_by_resume_once_ready() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; 4096];
    let Outcome::Pending(ticket, buf) = s.handle(&mut session, Message::Text(b"takeoff"), &mut out) else {
        panic!("takeoff waits for the autopilot");
    };
    assert_eq!(ticket, Ticket(7));
    assert_eq!(session.pending(), Some((Ticket(7), CommandId::Takeoff)));
    s.backend_mut().not_ready = 1;
    let Outcome::Pending(again, buf) = s.resume(&mut session, buf) else {
        panic!("not ready yet");
    };
    assert_eq!(again, Ticket(7));
    let v = reply(s.resume(&mut session, buf));
    assert_eq!(
        v,
        serde_json::json!({"ret": 0, "cmd": 18, "ts": TS, "fsm": "takeoff"})
    );
    assert_eq!(session.pending(), None);
}

#[test]
fn a_pending_command_that_fails_is_answered_with_its_failure() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; 4096];
    let _ = s.handle(&mut session, Message::Text(b"takeoff"), &mut out);
    s.backend_mut().finish_fails = true;
    let v = reply(s.resume(&mut session, &mut out));
    assert_eq!((v["ret"].as_i64(), v["cmd"].as_i64()), (Some(-1), Some(18)));
    assert_eq!(v["msg"], "MAV_RESULT_DENIED");
}

#[test]
fn resume_without_a_pending_command_closes_with_1011() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; 4096];
    assert_eq!(
        s.resume(&mut session, &mut out),
        Outcome::Close(CloseCode::InternalError)
    );
}

#[test]
fn a_failure_written_into_the_buffer_is_whole_and_replaces_the_fields() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; 4096];
    let v = reply(s.handle(&mut session, Message::Text(b"ver"), &mut out));
    assert!(LONG_REASON.len() > lluav_core::error::FAILURE_MSG_CAPACITY);
    assert_eq!(
        v,
        serde_json::json!({"ret": -3, "cmd": 5, "ts": TS, "msg": LONG_REASON}),
        "whole, escaped, and without the partial field"
    );
}

#[test]
fn a_failure_written_inside_a_nested_object_still_replaces_everything() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; 4096];
    let v = reply(s.handle(&mut session, Message::Text(b"sysinfo"), &mut out));
    assert_eq!(
        v,
        serde_json::json!({"ret": -3, "cmd": 6, "ts": TS, "msg": "sysinfo() failed: EPERM"})
    );
}

#[test]
fn a_written_failure_is_cut_at_a_character_boundary_to_fit_a_small_buffer() {
    let mut s = server();
    let mut session = s.open(None);
    let mut out = vec![0u8; lluav_core::MIN_RESPONSE_CAPACITY];
    let reply_text = s
        .handle(&mut session, Message::Text(b"ver"), &mut out)
        .reply()
        .expect("a reply")
        .to_owned();
    let v = checked_json(&reply_text);
    let msg = v["msg"].as_str().unwrap();
    assert!(LONG_REASON.starts_with(msg) && msg.len() > 64, "{msg:?}");
    assert!(reply_text.len() <= lluav_core::MIN_RESPONSE_CAPACITY);
}

#[test]
fn message_text_is_the_one_close_policy() {
    assert_eq!(Message::Text(b"state").text(), Ok("state"));
    assert_eq!(Message::Text(b"\xff").text(), Err(CloseCode::InvalidPayload));
    assert_eq!(Message::Binary(b"state").text(), Err(CloseCode::Unsupported));
    assert_eq!(Message::Oversized.text(), Err(CloseCode::TooBig));
}

#[test]
fn outcome_says_what_to_send_and_how_to_close() {
    assert_eq!(Outcome::Reply("x").reply(), Some("x"));
    assert_eq!(Outcome::Reply("x").close_code(), None);
    let both = Outcome::ReplyThenClose("x", CloseCode::Policy);
    assert_eq!(
        (both.reply(), both.close_code()),
        (Some("x"), Some(CloseCode::Policy))
    );
    let close = Outcome::Close(CloseCode::TooBig);
    assert_eq!(
        (close.reply(), close.close_code()),
        (None, Some(CloseCode::TooBig))
    );
    let mut buf = [0u8; 1];
    let pending = Outcome::Pending(Ticket(1), &mut buf);
    assert_eq!((pending.reply(), pending.close_code()), (None, None));
}
