//! The one entry point adapters call: a WebSocket message in, response
//! bytes (and possibly a close code) out.
//!
//! [`Server::handle`] runs the whole protocol: DESIGN.md's WebSocket close
//! policy, the gates in order, argument parsing, the session commands the
//! core owns (`login`, `help`, `admin_lock`, `admin_unlock`, `passwd`), the
//! backend, and the response. Adapters own sockets and framing only.

use crate::backend::{Backend, Clock, Context};
use crate::command::{Args, Command};
use crate::error::{ArgError, Failure, ParseError, Refusal, Ret, cut_at_char_boundary, messages};
use crate::gate;
use crate::parse::{self, Split};
use crate::response::{self, Fields, HEAD_RESERVE};
use crate::session::{Auth, LoginOutcome, Session};
use crate::table::{CommandId, TABLE, lookup};

/// A complete WebSocket message, as the adapter's framing layer saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message<'a> {
    /// A text message (reassembled if it was fragmented); UTF-8 is checked here.
    Text(&'a [u8]),
    /// A binary message.
    Binary(&'a [u8]),
    /// A message longer than the adapter's frame limit.
    Oversized,
}

/// WebSocket close codes the protocol uses (RFC 6455, section 7.4.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[repr(u16)]
pub enum CloseCode {
    /// Normal closure.
    Normal = 1000,
    /// The server is going away (shutdown).
    GoingAway = 1001,
    /// A WebSocket protocol violation.
    ProtocolError = 1002,
    /// A binary message: this protocol is text only.
    Unsupported = 1003,
    /// A text message that is not UTF-8.
    InvalidPayload = 1007,
    /// Policy: too many wrong passwords.
    Policy = 1008,
    /// A message over the frame limit.
    TooBig = 1009,
    /// The response buffer is smaller than [`crate::MIN_RESPONSE_CAPACITY`].
    InternalError = 1011,
}

impl CloseCode {
    /// The number on the wire.
    pub fn code(self) -> u16 {
        self as u16
    }
}

/// What the adapter must do with one message.
#[must_use]
#[derive(Debug, PartialEq, Eq)]
pub enum Outcome<'o> {
    /// Send this text message.
    Reply(&'o str),
    /// Send this text message, then close with this code.
    ReplyThenClose(&'o str, CloseCode),
    /// Close with this code; nothing to send first.
    Close(CloseCode),
}

/// The protocol for one vehicle: its backend, clock and login state. Every
/// connection brings its own [`Session`].
#[derive(Debug)]
pub struct Server<B, C> {
    backend: B,
    clock: C,
    auth: Auth,
}

/// An answer before it is written.
enum Answer<'a> {
    /// Success for `cmd`; the members end at this offset of the buffer.
    Done(u8, usize),
    /// An error: ret, cmd and the message in parts.
    Error(Ret, u8, [&'a str; 2]),
    /// An error whose message the backend owns.
    Failed(u8, Failure),
}

impl<'a> Answer<'a> {
    fn refused(cmd: u8, r: Refusal) -> Self {
        Answer::Error(Ret::Failed, cmd, [r.message(), ""])
    }

    fn invalid(e: ParseError<'a>) -> Self {
        let cmd = e.command().map_or(0, u8::from);
        match e {
            ParseError::Empty => Answer::Error(Ret::InvalidArgs, cmd, [messages::EMPTY, ""]),
            ParseError::Unknown(name) => Answer::Error(
                Ret::InvalidArgs,
                cmd,
                [
                    messages::UNSUPPORTED_PREFIX,
                    cut_at_char_boundary(name, messages::UNKNOWN_NAME_ECHO),
                ],
            ),
            ParseError::InvalidArgs(id, _) => Answer::Error(
                Ret::InvalidArgs,
                cmd,
                [messages::INVALID_ARGS_PREFIX, id.spec().usage],
            ),
        }
    }
}

impl<B: Backend, C: Clock> Server<B, C> {
    /// A server for one vehicle.
    pub fn new(backend: B, clock: C, auth: Auth) -> Self {
        Server { backend, clock, auth }
    }

    /// The backend.
    pub fn backend(&self) -> &B {
        &self.backend
    }

    /// The backend, mutably (for adapters that tick a simulator).
    pub fn backend_mut(&mut self) -> &mut B {
        &mut self.backend
    }

    /// The vehicle-wide login state.
    pub fn auth(&self) -> &Auth {
        &self.auth
    }

    /// The vehicle-wide login state, mutably.
    pub fn auth_mut(&mut self) -> &mut Auth {
        &mut self.auth
    }

    /// Handles one WebSocket message of `session`, writing the response
    /// into `out`. Every text message gets exactly one JSON object; `out`
    /// should hold at least [`crate::MIN_RESPONSE_CAPACITY`] bytes, or even
    /// an error cannot be written and the outcome is a close with 1011.
    pub fn handle<'o>(
        &mut self,
        session: &mut Session,
        message: Message<'_>,
        out: &'o mut [u8],
    ) -> Outcome<'o> {
        let text = match message {
            Message::Text(bytes) => match core::str::from_utf8(bytes) {
                Ok(text) => text,
                Err(_) => return Outcome::Close(CloseCode::InvalidPayload),
            },
            Message::Binary(_) => return Outcome::Close(CloseCode::Unsupported),
            Message::Oversized => return Outcome::Close(CloseCode::TooBig),
        };
        let mut close = None;
        let answer = self.answer(session, text, out, &mut close);
        let ts = self.clock.unix_ms();
        let len = match answer {
            Answer::Done(cmd, end) => response::finish_ok(out, cmd, ts, end)
                .or_else(|| response::write_error(out, Ret::Failed, cmd, ts, &[messages::TOO_LARGE])),
            Answer::Error(ret, cmd, parts) => response::write_error(out, ret, cmd, ts, &parts),
            Answer::Failed(cmd, f) => response::write_error(out, f.ret(), cmd, ts, &[f.msg()]),
        };
        let reply = len
            .and_then(|n| out.get(..n))
            .and_then(|b| core::str::from_utf8(b).ok());
        match (reply, close) {
            (Some(r), None) => Outcome::Reply(r),
            (Some(r), Some(code)) => Outcome::ReplyThenClose(r, code),
            (None, _) => Outcome::Close(CloseCode::InternalError),
        }
    }

    fn answer<'a>(
        &mut self,
        session: &mut Session,
        text: &'a str,
        out: &mut [u8],
        close: &mut Option<CloseCode>,
    ) -> Answer<'a> {
        let split = parse::split(text);
        let spec = split.and_then(|s| lookup(s.name));
        let cmd = spec.map_or(0, |s| u8::from(s.id));
        if spec.map(|s| s.id) != Some(CommandId::Login)
            && let Err(r) = gate::login(session, &self.auth)
        {
            return Answer::refused(cmd, r);
        }
        let Some(Split { name, args }) = split else {
            return Answer::invalid(ParseError::Empty);
        };
        let Some(spec) = spec else {
            return Answer::invalid(ParseError::Unknown(name));
        };
        let backend = &self.backend;
        if let Err(r) = gate::command(&spec.flags, session, &self.auth, || backend.armed()) {
            return Answer::refused(cmd, r);
        }
        let command = match parse::parse_args(spec, args) {
            Ok(c) => c,
            Err(e) => return Answer::invalid(e),
        };
        let mut fields = Fields::after_head(out, HEAD_RESERVE);
        match (self.run(session, &command, &mut fields, close), fields.end()) {
            (Err(f), _) => Answer::Failed(cmd, f),
            (Ok(()), Some(end)) => Answer::Done(cmd, end),
            (Ok(()), None) => Answer::Error(Ret::Failed, cmd, [messages::TOO_LARGE, ""]),
        }
    }

    /// Runs a command that passed every gate.
    fn run(
        &mut self,
        session: &mut Session,
        command: &Command<'_>,
        out: &mut Fields<'_>,
        close: &mut Option<CloseCode>,
    ) -> Result<(), Failure> {
        match (command.id(), command.args()) {
            (CommandId::Login, Args::Secret(attempt)) => match self.auth.login(session, attempt) {
                LoginOutcome::Wrong { close: shut } => {
                    if shut {
                        *close = Some(CloseCode::Policy);
                    }
                    Err(Failure::failed(messages::WRONG_PASSWORD))
                }
                _ => {
                    out.bool("logged_in", session.logged_in())
                        .bool("admin", session.admin());
                    Ok(())
                }
            },
            (CommandId::Help, _) => {
                out.array("commands", |a| {
                    for spec in &TABLE {
                        a.str(spec.name);
                    }
                });
                Ok(())
            }
            (CommandId::AdminLock | CommandId::AdminUnlock, _) => {
                self.auth.set_lock_mode(command.id() == CommandId::AdminLock);
                out.bool("lock_mode", self.auth.lock_mode());
                Ok(())
            }
            (CommandId::Passwd, Args::NewPassword(new)) => {
                let bad = |_| invalid_args(command.id(), ArgError::BadPassword);
                self.auth.check_password(new).map_err(bad)?;
                self.backend.password_changed(new)?;
                self.auth.set_password(new).map_err(bad)?;
                self.auth.admit(session);
                Ok(())
            }
            _ => {
                let ctx = Context {
                    lock_mode: self.auth.lock_mode(),
                    admin: session.admin(),
                };
                self.backend.execute(command, &ctx, out)
            }
        }
    }
}

fn invalid_args(id: CommandId, e: ArgError) -> Failure {
    let msg = ParseError::InvalidArgs(id, e);
    Failure::fmt(Ret::InvalidArgs, format_args!("{msg}"))
}
