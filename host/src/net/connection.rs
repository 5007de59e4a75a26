//! One WebSocket session after its `101`: messages in, the handler's
//! outcomes out, in order, until a close.
//!
//! Framing is ours ([`super::frame`], [`super::reader`]), as the HTTP
//! upgrade is: text is checked for UTF-8 as it arrives, so invalid text
//! closes with 1007 at its first bad byte; a message over the limit closes
//! with 1009 (through the core's policy, [`Message::Oversized`]) as soon
//! as the frame header announcing it arrives; a binary message goes to the
//! handler (the core closes with 1003); any other protocol violation closes
//! with 1002. Pings are answered with pongs in turn with the replies, and
//! at once while a command is pending ([`super::waiting`]: the session
//! reads on meanwhile, later requests wait in a bounded backlog).
//!
//! An idle session holds no buffers: the read buffer and the queue of
//! replies are freed while it waits, and the buffer the handler writes a
//! reply into is lent by the listener's [`Buffers`] per message.

use std::future::{Future, poll_fn};
use std::net::SocketAddr;
use std::pin::{Pin, pin};
use std::sync::Arc;

use futures_util::FutureExt;
use lluav_core::websocket::{Opcode, close_reply};
use lluav_core::{CloseCode, Message, Outcome};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::sync::{Notify, watch};
use tokio::time::{Instant, Sleep, timeout};
use tracing::{debug, warn};

use super::buffers::{self, Buffers};
use super::frame;
use super::reader::{Event as Received, READ_CHUNK, Reader};
use super::report::{Offence, Reports};
use super::slots::Held;
use super::waiting::{self, Backlog, Ended, Queued, ReadOn, Waited, Wire};
use super::woken::Woken;
use super::{Handler, LINGER, Limits, wire};

/// Frames a connection answers at shutdown if they had already arrived:
/// enough for any honest pipeline, bounded so that a client streaming
/// requests cannot hold the shutdown open.
const MAX_FRAMES_AFTER_SHUTDOWN: usize = 256;

/// Most replies a connection queues before it writes them even if more
/// requests are waiting, so that a fast pipeliner still gets replies
/// steadily.
const MAX_UNFLUSHED: usize = 64;

/// Bytes of queued replies that are written at once, waiting requests or
/// not.
const WRITE_BUFFER: usize = 64 * 1024;

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
enum Next {
    /// A frame to act on.
    Frame(Input),
    /// The peer closed the TCP stream, or replies could not be written.
    Ended,
    /// Nothing arrived within the idle timeout.
    Idle,
    /// A password is configured and the session did not log in in time.
    LoginTimeout,
    /// Ended from outside.
    End(End),
}

/// A frame to act on.
enum Input {
    /// What the frames read so far make.
    Read(Received),
    /// A frame read while a command was pending, its turn come.
    Queued(Queued),
}

/// What the connection does after a frame.
enum Flow {
    /// Read the next message.
    Continue,
    /// The connection is over; nothing more to send.
    Done,
    /// Close with this code and reason, wait for the peer's close, stop.
    Close(CloseCode, &'static str),
    /// The peer sent its close: answer it with this code and stop.
    Answer(u16),
    /// The peer's close was answered already (while a command was
    /// pending): stop.
    Answered,
}

/// Where the message handed to the handler comes from.
enum Source<'q> {
    /// The reader's last [`Received::Message`].
    Reader,
    /// The reader's last [`Received::Oversized`].
    Oversized,
    /// The backlog.
    Queued(Message<'q>),
}

/// The one timer of a session: the idle timeout, and the login deadline
/// until the session is admitted. Made once: a timer made afresh for every
/// frame costs a timer-wheel registration per request. It is re-armed only
/// when it fires.
struct Timer {
    sleep: Woken<Sleep>,
    last_frame: Instant,
    login_deadline: Option<Instant>,
}

impl Timer {
    /// What the timer firing means now, or `None` after re-arming it.
    fn fired(&mut self, limits: &Limits) -> Option<Next> {
        let now = Instant::now();
        if self.login_deadline.is_some_and(|d| now >= d) {
            return Some(Next::LoginTimeout);
        }
        let idle = self.last_frame + limits.idle_timeout;
        if now >= idle {
            return Some(Next::Idle);
        }
        let next = self.login_deadline.map_or(idle, |d| d.min(idle));
        self.sleep.inner_mut().reset(next);
        None
    }
}

/// Where a session's bytes go: the stream, what was read of it, the
/// replies not yet written.
struct Io<S> {
    stream: S,
    reader: Reader,
    /// Frames queued: a pipelining client gets its replies in one write, a
    /// client waiting for its reply gets it before we wait.
    outbox: Vec<u8>,
    /// Replies and pongs in `outbox`.
    queued: usize,
    /// The last read took less than it had room for: the socket had
    /// nothing more then (tokio then knows it is not readable either).
    drained: bool,
}

impl<S: AsyncRead + AsyncWrite + Unpin> Io<S> {
    /// Reads more bytes; 0 at the end of the stream. While it waits, the
    /// session holds no buffers.
    async fn read(&mut self) -> std::io::Result<usize> {
        let Io {
            stream,
            reader,
            outbox,
            drained,
            ..
        } = self;
        poll_fn(|cx| {
            let polled = wire::poll_read(stream, reader, cx, drained);
            if polled.is_pending() && outbox.is_empty() {
                buffers::recycle(std::mem::take(outbox));
            }
            polled
        })
        .await
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

    /// Writes the queued frames; false if the peer does not take them in
    /// time (the connection is then dropped).
    async fn flush(&mut self, limits: &Limits) -> bool {
        if self.outbox.is_empty() {
            return true;
        }
        self.queued = 0;
        wire::write(&mut self.stream, &mut self.outbox, limits.io_timeout).await
    }

    /// Writes the queued frames if there are enough of them, whether or
    /// not more requests are waiting; false if the peer does not take them.
    async fn flush_if_full(&mut self, limits: &Limits) -> bool {
        if self.queued >= MAX_UNFLUSHED || self.outbox.len() >= WRITE_BUFFER {
            return self.flush(limits).await;
        }
        true
    }

    /// Ends our side of the stream and reads on briefly: a peer still
    /// sending (the rest of an oversized message) would get a reset
    /// instead of our last frames if the socket closed with its bytes
    /// unread.
    async fn linger(&mut self) {
        let stream = &mut self.stream;
        let _ = timeout(LINGER, async {
            let _ = stream.shutdown().await;
            let mut sink = vec![0u8; 4096];
            while let Ok(1..) = stream.read(&mut sink).await {}
        })
        .await;
    }
}

/// A session: the socket, the handler's per-connection state and what the
/// connection needs to serve it.
pub struct Connection<'h, S, H: Handler> {
    io: Io<S>,
    handler: &'h H,
    session: H::Session,
    buffers: &'h Buffers,
    limits: Limits,
    peer: SocketAddr,
    slot: Option<Held>,
    admitted: bool,
    reports: &'h Reports,
    /// Frames read while a command was pending, to handle in turn.
    backlog: Backlog,
}

/// What a session is served with besides its stream.
pub struct Context<'h, H> {
    /// The handler of every message.
    pub handler: &'h H,
    /// Where response buffers are borrowed from.
    pub buffers: &'h Buffers,
    /// Limits and timeouts.
    pub limits: Limits,
    /// Where misbehaving clients are reported.
    pub reports: &'h Reports,
}

impl<'h, S, H> Connection<'h, S, H>
where
    S: AsyncRead + AsyncWrite + Unpin,
    H: Handler,
{
    /// A session for `peer` over `stream` (after its `101`; `leftover`:
    /// what arrived after the request head), holding `slot` (if it was
    /// counted).
    pub fn new(
        stream: S,
        leftover: Vec<u8>,
        peer: SocketAddr,
        slot: Option<Held>,
        cx: Context<'h, H>,
    ) -> Self {
        let session = cx.handler.session(peer);
        Connection {
            io: Io {
                stream,
                reader: Reader::new(leftover, cx.limits.max_message),
                outbox: Vec::new(),
                queued: 0,
                drained: false,
            },
            handler: cx.handler,
            session,
            buffers: cx.buffers,
            limits: cx.limits,
            peer,
            slot,
            admitted: false,
            reports: cx.reports,
            backlog: Backlog::default(),
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
        let ended = Woken::new(async move {
            tokio::select! {
                _ = stop.wait_for(|stopping| *stopping) => End::Shutdown,
                () = cancel.notified() => End::Reclaimed,
            }
        });
        tokio::pin!(ended);
        self.check_admitted();
        let start = Instant::now();
        let mut timer = Timer {
            sleep: Woken::new(tokio::time::sleep(
                self.limits.idle_timeout.min(self.limits.login_timeout),
            )),
            last_frame: start,
            login_deadline: (!self.admitted).then(|| start + self.limits.login_timeout),
        };
        debug!(peer = %self.peer, "connected");
        loop {
            let flow = match self.next(ended.as_mut(), &mut timer).await {
                Next::Frame(input) => {
                    let flow = self.input(input).await;
                    // Read once the frame is answered: a pending command
                    // is not idleness.
                    timer.last_frame = Instant::now();
                    if self.check_admitted() {
                        timer.login_deadline = None;
                    }
                    flow
                }
                Next::Ended => Flow::Done,
                Next::Idle => Flow::Close(CloseCode::Normal, "idle timeout"),
                Next::LoginTimeout => {
                    self.reports.note(self.peer.ip(), Offence::LoginTimeout);
                    Flow::Close(CloseCode::Policy, "no login in time")
                }
                Next::End(End::Reclaimed) => Flow::Close(CloseCode::Policy, "not logged in; slot reclaimed"),
                Next::End(End::Shutdown) => self.drain().await,
            };
            if !matches!(flow, Flow::Continue) {
                self.finish(flow).await;
                break;
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

    /// The next thing to act on. Frames already read come first, with no
    /// system call; replies are written once no request is waiting.
    async fn next(&mut self, mut ended: Pin<&mut impl Future<Output = End>>, timer: &mut Timer) -> Next {
        let limits = self.limits;
        loop {
            // What was read while a command was pending came first.
            if let Some(queued) = self.backlog.pop() {
                return Next::Frame(Input::Queued(queued));
            }
            if let Some(event) = self.io.reader.next_event() {
                return Next::Frame(Input::Read(event));
            }
            // A pipelining client's next requests may be here already:
            // their replies then go out together.
            if self.io.queued > 0 && !self.io.drained {
                match self.io.read().now_or_never() {
                    Some(Ok(1..)) => continue,
                    Some(_) => return Next::Ended,
                    None => {}
                }
            }
            let queued = !self.io.outbox.is_empty();
            if !self.io.flush(&limits).await {
                debug!(peer = %self.peer, "replies not written; dropping the connection");
                return Next::Ended;
            }
            if queued {
                self.handler.written(&self.session);
            }
            tokio::select! {
                biased;
                end = &mut ended => return Next::End(end),
                read = self.io.read() => if !matches!(read, Ok(1..)) {
                    return Next::Ended;
                },
                () = &mut timer.sleep => {
                    if let Some(next) = timer.fired(&limits) {
                        return next;
                    }
                }
            }
        }
    }

    /// Acts on a frame.
    async fn input(&mut self, input: Input) -> Flow {
        if self.io.outbox.capacity() == 0 {
            self.io.outbox = buffers::spare(READ_CHUNK);
        }
        match input {
            Input::Read(event) | Input::Queued(Queued::Stop(event)) => self.event(event).await,
            Input::Queued(Queued::Text(bytes)) => self.message(Source::Queued(Message::Text(&bytes))).await,
            Input::Queued(Queued::Binary(bytes)) => {
                self.message(Source::Queued(Message::Binary(&bytes))).await
            }
        }
    }

    /// Acts on one event of the frames received.
    async fn event(&mut self, event: Received) -> Flow {
        match event {
            Received::Message => self.message(Source::Reader).await,
            Received::Oversized => self.message(Source::Oversized).await,
            Received::InvalidText => Flow::Close(CloseCode::InvalidPayload, ""),
            Received::Control(Opcode::Ping) => {
                let Io { reader, outbox, .. } = &mut self.io;
                frame::write(outbox, Opcode::Pong, reader.control());
                self.io.queued += 1;
                self.written().await
            }
            Received::Control(Opcode::Close) => Flow::Answer(close_reply(self.io.reader.control())),
            Received::Control(_) => Flow::Continue,
            Received::Fail(code) => {
                debug!(peer = %self.peer, code = code.code(), "WebSocket protocol violation");
                Flow::Close(code, "")
            }
        }
    }

    /// Hands a message (or the news of an oversized one) to the handler
    /// and queues its reply. While the handler waits, the session reads
    /// on ([`waiting`]).
    async fn message(&mut self, source: Source<'_>) -> Flow {
        let mut out = self.buffers.lend();
        let Io {
            stream,
            reader,
            outbox,
            queued,
            drained,
        } = &mut self.io;
        let (message, read_on) = match source {
            Source::Reader => (reader.message(), Some(ReadOn::After(reader.unparsed()))),
            // Not a message the reader moved past: the handler answers it
            // at once (the core's close policy), nothing is read meanwhile.
            Source::Oversized => (Message::Oversized, None),
            Source::Queued(message) => (message, Some(ReadOn::Into(reader))),
        };
        let (code, waited) = {
            // Pinned here, in the one place it lives while it runs.
            let handling = pin!(self.handler.handle(&mut self.session, message, &mut out));
            let wire = Wire {
                stream,
                outbox: &mut *outbox,
            };
            let (outcome, waited) =
                waiting::answer(handling, read_on, wire, &mut self.backlog, &self.limits).await;
            if waited.is_some() {
                // The wait wrote what was queued, and read on.
                (*queued, *drained) = (0, false);
            }
            let ended = waited.as_ref().map_or(Ended::Open, |w| w.ended);
            (queue_reply(&outcome, ended, outbox, queued, self.peer), waited)
        };
        drop(out);
        let ended = match waited {
            Some(Waited { reader, ended }) => {
                if let Some(next) = reader {
                    self.io.reader.take_over(next);
                }
                ended
            }
            None => Ended::Open,
        };
        self.answered(code, ended).await
    }

    /// What follows a message's answer: `code` is the handler's close
    /// code, `ended` how a wait for the answer ended.
    async fn answered(&mut self, code: Option<CloseCode>, ended: Ended) -> Flow {
        match ended {
            Ended::Open => {}
            Ended::Closed => return Flow::Answered,
            Ended::Broken => {
                debug!(peer = %self.peer, "peer does not take pongs; dropping it");
                return Flow::Done;
            }
        }
        if code == Some(CloseCode::Policy) {
            self.reports.note(self.peer.ip(), Offence::WrongPasswords);
        }
        match code {
            Some(code) => Flow::Close(code, ""),
            None => self.written().await,
        }
    }

    /// After queueing a frame: written now if enough are queued.
    async fn written(&mut self) -> Flow {
        let queued = !self.io.outbox.is_empty();
        if self.io.flush_if_full(&self.limits).await {
            if queued && self.io.outbox.is_empty() {
                self.handler.written(&self.session);
            }
            Flow::Continue
        } else {
            debug!(peer = %self.peer, "peer does not take replies; dropping it");
            Flow::Done
        }
    }

    /// At shutdown: answers the frames that had already arrived (their
    /// senders are waiting for the replies), then closes with 1001. The
    /// short wait lets the reactor report bytes already in the socket.
    async fn drain(&mut self) -> Flow {
        for _ in 0..MAX_FRAMES_AFTER_SHUTDOWN {
            let input = match self.backlog.pop() {
                Some(queued) => Input::Queued(queued),
                None => match timeout(IN_FLIGHT_WAIT, self.io.receive()).await {
                    Ok(Some(event)) => Input::Read(event),
                    _ => break,
                },
            };
            match self.input(input).await {
                Flow::Continue => {}
                other => return other,
            }
        }
        Flow::Close(CloseCode::GoingAway, "lluavd is shutting down")
    }

    /// Ends the session as `flow` says.
    async fn finish(&mut self, flow: Flow) {
        let limits = self.limits;
        let io = &mut self.io;
        match flow {
            Flow::Continue | Flow::Done => return,
            Flow::Answered => {}
            Flow::Close(code, reason) => {
                // Offenders are reported (once a minute) where the offence
                // is seen; a line per close would let a client flood the log.
                debug!(peer = %self.peer, code = code.code(), reason, "closing");
                let mut payload = code.code().to_be_bytes().to_vec();
                payload.extend_from_slice(reason.as_bytes());
                frame::write(&mut io.outbox, Opcode::Close, &payload);
                // Replies queued before the close go first; then wait for
                // the peer's close, skipping whatever else it sends.
                let handshake = async {
                    if !io.flush(&limits).await {
                        return;
                    }
                    io.reader.discard();
                    while let Some(event) = io.receive().await {
                        if matches!(event, Received::Control(Opcode::Close) | Received::Fail(_)) {
                            break;
                        }
                    }
                };
                let _ = timeout(CLOSE_HANDSHAKE_TIMEOUT, handshake).await;
            }
            Flow::Answer(code) => {
                frame::write(&mut io.outbox, Opcode::Close, &code.to_be_bytes());
                let _ = timeout(CLOSE_HANDSHAKE_TIMEOUT, io.flush(&limits)).await;
            }
        }
        io.linger().await;
    }
}

/// Queues the reply of `outcome` in `outbox` (unless the peer closed
/// while it was awaited, `ended`) and gives the close code that follows.
fn queue_reply(
    outcome: &Outcome<'_>,
    ended: Ended,
    outbox: &mut Vec<u8>,
    queued: &mut usize,
    peer: SocketAddr,
) -> Option<CloseCode> {
    if let Outcome::Pending(ticket, _) = outcome {
        // A handler must wait for its backend; this one broke that promise.
        warn!(%peer, ?ticket, "handler answered Pending; closing");
        return Some(CloseCode::InternalError);
    }
    if let Some(text) = outcome.reply()
        && ended == Ended::Open
    {
        // Queued, not written: the read loop writes once no further
        // request is already waiting, and a close writes first.
        frame::write(outbox, Opcode::Text, text.as_bytes());
        *queued += 1;
    }
    outcome.close_code()
}
