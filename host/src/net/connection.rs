//! One WebSocket session after its `101`: messages in, the handler's
//! outcomes out, in order, until a close.
//!
//! Mapping from tungstenite to the core (DESIGN.md, "WebSocket
//! behaviour"): a message over the limit is [`Message::Oversized`], a
//! binary message [`Message::Binary`], and the core's close policy decides
//! (1009, 1003). A text message whose bytes are not UTF-8 — which
//! tungstenite reports as an error before the message exists — closes with
//! 1007, any other protocol violation with 1002. Pings are answered by
//! tungstenite on the next read.

use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;

use futures_util::{FutureExt, SinkExt, StreamExt};
use lluav_core::{CloseCode, Message, Outcome};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{Notify, watch};
use tokio::time::{Instant, Sleep, timeout};
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::protocol::frame::CloseFrame;
use tokio_tungstenite::tungstenite::protocol::frame::coding::CloseCode as WsCloseCode;
use tokio_tungstenite::tungstenite::{Error as WsError, Message as WsMessage};
use tracing::{debug, warn};

use super::report::{Offence, Reports};
use super::slots::Held;
use super::{Handler, LINGER, Limits};

/// Frames a connection answers at shutdown if they had already arrived:
/// enough for any honest pipeline, bounded so that a client streaming
/// requests cannot hold the shutdown open.
const MAX_FRAMES_AFTER_SHUTDOWN: usize = 256;

/// Most replies a connection queues before it flushes even if more
/// requests are waiting, so that a fast pipeliner still gets replies
/// steadily.
const MAX_UNFLUSHED: usize = 64;

/// At shutdown, how long a connection waits for the next frame that may
/// already be on its way before it closes.
const IN_FLIGHT_WAIT: std::time::Duration = std::time::Duration::from_millis(100);

/// How long a close waits for the peer's close frame. Short, because a
/// peer that stopped reading must not hold up a shutdown for long; the
/// socket is closed either way.
const CLOSE_HANDSHAKE_TIMEOUT: std::time::Duration = std::time::Duration::from_secs(3);

/// What ends a session from outside.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum End {
    /// The daemon is shutting down.
    Shutdown,
    /// The slot was reclaimed for a newcomer (the session had not logged in).
    Reclaimed,
}

/// What the read loop saw next.
enum Event {
    /// A complete message, or tungstenite's verdict on one.
    Frame(Result<WsMessage, WsError>),
    /// The peer closed the TCP stream, or replies could not be flushed.
    Ended,
    /// Nothing arrived within the idle timeout.
    Idle,
    /// A password is configured and the session did not log in in time.
    LoginTimeout,
    /// Ended from outside.
    End(End),
}

/// What the connection does after a frame.
enum Flow {
    /// Read the next message.
    Continue,
    /// The connection is over; nothing more to send.
    Done,
    /// Close with this code and reason, then stop.
    Close(WsCloseCode, &'static str),
}

/// The one timer of a session: the idle timeout, and the login deadline
/// until the session is admitted. Made once: a timer made afresh for every
/// frame costs a timer-wheel registration per request. It is re-armed only
/// when it fires.
struct Timer {
    sleep: Pin<Box<Sleep>>,
    last_frame: Instant,
    login_deadline: Option<Instant>,
}

impl Timer {
    /// What the timer firing means now, or `None` after re-arming it.
    fn fired(&mut self, limits: &Limits) -> Option<Event> {
        let now = Instant::now();
        if self.login_deadline.is_some_and(|d| now >= d) {
            return Some(Event::LoginTimeout);
        }
        let idle = self.last_frame + limits.idle_timeout;
        if now >= idle {
            return Some(Event::Idle);
        }
        let next = self.login_deadline.map_or(idle, |d| d.min(idle));
        self.sleep.as_mut().reset(next);
        None
    }
}

/// A session: the WebSocket, the handler's per-connection state and the
/// reply buffer.
pub struct Connection<'h, S, H: Handler> {
    ws: WebSocketStream<S>,
    handler: &'h H,
    session: H::Session,
    out: Vec<u8>,
    /// Replies written but not yet flushed: a pipelining client gets them
    /// in one write, a client waiting for its reply gets it before we wait.
    unflushed: usize,
    limits: Limits,
    peer: SocketAddr,
    slot: Option<Held>,
    admitted: bool,
    reports: &'h Reports,
}

impl<'h, S, H> Connection<'h, S, H>
where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    /// A session for `peer` over `ws`, holding `slot` (if it was counted).
    pub fn new(
        ws: WebSocketStream<S>,
        handler: &'h H,
        peer: SocketAddr,
        limits: Limits,
        slot: Option<Held>,
        reports: &'h Reports,
    ) -> Self {
        let session = handler.session(peer);
        Connection {
            ws,
            handler,
            session,
            out: vec![0u8; limits.response_capacity],
            unflushed: 0,
            limits,
            peer,
            slot,
            admitted: false,
            reports,
        }
    }

    /// Serves the session until it ends: the peer closes, a close code, an
    /// idle or login timeout, reclaiming, or `stop` turning true (shutdown:
    /// answer what already arrived, then close with 1001).
    pub async fn run(mut self, mut stop: watch::Receiver<bool>) {
        let cancel = self
            .slot
            .as_ref()
            .map_or_else(|| Arc::new(Notify::new()), |s| Arc::clone(&s.cancel));
        let ended = async move {
            tokio::select! {
                _ = stop.wait_for(|stopping| *stopping) => End::Shutdown,
                () = cancel.notified() => End::Reclaimed,
            }
        };
        tokio::pin!(ended);
        self.check_admitted();
        let start = Instant::now();
        let mut timer = Timer {
            sleep: Box::pin(tokio::time::sleep(
                self.limits.idle_timeout.min(self.limits.login_timeout),
            )),
            last_frame: start,
            login_deadline: (!self.admitted).then(|| start + self.limits.login_timeout),
        };
        debug!(peer = %self.peer, "connected");
        loop {
            let event = self.next_event(ended.as_mut(), &mut timer).await;
            let flow = match event {
                Event::Frame(frame) => {
                    timer.last_frame = Instant::now();
                    let flow = self.frame(frame).await;
                    if self.check_admitted() {
                        timer.login_deadline = None;
                    }
                    flow
                }
                Event::Ended => Flow::Done,
                Event::Idle => Flow::Close(WsCloseCode::Normal, "idle timeout"),
                Event::LoginTimeout => {
                    self.reports.note(self.peer.ip(), Offence::LoginTimeout);
                    Flow::Close(WsCloseCode::Policy, "no login in time")
                }
                Event::End(End::Reclaimed) => {
                    Flow::Close(WsCloseCode::Policy, "not logged in; slot reclaimed")
                }
                Event::End(End::Shutdown) => self.drain().await,
            };
            match flow {
                Flow::Continue => {}
                Flow::Done => break,
                Flow::Close(code, reason) => {
                    self.close(code, reason).await;
                    break;
                }
            }
        }
        debug!(peer = %self.peer, "disconnected");
        self.handler.closed(self.session);
    }

    /// Whether the session has been admitted (logged in, or no login
    /// needed); marks its slot once it is, so it is never reclaimed.
    /// Returns true when this call admitted it.
    fn check_admitted(&mut self) -> bool {
        if self.admitted || !self.handler.admitted(&self.session) {
            return false;
        }
        self.admitted = true;
        if let Some(slot) = &self.slot {
            slot.admit();
        }
        true
    }

    async fn next_event(
        &mut self,
        mut ended: Pin<&mut impl Future<Output = End>>,
        timer: &mut Timer,
    ) -> Event {
        if self.unflushed > 0 && self.unflushed < MAX_UNFLUSHED {
            match self.ws.next().now_or_never() {
                Some(Some(frame)) => return Event::Frame(frame),
                Some(None) => return Event::Ended,
                None => {}
            }
        }
        if !self.flush().await {
            return Event::Ended;
        }
        loop {
            tokio::select! {
                biased;
                end = &mut ended => return Event::End(end),
                next = self.ws.next() => return next.map_or(Event::Ended, Event::Frame),
                () = &mut timer.sleep => {
                    if let Some(event) = timer.fired(&self.limits) {
                        return event;
                    }
                }
            }
        }
    }

    /// Writes the replies queued so far; false if the peer does not take
    /// them (the connection is then dropped).
    async fn flush(&mut self) -> bool {
        if self.unflushed == 0 {
            return true;
        }
        self.unflushed = 0;
        let flushed = matches!(timeout(self.limits.io_timeout, self.ws.flush()).await, Ok(Ok(())));
        if !flushed {
            debug!(peer = %self.peer, "replies not flushed; dropping the connection");
        }
        flushed
    }

    /// Handles one frame: the message to the handler, its reply queued.
    async fn frame(&mut self, frame: Result<WsMessage, WsError>) -> Flow {
        let message = match &frame {
            Ok(WsMessage::Text(text)) => Message::Text(text.as_bytes()),
            Ok(WsMessage::Binary(bytes)) => Message::Binary(bytes),
            // tungstenite queued the pong (or the close reply) and sends it
            // on the next read; a close from the peer ends the stream after.
            Ok(WsMessage::Ping(_) | WsMessage::Pong(_) | WsMessage::Close(_) | WsMessage::Frame(_)) => {
                return Flow::Continue;
            }
            Err(WsError::Capacity(_)) => Message::Oversized,
            Err(WsError::Utf8(_)) => return Flow::Close(ws_code(CloseCode::InvalidPayload), ""),
            Err(WsError::Protocol(e)) => {
                debug!(peer = %self.peer, error = %e, "WebSocket protocol violation");
                return Flow::Close(ws_code(CloseCode::ProtocolError), "");
            }
            Err(e) => {
                debug!(peer = %self.peer, error = %e, "connection lost");
                return Flow::Done;
            }
        };
        let outcome = self
            .handler
            .handle(&mut self.session, message, &mut self.out)
            .await;
        let (reply, code) = (outcome.reply(), outcome.close_code());
        if let Outcome::Pending(ticket, _) = outcome {
            // A handler must wait for its backend; this one broke that promise.
            warn!(peer = %self.peer, ?ticket, "handler answered Pending; closing");
            return Flow::Close(ws_code(CloseCode::InternalError), "");
        }
        if let Some(text) = reply {
            // Queued, not flushed: the read loop flushes once no further
            // request is already waiting, and a close flushes first.
            match timeout(self.limits.io_timeout, self.ws.feed(WsMessage::text(text))).await {
                Ok(Ok(())) => self.unflushed += 1,
                Ok(Err(e)) => {
                    debug!(peer = %self.peer, error = %e, "reply not sent");
                    return Flow::Done;
                }
                Err(_) => {
                    debug!(peer = %self.peer, "peer does not take replies; dropping it");
                    return Flow::Done;
                }
            }
        }
        if code == Some(CloseCode::Policy) {
            self.reports.note(self.peer.ip(), Offence::WrongPasswords);
        }
        code.map_or(Flow::Continue, |code| Flow::Close(ws_code(code), ""))
    }

    /// At shutdown: answers the frames that had already arrived (their
    /// senders are waiting for the replies), then closes with 1001. The
    /// short wait lets the reactor report bytes already in the socket.
    async fn drain(&mut self) -> Flow {
        for _ in 0..MAX_FRAMES_AFTER_SHUTDOWN {
            let Ok(Some(frame)) = timeout(IN_FLIGHT_WAIT, self.ws.next()).await else {
                break;
            };
            match self.frame(frame).await {
                Flow::Continue => {}
                other => return other,
            }
        }
        Flow::Close(WsCloseCode::Away, "lluavd is shutting down")
    }

    /// Flushes, sends a close frame and waits (bounded) for the peer's, so
    /// the close handshake completes; what the peer sends meanwhile is
    /// discarded.
    async fn close(&mut self, code: WsCloseCode, reason: &'static str) {
        // Offenders are reported (once a minute) where the offence is
        // seen; a line per close would let a client flood the log.
        debug!(peer = %self.peer, %code, reason, "closing");
        let frame = CloseFrame {
            code,
            reason: reason.into(),
        };
        let ws = &mut self.ws;
        let handshake = async {
            if ws.close(Some(frame)).await.is_err() {
                return;
            }
            while let Some(Ok(_)) = ws.next().await {}
        };
        let _ = timeout(CLOSE_HANDSHAKE_TIMEOUT, handshake).await;
        // A peer still sending (the rest of an oversized message) would get
        // a reset instead of the close frame if the socket closed with its
        // bytes unread: end our side, then read on briefly.
        let stream = self.ws.get_mut();
        let _ = timeout(LINGER, async {
            let _ = stream.shutdown().await;
            // On the heap: an array here would make every session's task
            // this much larger for its whole life.
            let mut sink = vec![0u8; 4096];
            while let Ok(1..) = stream.read(&mut sink).await {}
        })
        .await;
    }
}

fn ws_code(code: CloseCode) -> WsCloseCode {
    WsCloseCode::from(code.code())
}
