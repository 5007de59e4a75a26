//! The `/events` endpoint (DESIGN.md, "Events"): after its `101`, a
//! session that only listens. With a password its first message must be
//! `login <password>`, answered by the handler exactly as the command
//! socket answers it (a wrong one counts as one); from then on the server
//! only sends: each event as a text message, or a `gap` when this
//! subscriber fell behind. Any other client message closes with 1008.
//! Silence is no reason to close a subscriber: the server pings it every
//! [`PING_EVERY`] and drops it when a ping goes unanswered that long.
//!
//! The same Origin/Host policy, limits and TLS as every session (the
//! listener admits it like one); it takes a session slot.

use std::net::SocketAddr;
use std::time::Duration;

use lluav_core::websocket::{Opcode, close_reply};
use lluav_core::{CloseCode, Message};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{Notify, watch};
use tokio::time::{Instant, sleep_until, timeout};
use tracing::debug;

use super::connection::Context;
use super::frame;
use super::reader::{Event as Received, Reader};
use super::slots::Held;
use super::{Handler, LINGER, Limits, wire};
use crate::events::{Next, Subscriber, gap, now_ms};

/// How often a subscriber is pinged, and how long it has to answer.
pub const PING_EVERY: Duration = Duration::from_secs(10);

/// How long the close handshake waits for the peer's close frame.
const CLOSE_WAIT: Duration = Duration::from_secs(3);

/// The kernel's send buffer of a subscriber's socket, bytes: a couple of
/// hundred events. Linux would grow it to megabytes — tens of thousands of
/// stale events held for a subscriber that stopped reading — where the
/// queue of [`crate::events::QUEUE`] events and a `gap` are the promise.
const SEND_BUFFER: usize = 32 * 1024;

/// Keeps a subscriber's kernel send buffer small (32 KiB: a couple of
/// hundred events, so that the events queue and its `gap` are what a
/// subscriber that stops reading meets); a socket that refuses keeps its
/// own. `fd` must be the open socket of the
/// connection being served (the listener passes its TCP stream's).
pub fn small_send_buffer(fd: std::os::fd::RawFd) {
    // SAFETY: `fd` is the descriptor of the TCP stream the caller's
    // connection owns, open for the whole call; it is only borrowed here.
    let fd = unsafe { std::os::fd::BorrowedFd::borrow_raw(fd) };
    if let Err(e) = nix::sys::socket::setsockopt(&fd, nix::sys::socket::sockopt::SndBuf, &SEND_BUFFER) {
        debug!(error = %e, "subscriber's send buffer left as it was");
    }
}

/// Whether the request target names the events endpoint (`/events`, with
/// or without a query).
pub fn is_events(target: &str) -> bool {
    target.split(['?', '#']).next() == Some("/events")
}

/// What ends a subscriber's loop.
enum Stop {
    /// Close with this code.
    Close(CloseCode, &'static str),
    /// The peer closed: answer its close with this code.
    Answer(u16),
    /// The connection is gone (TCP closed, a write timed out, a ping went
    /// unanswered): nothing more to send.
    Gone,
}

/// Serves one `/events` subscriber until it ends; `early`: its place on
/// the bus, taken before its `101` (none: taken once it is admitted).
pub async fn serve<S, H>(
    stream: S,
    leftover: Vec<u8>,
    peer: SocketAddr,
    slot: Held,
    cx: Context<'_, H>,
    mut stop: watch::Receiver<bool>,
    early: Option<Subscriber>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    let mut s = Stream {
        stream,
        reader: Reader::new(leftover, cx.limits.max_message),
        outbox: Vec::new(),
        limits: cx.limits,
        early,
    };
    let mut session = cx.handler.session(peer);
    let cancel = std::sync::Arc::clone(&slot.cancel);
    let ended = serve_session(&mut s, &mut session, &slot, &cancel, cx.handler, &mut stop, peer).await;
    match ended {
        Stop::Close(code, reason) => {
            debug!(%peer, code = code.code(), reason, "closing subscriber");
            let mut payload = code.code().to_be_bytes().to_vec();
            payload.extend_from_slice(reason.as_bytes());
            frame::write(&mut s.outbox, Opcode::Close, &payload);
            let _ = timeout(CLOSE_WAIT, async {
                if s.flush().await {
                    s.reader.discard();
                    while let Some(event) = s.receive().await {
                        if matches!(event, Received::Control(Opcode::Close) | Received::Fail(_)) {
                            break;
                        }
                    }
                }
            })
            .await;
        }
        Stop::Answer(code) => {
            frame::write(&mut s.outbox, Opcode::Close, &code.to_be_bytes());
            let _ = timeout(CLOSE_WAIT, s.flush()).await;
        }
        Stop::Gone => {}
    }
    let _ = timeout(LINGER, s.stream.shutdown()).await;
    cx.handler.closed(session);
    drop(slot);
}

/// The subscriber's socket.
struct Stream<S> {
    stream: S,
    reader: Reader,
    outbox: Vec<u8>,
    limits: Limits,
    /// The place on the bus taken before the `101` (without a password)
    /// or before a login's answer, until the loop takes it.
    early: Option<Subscriber>,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Stream<S> {
    async fn flush(&mut self) -> bool {
        self.outbox.is_empty()
            || wire::write(&mut self.stream, &mut self.outbox, self.limits.io_timeout).await
    }

    async fn read(&mut self) -> std::io::Result<usize> {
        let Stream { stream, reader, .. } = self;
        stream.read_buf(reader.buffer()).await
    }

    /// The next event of the frames received, reading as needed; `None`
    /// when the stream ends.
    async fn receive(&mut self) -> Option<Received> {
        loop {
            if let Some(event) = self.reader.next_event() {
                return Some(event);
            }
            if !matches!(self.read().await, Ok(1..)) {
                return None;
            }
        }
    }

    async fn send_text(&mut self, text: &str) -> bool {
        frame::write(&mut self.outbox, Opcode::Text, text.as_bytes());
        self.flush().await
    }
}

/// The login phase, then the events, until something ends the session.
async fn serve_session<S, H>(
    s: &mut Stream<S>,
    session: &mut H::Session,
    slot: &Held,
    cancel: &Notify,
    handler: &H,
    stop: &mut watch::Receiver<bool>,
    peer: SocketAddr,
) -> Stop
where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    let login_deadline = Instant::now() + s.limits.login_timeout;
    let mut events: Option<Subscriber> = None;
    let mut out = vec![0u8; s.limits.response_capacity];
    let mut next_ping = Instant::now() + PING_EVERY;
    let mut ping_sent: Option<Instant> = None;
    loop {
        if events.is_none() && handler.admitted(session) {
            let Some(sub) = s.early.take().or_else(|| handler.subscribe()) else {
                return Stop::Close(CloseCode::InternalError, "no events here");
            };
            slot.admit();
            events = Some(sub);
        } else if events.is_none() {
            // Not admitted yet: what happens before its login is not its.
            s.early = None;
        }
        let subscribed = events.is_some();
        let ping_due = ping_sent.map_or(next_ping, |sent| sent + PING_EVERY);
        let deadline = if subscribed {
            ping_due
        } else {
            login_deadline.min(ping_due)
        };
        tokio::select! {
            biased;
            () = async {
                // Only whether: the guard it returns must not live on.
                let _ = stop.wait_for(|stopping| *stopping).await;
            } => {
                return Stop::Close(CloseCode::GoingAway, "lluavd is shutting down");
            }
            () = cancel.notified() => return Stop::Close(CloseCode::Policy, "not logged in; slot reclaimed"),
            received = s.receive() => {
                let Some(received) = received else { return Stop::Gone };
                if let Some(stop) = on_received(s, received, subscribed, &mut ping_sent, session, handler, &mut out).await {
                    return stop;
                }
            }
            next = async {
                match events.as_mut() {
                    Some(sub) => sub.next().await,
                    None => std::future::pending().await,
                }
            } => {
                let text = match next {
                    Next::Event(e) => e.json.to_string(),
                    Next::Gap(missed) => gap(missed, now_ms()),
                    Next::Closed => return Stop::Close(CloseCode::GoingAway, "lluavd is shutting down"),
                };
                if !s.send_text(&text).await {
                    debug!(%peer, "subscriber does not take events; dropping it");
                    return Stop::Gone;
                }
            }
            () = sleep_until(deadline) => {
                let now = Instant::now();
                if !subscribed && now >= login_deadline {
                    return Stop::Close(CloseCode::Policy, "no login in time");
                }
                if let Some(stop) = ping(s, &mut ping_sent, peer).await {
                    return stop;
                }
                next_ping = now + PING_EVERY;
            }
        }
    }
}

/// What a frame from the subscriber does: pings answered, its pong noted,
/// a close answered; a message is a login before it is admitted and ends
/// the session after. `Some` ends the session.
async fn on_received<S, H>(
    s: &mut Stream<S>,
    received: Received,
    subscribed: bool,
    ping_sent: &mut Option<Instant>,
    session: &mut H::Session,
    handler: &H,
    out: &mut [u8],
) -> Option<Stop>
where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    match received {
        Received::Control(Opcode::Ping) => {
            let payload = s.reader.control().to_vec();
            frame::write(&mut s.outbox, Opcode::Pong, &payload);
            (!s.flush().await).then_some(Stop::Gone)
        }
        Received::Control(Opcode::Pong) => {
            *ping_sent = None;
            None
        }
        Received::Control(Opcode::Close) => Some(Stop::Answer(close_reply(s.reader.control()))),
        Received::Control(_) => None,
        Received::Fail(code) => Some(Stop::Close(code, "")),
        Received::Oversized => Some(Stop::Close(CloseCode::TooBig, "")),
        Received::InvalidText => Some(Stop::Close(CloseCode::InvalidPayload, "")),
        Received::Message if subscribed => {
            Some(Stop::Close(CloseCode::Policy, "the events endpoint only sends"))
        }
        Received::Message => login(s, session, handler, out).await,
    }
}

/// Pings the subscriber, unless the last ping went unanswered (then the
/// subscriber is gone). `Some` ends the session.
async fn ping<S>(s: &mut Stream<S>, ping_sent: &mut Option<Instant>, peer: SocketAddr) -> Option<Stop>
where
    S: AsyncRead + AsyncWrite + Unpin,
{
    if ping_sent.is_some() {
        debug!(%peer, "subscriber did not answer a ping; dropping it");
        return Some(Stop::Gone);
    }
    frame::write(&mut s.outbox, Opcode::Ping, b"");
    if !s.flush().await {
        return Some(Stop::Gone);
    }
    *ping_sent = Some(Instant::now());
    None
}

/// A message before the subscriber is admitted: a `login`, answered as the
/// command socket answers it; anything else ends the session.
async fn login<S, H>(s: &mut Stream<S>, session: &mut H::Session, handler: &H, out: &mut [u8]) -> Option<Stop>
where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    let message = s.reader.message();
    let is_login = matches!(message, Message::Text(t) if t.split(|&b| b == b' ').next() == Some(b"login"));
    if !is_login {
        return Some(Stop::Close(CloseCode::Policy, "log in first: login <password>"));
    }
    let outcome = handler.handle(session, message, out).await;
    let (reply, code) = (outcome.reply().map(str::to_owned), outcome.close_code());
    // On the bus before the login's answer: all that follows it is told.
    if handler.admitted(session) {
        s.early = handler.subscribe();
    }
    if let Some(text) = reply
        && !s.send_text(&text).await
    {
        return Some(Stop::Gone);
    }
    code.map(|code| Stop::Close(code, ""))
}
