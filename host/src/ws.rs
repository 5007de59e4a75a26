//! The daemon's WebSocket layer: accepting, framing, limits and shutdown.
//!
//! Everything here is about sockets; nothing is about the protocol. Each
//! connection runs in its own task and hands every complete message to a
//! [`Handler`] as a core [`Message`], then carries out the [`Outcome`]: a
//! text reply, a close code, or both. The protocol handler
//! ([`crate::daemon::Protocol`]) and the Autobahn echo handler ([`Echo`])
//! share this code path, so what Autobahn tests is what clients get.
//!
//! Mapping from tungstenite to the core (DESIGN.md, "WebSocket behaviour"):
//! a message over the limit is [`Message::Oversized`] (the core answers
//! 1009), a binary message is [`Message::Binary`] (1003), a text message
//! whose bytes are not UTF-8 — which tungstenite reports as an error before
//! the message exists — closes with 1007, any other protocol violation with
//! 1002. Pings are answered by tungstenite on the next read.

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use futures_util::{FutureExt, SinkExt, StreamExt};
use lluav_core::{Message, Outcome};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Semaphore, watch};
use tokio::task::JoinSet;
use tokio::time::{Instant, timeout};
use tokio_tungstenite::WebSocketStream;
use tokio_tungstenite::tungstenite::handshake::server::{Callback, ErrorResponse, Request, Response};
use tokio_tungstenite::tungstenite::http::StatusCode;
use tokio_tungstenite::tungstenite::protocol::frame::CloseFrame;
use tokio_tungstenite::tungstenite::protocol::{WebSocketConfig, frame::coding::CloseCode as WsCloseCode};
use tokio_tungstenite::tungstenite::{Error as WsError, Message as WsMessage};
use tracing::{debug, info, warn};

/// What a connection does with each complete message.
pub trait Handler: Send + Sync + 'static {
    /// Per-connection state (for the protocol: the login [`lluav_core::Session`]).
    type Session: Send + 'static;

    /// State for a new connection from `peer`.
    fn session(&self, peer: SocketAddr) -> Self::Session;

    /// Handles one message; the reply may borrow from `message` or `out`.
    /// `out` holds [`Limits::response_capacity`] bytes. The answer may take
    /// a while (an autopilot's acknowledgement); other connections are
    /// served meanwhile, and this one's later messages wait their turn.
    /// Never [`Outcome::Pending`].
    fn handle<'o>(
        &'o self,
        session: &'o mut Self::Session,
        message: Message<'o>,
        out: &'o mut [u8],
    ) -> impl Future<Output = Outcome<'o>> + Send + 'o;

    /// The connection of `session` has ended.
    fn closed(&self, session: Self::Session) {
        let _ = session;
    }
}

/// Echoes every text message back unchanged and otherwise behaves like the
/// protocol's close policy (binary → 1003, oversized → 1009). Used to run the
/// Autobahn|Testsuite against this module's connection code.
#[derive(Clone, Copy, Debug, Default)]
pub struct Echo;

impl Handler for Echo {
    type Session = ();

    fn session(&self, _: SocketAddr) {}

    async fn handle<'o>(&'o self, _: &'o mut (), message: Message<'o>, _: &'o mut [u8]) -> Outcome<'o> {
        match message.text() {
            Ok(text) => Outcome::Reply(text),
            Err(code) => Outcome::Close(code),
        }
    }
}

/// Connection limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest message (and frame) accepted, in bytes; larger closes with 1009.
    pub max_message: usize,
    /// Most connections served at once; more are refused with HTTP 503.
    pub max_connections: usize,
    /// A connection that sends nothing for this long is closed.
    pub idle_timeout: Duration,
    /// Bytes of the per-connection response buffer.
    pub response_capacity: usize,
    /// Time allowed for the HTTP upgrade, and for a peer to take one reply
    /// or answer a close.
    pub io_timeout: Duration,
    /// At shutdown, time allowed for connections to finish before they are
    /// dropped.
    pub shutdown_grace: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_message: 64 * 1024,
            max_connections: 256,
            idle_timeout: Duration::from_secs(300),
            response_capacity: 64 * 1024,
            io_timeout: Duration::from_secs(10),
            shutdown_grace: Duration::from_secs(10),
        }
    }
}

/// Frames a connection answers at shutdown if they had already arrived:
/// enough for any honest pipeline, bounded so that a client streaming
/// requests cannot hold the shutdown open.
const MAX_FRAMES_AFTER_SHUTDOWN: usize = 256;

/// Bytes of replies a connection gathers before writing them to the socket
/// (it also writes whenever no further request is waiting).
const WRITE_BUFFER: usize = 64 * 1024;

/// Most replies a connection queues before it flushes even if more
/// requests are waiting, so that a fast pipeliner still gets replies
/// steadily.
const MAX_UNFLUSHED: usize = 64;

/// At shutdown, how long a connection waits for the next frame that may
/// already be on its way before it closes.
const IN_FLIGHT_WAIT: Duration = Duration::from_millis(100);

/// How long a close waits for the peer's close frame. Short, because a
/// peer that stopped reading must not hold up a shutdown for long; the
/// socket is closed either way.
const CLOSE_HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(3);

/// Refusals (HTTP 503) in progress at once; beyond it a connection over
/// the limit is dropped without an answer.
const MAX_REFUSALS: usize = 64;

/// Serves WebSocket connections on `listener` with `handler` until
/// `shutdown` completes, then stops accepting, lets every connection answer
/// the frames it already received, closes them with 1001 and returns once
/// they are gone (or [`Limits::shutdown_grace`] has passed).
pub async fn serve<H: Handler>(
    listener: TcpListener,
    handler: Arc<H>,
    limits: Limits,
    shutdown: impl Future<Output = ()>,
) {
    let (stop_tx, stop_rx) = watch::channel(false);
    let slots = Arc::new(Semaphore::new(limits.max_connections));
    let refusals = Arc::new(Semaphore::new(MAX_REFUSALS));
    let mut tasks = JoinSet::new();
    tokio::pin!(shutdown);
    loop {
        tokio::select! {
            () = &mut shutdown => break,
            Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            accepted = listener.accept() => {
                let (stream, peer) = match accepted {
                    Ok(a) => a,
                    Err(e) => {
                        // Typically EMFILE: back off instead of spinning.
                        warn!(error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                        continue;
                    }
                };
                if let Err(e) = stream.set_nodelay(true) {
                    debug!(%peer, error = %e, "TCP_NODELAY not set");
                }
                match Arc::clone(&slots).try_acquire_owned() {
                    Ok(slot) => {
                        let handler = Arc::clone(&handler);
                        let stop = stop_rx.clone();
                        tasks.spawn(async move {
                            connection(stream, peer, &*handler, limits, stop).await;
                            drop(slot);
                        });
                    }
                    Err(_) => match Arc::clone(&refusals).try_acquire_owned() {
                        Ok(permit) => {
                            tasks.spawn(async move {
                                refuse(stream, peer, limits).await;
                                drop(permit);
                            });
                        }
                        Err(_) => warn!(%peer, "connection limit reached; dropped"),
                    },
                }
            }
        }
    }
    drop(listener);
    info!(
        connections = limits.max_connections - slots.available_permits(),
        "shutting down"
    );
    let _ = stop_tx.send(true);
    let drained = timeout(limits.shutdown_grace, async {
        while tasks.join_next().await.is_some() {}
    })
    .await;
    if drained.is_err() {
        warn!(
            left = tasks.len(),
            "connections still open after the grace period; dropping them"
        );
        tasks.shutdown().await;
    }
}

/// Answers a connection over the limit with HTTP 503 instead of a hang.
async fn refuse(stream: TcpStream, peer: SocketAddr, limits: Limits) {
    warn!(%peer, max = limits.max_connections, "connection limit reached; refusing");
    let refusal = Refusal {
        max_connections: limits.max_connections,
    };
    let _ = timeout(
        limits.io_timeout,
        tokio_tungstenite::accept_hdr_async(stream, refusal),
    )
    .await;
}

/// The upgrade callback that turns every request down with 503.
struct Refusal {
    max_connections: usize,
}

impl Callback for Refusal {
    fn on_request(self, _: &Request, _: Response) -> Result<Response, ErrorResponse> {
        let mut response = ErrorResponse::new(Some(format!(
            "lluavd: connection limit ({}) reached, try again later\n",
            self.max_connections
        )));
        *response.status_mut() = StatusCode::SERVICE_UNAVAILABLE;
        Err(response)
    }
}

/// What the read loop saw next.
enum Event {
    /// A complete message, or tungstenite's verdict on one.
    Frame(Result<WsMessage, WsError>),
    /// The peer closed the TCP stream.
    Ended,
    /// Nothing arrived within the idle timeout.
    Idle,
    /// The daemon is shutting down.
    Shutdown,
}

/// One connection, from the HTTP upgrade to the closed socket, over any
/// byte stream: `serve` passes TCP streams, the fuzz targets in-memory ones.
/// `stop` turning true starts the shutdown of this connection.
pub async fn connection<S, H>(
    stream: S,
    peer: SocketAddr,
    handler: &H,
    limits: Limits,
    mut stop: watch::Receiver<bool>,
) where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    let config = WebSocketConfig::default()
        .max_message_size(Some(limits.max_message))
        .max_frame_size(Some(limits.max_message))
        .read_buffer_size(16 * 1024)
        .write_buffer_size(WRITE_BUFFER);
    let accepted = timeout(
        limits.io_timeout,
        tokio_tungstenite::accept_async_with_config(stream, Some(config)),
    )
    .await;
    let mut ws = match accepted {
        Ok(Ok(ws)) => ws,
        Ok(Err(e)) => {
            debug!(%peer, error = %e, "WebSocket handshake failed");
            return;
        }
        Err(_) => {
            debug!(%peer, "WebSocket handshake timed out");
            return;
        }
    };
    debug!(%peer, "connected");
    let mut session = handler.session(peer);
    let mut out = vec![0u8; limits.response_capacity];
    // Replies written but not yet flushed: a pipelining client gets them in
    // one write, a client waiting for its reply gets it before we wait.
    let mut unflushed = 0;
    // One idle timer and one shutdown wait for the whole connection: made
    // afresh for every frame, they cost a timer-wheel registration and a
    // watch registration per request. The timer is re-armed only when it
    // fires, from the time of the last frame.
    let idle = tokio::time::sleep(limits.idle_timeout);
    tokio::pin!(idle);
    let mut last_frame = Instant::now();
    let stopping = stop.wait_for(|stopping| *stopping);
    tokio::pin!(stopping);
    loop {
        let ready = if unflushed > 0 && unflushed < MAX_UNFLUSHED {
            ws.next().now_or_never()
        } else {
            None
        };
        let event = match ready {
            Some(Some(frame)) => Event::Frame(frame),
            Some(None) => Event::Ended,
            None => {
                if unflushed > 0 {
                    unflushed = 0;
                    if !matches!(timeout(limits.io_timeout, ws.flush()).await, Ok(Ok(()))) {
                        debug!(%peer, "replies not flushed; dropping the connection");
                        break;
                    }
                }
                loop {
                    tokio::select! {
                        biased;
                        _ = &mut stopping => break Event::Shutdown,
                        next = ws.next() => break match next {
                            Some(frame) => Event::Frame(frame),
                            None => Event::Ended,
                        },
                        () = &mut idle => {
                            let deadline = last_frame + limits.idle_timeout;
                            if Instant::now() >= deadline {
                                break Event::Idle;
                            }
                            idle.as_mut().reset(deadline);
                        }
                    }
                }
            }
        };
        if matches!(event, Event::Frame(_)) {
            last_frame = Instant::now();
        }
        let verdict = match event {
            Event::Frame(frame) => {
                on_frame(
                    &mut ws,
                    handler,
                    &mut session,
                    &mut out,
                    frame,
                    limits,
                    &mut unflushed,
                )
                .await
            }
            Event::Ended => Flow::Done,
            Event::Idle => {
                debug!(%peer, "idle timeout");
                Flow::Close(WsCloseCode::Normal, "idle timeout")
            }
            Event::Shutdown => {
                let mut verdict = Flow::Close(WsCloseCode::Away, "lluavd is shutting down");
                // Answer what had already arrived; the sender is still
                // waiting for those replies. The short wait lets the reactor
                // report bytes already in the socket buffer.
                for _ in 0..MAX_FRAMES_AFTER_SHUTDOWN {
                    let Ok(Some(frame)) = timeout(IN_FLIGHT_WAIT, ws.next()).await else {
                        break;
                    };
                    match on_frame(
                        &mut ws,
                        handler,
                        &mut session,
                        &mut out,
                        frame,
                        limits,
                        &mut unflushed,
                    )
                    .await
                    {
                        Flow::Continue => {}
                        other => {
                            verdict = other;
                            break;
                        }
                    }
                }
                verdict
            }
        };
        match verdict {
            Flow::Continue => {}
            Flow::Done => break,
            Flow::Close(code, reason) => {
                // Closes other than normal ones say something about a client
                // (a broken one, or a password guesser): worth a log line.
                match code {
                    WsCloseCode::Normal | WsCloseCode::Away => debug!(%peer, %code, "closing"),
                    _ => info!(%peer, %code, "closing"),
                }
                close(&mut ws, code, reason).await;
                break;
            }
        }
    }
    handler.closed(session);
    debug!(%peer, "disconnected");
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

async fn on_frame<S: AsyncRead + AsyncWrite + Unpin, H: Handler>(
    ws: &mut WebSocketStream<S>,
    handler: &H,
    session: &mut H::Session,
    out: &mut [u8],
    frame: Result<WsMessage, WsError>,
    limits: Limits,
    unflushed: &mut usize,
) -> Flow {
    let outcome = match &frame {
        Ok(WsMessage::Text(text)) => handler.handle(session, Message::Text(text.as_bytes()), out).await,
        Ok(WsMessage::Binary(bytes)) => handler.handle(session, Message::Binary(bytes), out).await,
        // tungstenite queued the pong (or the close reply) and sends it on
        // the next read; a close from the peer ends the stream right after.
        Ok(WsMessage::Ping(_) | WsMessage::Pong(_) | WsMessage::Close(_) | WsMessage::Frame(_)) => {
            return Flow::Continue;
        }
        Err(WsError::Capacity(_)) => handler.handle(session, Message::Oversized, out).await,
        Err(WsError::Utf8(_)) => return Flow::Close(WsCloseCode::Invalid, ""),
        Err(WsError::Protocol(e)) => {
            debug!(error = %e, "WebSocket protocol violation");
            return Flow::Close(WsCloseCode::Protocol, "");
        }
        Err(e) => {
            debug!(error = %e, "connection lost");
            return Flow::Done;
        }
    };
    let (reply, code) = (outcome.reply(), outcome.close_code());
    if let Outcome::Pending(ticket, _) = outcome {
        // A handler must wait for its backend; this one broke that promise.
        warn!(?ticket, "handler answered Pending; closing");
        return Flow::Close(WsCloseCode::Error, "");
    }
    if let Some(text) = reply {
        // Queued, not flushed: the connection loop flushes once no further
        // request is already waiting, and a close flushes first.
        let sent = timeout(limits.io_timeout, ws.feed(WsMessage::text(text))).await;
        match sent {
            Ok(Ok(())) => *unflushed += 1,
            Ok(Err(e)) => {
                debug!(error = %e, "reply not sent");
                return Flow::Done;
            }
            Err(_) => {
                debug!("peer does not take replies; dropping it");
                return Flow::Done;
            }
        }
    }
    match code {
        Some(code) => Flow::Close(WsCloseCode::from(code.code()), ""),
        None => Flow::Continue,
    }
}

/// Sends a close frame and waits (bounded) for the peer's, so the close
/// handshake completes; anything the peer sends meanwhile is discarded.
async fn close<S: AsyncRead + AsyncWrite + Unpin>(
    ws: &mut WebSocketStream<S>,
    code: WsCloseCode,
    reason: &'static str,
) {
    let frame = CloseFrame {
        code,
        reason: reason.into(),
    };
    let handshake = async {
        if ws.close(Some(frame)).await.is_err() {
            return;
        }
        while let Some(Ok(_)) = ws.next().await {}
    };
    let _ = timeout(CLOSE_HANDSHAKE_TIMEOUT, handshake).await;
}
