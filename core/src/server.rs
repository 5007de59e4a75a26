//! The one entry point adapters call: a WebSocket message in, response
//! bytes (and possibly a close code) out.
//!
//! [`Server::handle`] runs the whole protocol: DESIGN.md's WebSocket close
//! policy ([`Message::text`]), the gates in order, argument parsing, the
//! session commands the core owns (`login`, `help`, `admin_lock`,
//! `admin_unlock`, `passwd`, and flight authority's `control`,
//! `control_take`, `control_release`), the backend, and the response. Adapters own
//! sockets and framing only: they open a [`Session`] per connection with
//! [`Server::open`], hand every message to [`Server::handle`], carry out the
//! [`Outcome`] (calling [`Server::resume`] once a pending backend is ready)
//! and report the end of the connection with [`Server::close`].

use crate::authority::{Control, Label, Via};
use crate::backend::{Backend, Clock, Context, Step, Ticket};
use crate::command::{Args, Command};
use crate::error::{ArgError, Failure, ParseError, Refusal, Ret, messages};
use crate::gate;
use crate::parse::{self, Split};
use crate::response::{self, Fields};
use crate::session::{Auth, AuthError, LoginOutcome, Peer, Pending, Session, SessionId};
use crate::table::{CommandId, TABLE, lookup};
use crate::throttle::{DefaultSlots, Slots};

/// A complete WebSocket message, as the adapter's framing layer saw it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Message<'a> {
    /// A text message (reassembled if it was fragmented); UTF-8 is checked
    /// by [`Message::text`].
    Text(&'a [u8]),
    /// A binary message.
    Binary(&'a [u8]),
    /// A message longer than the adapter's frame limit.
    Oversized,
}

impl<'a> Message<'a> {
    /// The text of a message the protocol accepts, or the code to close
    /// the connection with (DESIGN.md, "WebSocket behaviour"): a binary
    /// message 1003, text that is not UTF-8 1007, a message over the limit
    /// 1009. Both adapters' echo services use it too, so that the policy
    /// lives here only.
    pub fn text(self) -> Result<&'a str, CloseCode> {
        match self {
            Message::Text(bytes) => core::str::from_utf8(bytes).map_err(|_| CloseCode::InvalidPayload),
            Message::Binary(_) => Err(CloseCode::Unsupported),
            Message::Oversized => Err(CloseCode::TooBig),
        }
    }
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
    /// The backend is waiting for something outside: once it says this
    /// ticket is ready, call [`Server::resume`] with the buffer handed back
    /// here. Nothing is sent meanwhile, and the session's later messages
    /// wait their turn.
    Pending(Ticket, &'o mut [u8]),
}

impl<'o> Outcome<'o> {
    /// The text to send, if any.
    pub fn reply(&self) -> Option<&'o str> {
        match *self {
            Outcome::Reply(text) | Outcome::ReplyThenClose(text, _) => Some(text),
            Outcome::Close(_) | Outcome::Pending(..) => None,
        }
    }

    /// The code to close the connection with once the reply is sent, if any.
    pub fn close_code(&self) -> Option<CloseCode> {
        match *self {
            Outcome::ReplyThenClose(_, code) | Outcome::Close(code) => Some(code),
            Outcome::Reply(_) | Outcome::Pending(..) => None,
        }
    }
}

/// The protocol for one vehicle: its backend, clock and login state (`S`
/// is the storage of its login throttle's table). Every connection brings
/// its own [`Session`].
#[derive(Debug)]
pub struct Server<B, C, S = DefaultSlots> {
    backend: B,
    clock: C,
    auth: Auth<S>,
    /// Who flies (DESIGN.md, "Flight authority").
    control: Control,
    /// The last [`SessionId`] handed out.
    last_session: u32,
}

/// An answer before it is written.
enum Answer<'a> {
    /// Success for `cmd`; the members end at this offset of the buffer.
    Done(u8, usize),
    /// An error: ret, cmd and the message in parts.
    Error(Ret, u8, [&'a str; 2]),
    /// An error whose message the backend owns, and where the message ends
    /// in the buffer if [`Fields::fail`] wrote it there.
    Failed(u8, Failure, Option<usize>),
    /// The backend is waiting for something outside; whether the command
    /// takes control once it answers 0.
    Pending(CommandId, Ticket, bool),
}

impl<'a> Answer<'a> {
    fn refused(cmd: u8, r: Refusal) -> Self {
        Answer::Error(Ret::Failed, cmd, [r.message(), ""])
    }

    fn invalid(e: ParseError<'a>) -> Self {
        Answer::Error(Ret::InvalidArgs, e.command().map_or(0, u8::from), e.parts())
    }

    /// What a command that ran came to, given the fields it wrote (and, for
    /// one left pending, whether it takes control once it answers 0).
    fn settled(
        id: CommandId,
        result: Result<Step, Failure>,
        fields: &Fields<'_>,
        takes_control: bool,
    ) -> Self {
        let cmd = u8::from(id);
        match (result, fields.end()) {
            (Err(f), _) => Answer::Failed(cmd, f, fields.failure_end()),
            (Ok(Step::Pending(ticket)), _) => Answer::Pending(id, ticket, takes_control),
            (Ok(Step::Done), Some(end)) => Answer::Done(cmd, end),
            (Ok(Step::Done), None) => Answer::Error(Ret::Failed, cmd, [messages::TOO_LARGE, ""]),
        }
    }
}

impl<B: Backend, C: Clock, S: Slots> Server<B, C, S> {
    /// A server for one vehicle.
    pub fn new(backend: B, clock: C, auth: Auth<S>) -> Self {
        Server {
            backend,
            clock,
            auth,
            control: Control::default(),
            last_session: 0,
        }
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
    pub fn auth(&self) -> &Auth<S> {
        &self.auth
    }

    /// The vehicle-wide login state, mutably.
    pub fn auth_mut(&mut self) -> &mut Auth<S> {
        &mut self.auth
    }

    /// Who flies the vehicle (DESIGN.md, "Flight authority").
    pub fn control(&self) -> &Control {
        &self.control
    }

    /// A session for a new in-process connection from `peer` (who login
    /// throttling counts its wrong passwords for: its IP address, or a
    /// per-client key; `None` if the transport has neither). Transports
    /// use [`Server::open_via`], so that `control` can say who flies.
    pub fn open(&mut self, peer: Option<Peer>) -> Session {
        self.open_via(peer, Via::Local)
    }

    /// A session for a new connection from `peer`, reached `via` a
    /// transport (its label in `control`).
    pub fn open_via(&mut self, peer: Option<Peer>, via: Via<'_>) -> Session {
        self.last_session = self.last_session.wrapping_add(1).max(1);
        let id = SessionId(self.last_session);
        let mut session = Session::with(id, peer);
        session.set_label(Label::new(via, id));
        session
    }

    /// Reports that `session`'s connection has ended: control it held is
    /// free (the flight goes on).
    pub fn close(&mut self, session: &Session) {
        self.control.release(session.id());
        self.backend.session_closed(session.id());
    }

    /// When control lapses unless its session speaks first, ms since the
    /// Unix epoch; `None` while control is free. An adapter that tells
    /// others when control lapses waits until then and calls
    /// [`Server::expire_control`].
    pub fn control_lapses_at(&self) -> Option<i64> {
        let timeout = i64::from(self.backend.control_timeout_ms());
        self.control.pilot().map(|p| p.last_ms().saturating_add(timeout))
    }

    /// Ends control held without a request for the backend's control
    /// timeout; returns whether it did. Checked before every request
    /// anyway; an adapter that tells others when control lapses calls it
    /// when the timeout may have passed.
    pub fn expire_control(&mut self) -> bool {
        let now = self.clock.unix_ms();
        self.control
            .expire(now, self.backend.control_timeout_ms())
            .is_some()
    }

    /// Handles one WebSocket message of `session`, writing the response
    /// into `out`. Every text message gets exactly one JSON object (now, or
    /// through [`Server::resume`] after [`Outcome::Pending`]); `out` should
    /// hold at least [`crate::MIN_RESPONSE_CAPACITY`] bytes, or even an
    /// error cannot be written and the outcome is a close with 1011.
    pub fn handle<'o>(
        &mut self,
        session: &mut Session,
        message: Message<'_>,
        out: &'o mut [u8],
    ) -> Outcome<'o> {
        let text = match message.text() {
            Ok(text) => text,
            Err(code) => return Outcome::Close(code),
        };
        let now = self.clock.unix_ms();
        self.control
            .heard(session.id(), now, self.backend.control_timeout_ms());
        let mut close = None;
        let answer = self.answer(session, text, now, out, &mut close);
        write(session, answer, now, close, out)
    }

    /// Answers the command `session` was waiting for, once the backend said
    /// its ticket is ready. The answer may be [`Outcome::Pending`] again.
    /// A session that waits for nothing is closed with 1011: the adapter
    /// broke the contract.
    pub fn resume<'o>(&mut self, session: &mut Session, out: &'o mut [u8]) -> Outcome<'o> {
        let Some(Pending {
            ticket,
            id,
            takes_control,
        }) = session.take_pending()
        else {
            return Outcome::Close(CloseCode::InternalError);
        };
        let now = self.clock.unix_ms();
        let ctx = context(&self.backend, &self.control, &self.auth, session, now);
        let mut fields = Fields::after_head(out, u8::from(id), now);
        let result = self.backend.finish(ticket, &ctx, &mut fields);
        let answer = self.settle(session, id, result, &fields, takes_control, now);
        write(session, answer, now, None, out)
    }

    /// What a command that ran came to; one that takes control and answers
    /// 0 takes it first. (Control is settled before the answer is built, so
    /// that the answer is built where it is returned.)
    fn settle<'a>(
        &mut self,
        session: &Session,
        id: CommandId,
        result: Result<Step, Failure>,
        fields: &Fields<'_>,
        takes_control: bool,
        now: i64,
    ) -> Answer<'a> {
        let answers_0 = matches!(result, Ok(Step::Done)) && fields.end().is_some();
        if takes_control && answers_0 && !self.control.held_by(session.id()) {
            self.took_effect(session, id, now);
        }
        Answer::settled(id, result, fields, takes_control)
    }

    /// Control after a command that takes it (it steered or brought the
    /// vehicle down) answered 0: it goes to the command's session — except
    /// that in lock mode an admin pilot keeps it against a conservative
    /// command.
    /// (Not for the pilot's own commands: `handle` has already heard it.)
    fn took_effect(&mut self, session: &Session, id: CommandId, now: i64) {
        let steered = !id.spec().class.conservative();
        let admin_keeps = self.auth.lock_mode()
            && self
                .control
                .pilot()
                .is_some_and(|p| p.admin() && p.session() != session.id());
        if steered || !admin_keeps {
            self.control
                .give(session.id(), session.admin(), session.label(), now);
        }
    }

    fn answer<'a>(
        &mut self,
        session: &mut Session,
        text: &'a str,
        now: i64,
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
        let steers = spec.class.steers(|| backend.mission_running());
        let held = gate::failsafe(spec.class, steers, backend.failsafe())
            .and_then(|()| gate::control(steers, session, &self.control));
        if let Err(held) = held {
            let mut fields = Fields::after_head(out, cmd, now);
            let failure = held.fail(&mut fields);
            return Answer::settled(spec.id, Err(failure), &fields, false);
        }
        let command = match parse::parse_args(spec, args) {
            Ok(c) => c,
            Err(e) => return Answer::invalid(e),
        };
        let mut fields = Fields::after_head(out, cmd, now);
        let result = self.run(session, &command, now, &mut fields, close);
        let takes_control = steers || spec.class.conservative();
        self.settle(session, spec.id, result, &fields, takes_control, now)
    }

    /// Runs a command that passed every gate.
    fn run(
        &mut self,
        session: &mut Session,
        command: &Command<'_>,
        now: i64,
        out: &mut Fields<'_>,
        close: &mut Option<CloseCode>,
    ) -> Result<Step, Failure> {
        match (command.id(), command.args()) {
            (CommandId::Login, Args::Secret(attempt)) => self.login(session, attempt, now, out, close)?,
            (CommandId::Help, _) => {
                out.array("commands", |a| {
                    for spec in &TABLE {
                        a.str(spec.name());
                    }
                });
            }
            (CommandId::AdminLock | CommandId::AdminUnlock, _) => {
                let on = command.id() == CommandId::AdminLock;
                self.backend.lock_mode_changed(on)?;
                self.auth.set_lock_mode(on);
                out.bool("lock_mode", self.auth.lock_mode());
            }
            (CommandId::Passwd, Args::NewPassword(new)) => self.passwd(session, new)?,
            (CommandId::Control, _) => {
                match self.control.pilot() {
                    Some(p) => out.object("control", |o| p.write(o, Some(p.session() == session.id()))),
                    None => out.null("control"),
                };
            }
            (CommandId::ControlTake, &Args::Override(word)) => self.take_control(session, word, now, out)?,
            (CommandId::ControlRelease, _) => {
                if self.control.release(session.id()).is_none() {
                    return Err(Failure::failed(messages::NOT_IN_CONTROL));
                }
                out.null("control");
            }
            _ => {
                let ctx = context(&self.backend, &self.control, &self.auth, session, now);
                return self.backend.execute(command, &ctx, out);
            }
        }
        Ok(Step::Done)
    }

    /// `control_take [failsafe]`: takes control, even from a connected
    /// pilot; during a failsafe only with the word `failsafe`, which
    /// overrides it. In lock mode only an admin takes it from an admin.
    fn take_control(
        &mut self,
        session: &Session,
        word: bool,
        now: i64,
        out: &mut Fields<'_>,
    ) -> Result<(), Failure> {
        let from_admin = self
            .control
            .pilot()
            .is_some_and(|p| p.admin() && p.session() != session.id());
        if from_admin && self.auth.lock_mode() && !session.admin() {
            return Err(Failure::failed(messages::LOCKED));
        }
        match self.backend.failsafe() {
            Some(f) if f.holds() && !word => {
                let [source, sep, detail] = f.reason_parts();
                let parts = [
                    messages::FAILSAFE_OPEN,
                    source,
                    sep,
                    detail,
                    messages::FAILSAFE_TAKE,
                ];
                return Err(out.fail_parts(Ret::Failed, &parts));
            }
            Some(f) if f.holds() => self.backend.override_failsafe()?,
            _ => {}
        }
        self.control
            .give(session.id(), session.admin(), session.label(), now);
        if let Some(p) = self.control.pilot() {
            out.object("control", |o| p.write(o, Some(true)));
        }
        Ok(())
    }

    fn login(
        &mut self,
        session: &mut Session,
        attempt: &str,
        now: i64,
        out: &mut Fields<'_>,
        close: &mut Option<CloseCode>,
    ) -> Result<(), Failure> {
        match self.auth.login(session, attempt, now) {
            LoginOutcome::Throttled { retry_after_s } => return Err(Failure::throttled(retry_after_s)),
            LoginOutcome::Wrong { close: shut } => {
                if shut {
                    *close = Some(CloseCode::Policy);
                }
                return Err(Failure::failed(messages::WRONG_PASSWORD));
            }
            // A session that logged out can no longer fly: what it held
            // would otherwise block everyone until control_timeout.
            LoginOutcome::LoggedOut => {
                self.control.release(session.id());
            }
            LoginOutcome::User | LoginOutcome::Admin => {}
        }
        out.bool("logged_in", session.logged_in())
            .bool("admin", session.admin());
        Ok(())
    }

    fn passwd(&mut self, session: &mut Session, new: &str) -> Result<(), Failure> {
        let bad = |e| {
            let why = match e {
                AuthError::BadPassword => ArgError::BadPassword,
                AuthError::Ambiguous => ArgError::SpecialPassword,
            };
            Failure::invalid(CommandId::Passwd, why)
        };
        self.auth.check_password(new).map_err(bad)?;
        self.backend.password_changed(new)?;
        // Checked just above, against the same login values: it cannot
        // fail now.
        let _ = self.auth.set_password(new);
        self.auth.admit(session);
        Ok(())
    }
}

/// What the backend knows about a request: read once, at its time.
fn context<'c, B: Backend, S: Slots>(
    backend: &B,
    control: &'c Control,
    auth: &Auth<S>,
    session: &Session,
    now_ms: i64,
) -> Context<'c> {
    Context {
        now_ms,
        lock_mode: auth.lock_mode(),
        role: session.role(),
        session: session.id(),
        pilot: control.pilot(),
        failsafe: backend.failsafe(),
    }
}

/// Writes `answer` into `out` (or records a pending one in `session`).
fn write<'o>(
    session: &mut Session,
    answer: Answer<'_>,
    ts: i64,
    close: Option<CloseCode>,
    out: &'o mut [u8],
) -> Outcome<'o> {
    let len = match answer {
        Answer::Done(cmd, end) => response::finish(out, Ret::Ok, cmd, ts, end)
            .or_else(|| response::write_error(out, Ret::Failed, cmd, ts, &[messages::TOO_LARGE])),
        Answer::Error(ret, cmd, parts) => response::write_error(out, ret, cmd, ts, &parts),
        Answer::Failed(cmd, f, end) => match (f.is_written(), end) {
            (false, _) => {
                let len = response::write_error(out, f.ret(), cmd, ts, &[f.msg()]);
                match f.retry_after_s() {
                    Some(secs) => len.and_then(|end| response::retry_after(out, end, secs)),
                    None => len,
                }
            }
            (true, Some(end)) => response::finish(out, f.ret(), cmd, ts, end),
            // Written into some other buffer: a backend bug, not the
            // client's; say so rather than send a message that isn't there.
            (true, None) => response::write_error(out, Ret::Unhandled, cmd, ts, &[messages::UNHANDLED]),
        },
        Answer::Pending(id, ticket, takes_control) => {
            session.set_pending(Pending {
                ticket,
                id,
                takes_control,
            });
            return Outcome::Pending(ticket, out);
        }
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
