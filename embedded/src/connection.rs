//! One WebSocket connection over a [`Transport`]: the upgrade, then frames
//! in and replies out, every rule of DESIGN.md's "WebSocket behaviour".
//!
//! Binary messages, invalid UTF-8 and oversized messages are handed to the
//! service as such (the protocol answers 1003, 1007, 1009); invalid UTF-8
//! is detected while the message arrives, and handed over at once (the
//! rest of the message is never read). Pings are answered with pongs,
//! fragmented messages are reassembled in the message buffer, a close
//! frame is answered with a close frame, protocol violations fail the
//! connection with 1002. Nothing a peer sends can make this code panic.
//!
//! # Where the bytes go
//!
//! A connection owns one buffer, the message buffer (its size is the frame
//! limit; it first holds the upgrade request's head), and about 260 bytes
//! of state (a 14-byte carry for a frame header cut by the end of the
//! received bytes, 125 bytes for a control frame's payload,
//! embedded-websocket's 16-byte server state). Everything else is the
//! socket's:
//!
//! - **In**: frame headers are parsed and payloads unmasked straight out of
//!   the socket's receive buffer ([`Transport::read_with`]) into the message
//!   buffer, the one copy a message takes. The message cannot be handed to
//!   the core where it lies: embassy-net shows only the contiguous part of
//!   its receive ring (a frame that wraps around the ring's end is in two
//!   pieces), it wakes a reader only when that ring goes from empty to
//!   non-empty (so bytes left unconsumed to wait for the rest of a frame
//!   could only be polled for), and a fragmented message is interleaved
//!   with headers and control frames. The receive buffer therefore only
//!   needs to be as large as the TCP window one wants, not the frame limit.
//! - **Out**: the core writes its reply straight into the socket's transmit
//!   buffer ([`Transport::write_with`]), behind room for the frame header.
//!   Before taking the service's lock the connection waits until the
//!   transmit buffer's free run holds a whole reply (`reply` bytes plus
//!   header), so the core always gets exactly `reply` bytes: a reply that
//!   does not fit is the core's `Response too large`, at the same size
//!   whatever the socket's state, and the write under the lock never
//!   waits. If the free run is too short (earlier replies not yet
//!   acknowledged near the ring's end), the connection waits until the
//!   peer has acknowledged everything, when the run is the whole buffer.
//!   The message stays in the message buffer meanwhile, so the receive and
//!   transmit buffers are never needed at once (embassy-net's stack can lend
//!   only one of them at a time). The text frame's header is ours;
//!   the `101` answer, pongs and close frames are written by
//!   embedded-websocket, straight into a contiguous run of the transmit
//!   buffer too (`send.rs` says why the split, and what it never sees).

use embassy_time::{Duration, Instant, with_deadline, with_timeout};
use lluav_core::websocket::handshake::{self, KEY_LEN, Request, Upgrade};
use lluav_core::websocket::policy::Policy;
use lluav_core::websocket::{Opcode, close_reply, header_len};
use lluav_core::{CloseCode, MIN_RESPONSE_CAPACITY};

use crate::error::{Error, Rejection};
use crate::log::debug;
use crate::receive::{Event, Reader};
#[cfg(feature = "streamed-echo")]
use crate::send::write_text;
use crate::send::{Outgoing, Sender, Sent, write_reply};
use crate::service::{Handler, Service};
use crate::transport::{self, Transport};

/// The smallest message buffer: it must hold an upgrade request's head.
pub const MIN_MESSAGE: usize = 256;

/// A connection's limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// The reply capacity the core gets (at least
    /// [`MIN_RESPONSE_CAPACITY`]); the transport's transmit buffer must
    /// hold this plus the frame header ([`header_len`]).
    pub reply: usize,
    /// Close the connection when nothing arrives for this long.
    pub idle: Option<Duration>,
    /// How long the last close frame may take to be queued.
    pub close: Duration,
}

/// One WebSocket connection: [`Connection::accept`] the upgrade, then
/// [`Connection::run`] until it closes.
pub struct Connection<'b> {
    reader: Reader<'b>,
    sender: Sender,
    limits: Limits,
    /// Until when the session may stay without logging in.
    login: Option<Instant>,
}

impl<'b> Connection<'b> {
    /// A connection gathering messages in `message` (its size is the frame limit).
    pub fn new(message: &'b mut [u8], limits: Limits) -> Self {
        Connection {
            reader: Reader::new(message),
            sender: Sender::new(),
            limits,
            login: None,
        }
    }

    /// Closes the session with 1008 at `deadline` unless it has logged in
    /// by then; messages and pings do not move the deadline.
    pub fn set_login_deadline(&mut self, deadline: Option<Instant>) {
        self.login = deadline;
    }

    /// Reads the upgrade request, has the core judge it against `policy`
    /// (the address the connection arrived on and the allow-lists), asks
    /// `admit` (e.g. a per-address limit), and answers it: `101` on
    /// success, the rejection's status (and an error) otherwise.
    pub async fn accept<T: Transport>(
        &mut self,
        io: &mut T,
        policy: &Policy<'_>,
        admit: impl FnOnce(&Upgrade<'_>) -> bool,
    ) -> Result<(), Error<T::Error>> {
        let reply = self.limits.reply;
        if self.reader.capacity() < MIN_MESSAGE
            || reply < MIN_RESPONSE_CAPACITY
            || io.send_capacity() < header_len(reply) + reply
        {
            return Err(Error::Buffers);
        }
        let verdict = loop {
            let reader = &mut self.reader;
            let mut head = None;
            let got = transport::read(io, &mut |w| {
                let (n, decided) = reader.head(w);
                head = decided;
                n
            })
            .await;
            match (transport::received(io, got)?, head) {
                (None, _) => return Err(Error::Rejected(Rejection::Incomplete)),
                (_, None) => {}
                (_, Some(Ok(_))) => break check(self.reader.request(), policy, admit),
                (_, Some(Err(why))) => break Err(why.into()),
            }
        };
        let sent = match verdict {
            Ok(key) => self.sender.send(io, Outgoing::Switch(key)).await,
            Err(why) => match self.sender.send(io, Outgoing::Refusal(why)).await {
                Ok(()) => Err(io.flush().await.map_or_else(Error::Io, |()| Error::Rejected(why))),
                Err(e) => Err(e),
            },
        };
        self.reader.start_frames();
        sent
    }

    /// Serves messages of `session` until the connection closes; `admitted`
    /// hears after each message whether the session may run commands.
    /// `Ok(code)` is the close code of the close frame we sent (our own,
    /// or the answer to the peer's); the caller then closes the stream.
    pub async fn run<T: Transport, S: Service>(
        &mut self,
        io: &mut T,
        service: &S,
        session: &mut S::Session,
        mut admitted: impl FnMut(bool),
    ) -> Result<u16, Error<T::Error>> {
        loop {
            let event = match self.next_event(io).await {
                Err(Error::LoginTimeout) => {
                    let close = Outgoing::Close(CloseCode::Policy.code());
                    let _ = with_timeout(self.limits.close, self.sender.send(io, close)).await;
                    return Err(Error::LoginTimeout);
                }
                other => other?,
            };
            // A session that has not logged in cannot hold its slot by not
            // reading what it is sent: writes end at its login deadline too.
            let login = self.login.unwrap_or(Instant::MAX);
            let closed = match event {
                Event::More => None,
                Event::Control(opcode) => with_deadline(login, self.control(io, opcode))
                    .await
                    .map_err(|_| Error::LoginTimeout)??,
                Event::Fail(code) => {
                    with_deadline(login, self.sender.send(io, Outgoing::Close(code.code())))
                        .await
                        .map_err(|_| Error::LoginTimeout)??;
                    Some(code.code())
                }
                Event::Message | Event::InvalidText | Event::Oversized => {
                    let (closed, now) = with_deadline(login, self.respond(io, service, session, event))
                        .await
                        .map_err(|_| Error::LoginTimeout)??;
                    self.reader.finish_message();
                    if now {
                        self.login = None;
                    }
                    admitted(now);
                    closed
                }
            };
            if let Some(code) = closed {
                return Ok(code);
            }
        }
    }

    /// Reads until the next event, within the idle and login deadlines.
    async fn next_event<T: Transport>(&mut self, io: &mut T) -> Result<Event, Error<T::Error>> {
        loop {
            let idle = self.limits.idle.map_or(Instant::MAX, |d| Instant::now() + d);
            let deadline = idle.min(self.login.unwrap_or(Instant::MAX));
            let reader = &mut self.reader;
            let mut event = Event::More;
            let got = with_deadline(
                deadline,
                transport::read(io, &mut |w| {
                    let (n, e) = reader.feed(w);
                    event = e;
                    n
                }),
            )
            .await
            .map_err(|_| self.expired())?;
            match (transport::received(io, got)?, event) {
                (None, _) => return Err(Error::PeerClosed),
                (_, Event::More) => {}
                (_, event) => return Ok(event),
            }
        }
    }

    fn expired<E>(&self) -> Error<E> {
        match self.login {
            Some(at) if at <= Instant::now() => Error::LoginTimeout,
            _ => Error::Idle,
        }
    }

    /// Hands the message of `event` to the service and sends its answer;
    /// returns the close code if the connection is closing, and whether
    /// the session is admitted now.
    async fn respond<T: Transport, S: Service>(
        &mut self,
        io: &mut T,
        service: &S,
        session: &mut S::Session,
        event: Event,
    ) -> Result<(Option<u16>, bool), Error<T::Error>> {
        let reply = self.limits.reply;
        let message = self.reader.message(event);
        // Behind a feature: an await point in this function costs every
        // firmware the code of its state, taken or not (700 bytes).
        #[cfg(feature = "streamed-echo")]
        if S::ECHOES_TEXT
            && matches!(event, Event::Message)
            && let Ok(text) = message.text()
        {
            write_text(io, text.as_bytes()).await?;
            return Ok((None, true));
        }
        let mut waiting = None;
        let (sent, now) = loop {
            if !transport::reserve(io, header_len(reply) + reply).await? {
                return Err(Error::Buffers);
            }
            let mut handler = service.handler().await;
            let sent = io
                .write_with(|room| {
                    write_reply(room, reply, |out| match waiting {
                        None => handler.handle(session, message, out),
                        Some(_) => handler.resume(session, out),
                    })
                })
                .await?;
            let now = handler.admitted(session);
            drop(handler);
            match sent {
                Sent::Pending(ticket) => {
                    waiting = Some(ticket);
                    service.ready(ticket).await;
                }
                sent => break (sent, now),
            }
        };
        let code = match (sent, event) {
            (Sent::Reply, Event::Message) => return Ok((None, now)),
            // The rest of that message is unread: the connection cannot go
            // on, whatever the service answered.
            (Sent::Reply, Event::InvalidText) => CloseCode::InvalidPayload,
            (Sent::Reply, _) => CloseCode::TooBig,
            (Sent::ReplyThenClose(code) | Sent::Close(code), _) => code,
            (Sent::Pending(_), _) => CloseCode::InternalError,
        };
        self.sender.send(io, Outgoing::Close(code.code())).await?;
        Ok((Some(code.code()), now))
    }

    /// Answers a control frame; `Some(code)` when the connection is closing.
    async fn control<T: Transport>(
        &mut self,
        io: &mut T,
        opcode: Opcode,
    ) -> Result<Option<u16>, Error<T::Error>> {
        let payload = self.reader.control();
        match opcode {
            Opcode::Ping => {
                self.sender.send(io, Outgoing::Pong(payload)).await?;
                Ok(None)
            }
            Opcode::Close => {
                let code = close_reply(payload);
                debug!("peer closed with {}", code);
                self.sender.send(io, Outgoing::Close(code)).await?;
                Ok(Some(code))
            }
            _ => Ok(None),
        }
    }
}

/// Judges a complete request head against `policy` and `admit`; the key
/// to answer, or why the request is refused.
fn check<'r>(
    head: &'r [u8],
    policy: &Policy<'_>,
    admit: impl FnOnce(&Upgrade<'_>) -> bool,
) -> Result<&'r [u8; KEY_LEN], Rejection> {
    let Request::Upgrade(upgrade) = handshake::judge(head, policy)? else {
        return Err(Rejection::NotUpgrade);
    };
    if !admit(&upgrade) {
        return Err(Rejection::TooManySessions);
    }
    Ok(upgrade.key)
}
