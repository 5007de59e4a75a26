//! What a session does while its handler waits: a command pending on an
//! autopilot's acknowledgement can take tens of seconds (a mission upload
//! over a lossy radio), and the session keeps reading meanwhile.
//!
//! - A ping is answered with its pong at once (RFC 6455, section 5.5.2:
//!   "as soon as practical"), so that a client's keepalive does not give
//!   up on a session that is only waiting.
//! - A close from the peer is answered at once. The command still runs to
//!   its end (the backend records what it did); its answer, and the
//!   requests read after it, are dropped: nobody can receive them.
//! - Later messages are read and kept in order in the session's
//!   [`Backlog`], to be handled once the command is answered: answers stay
//!   in request order, one per request. The backlog is bounded
//!   ([`MAX_BACKLOG`] messages, and the message limit in bytes): once it
//!   is full the socket is not read until it has been worked off, so a
//!   client that keeps sending meets TCP's back-pressure, not a growing
//!   buffer. A message that ends the session (oversized, invalid text, a
//!   protocol violation) takes its turn in the backlog too, and reading
//!   stops there.
//!
//! None of this runs for a message answered at once: [`answer`] polls the
//! handler once and goes further only when it is not ready.

use std::collections::VecDeque;
use std::future::{Future, poll_fn};
use std::pin::Pin;
use std::task::Poll;

use lluav_core::Message;
use lluav_core::websocket::{Opcode, close_reply};
use tokio::io::{AsyncRead, AsyncWrite, AsyncWriteExt};
use tokio::time::timeout;

use super::reader::{Event, Reader};
use super::{Limits, buffers, frame, wire};

/// Most messages a session reads ahead while a command is pending. An
/// honest client pipelines a few requests behind a slow one; 64 is the
/// most replies a connection gathers into one write anyway. The bytes are
/// bounded too (see [`Backlog`]).
pub const MAX_BACKLOG: usize = 64;

/// A frame read while a command was pending, waiting its turn.
#[derive(Debug, PartialEq, Eq)]
pub enum Queued {
    /// A complete text message.
    Text(Vec<u8>),
    /// A complete binary message.
    Binary(Vec<u8>),
    /// What ends the session when its turn comes (an oversized message,
    /// invalid text, a protocol violation); nothing was read after it.
    Stop(Event),
}

/// Messages read while a command was pending, in the order they came.
///
/// Reading stops once it holds [`MAX_BACKLOG`] messages or more bytes than
/// the message limit. So a client may send one message of the longest
/// kind behind a pending command, or several adding up to no more, and
/// still have the ping behind them answered at once; and the backlog never
/// holds more than twice the message limit (the last message taken may
/// be of the longest kind too), about what a session holds anyway while a
/// long message arrives.
#[derive(Debug, Default)]
pub struct Backlog {
    items: VecDeque<Queued>,
    bytes: usize,
}

impl Backlog {
    /// The oldest frame waiting, if any. Once the last is taken the
    /// backlog holds no memory: most sessions never wait again.
    pub fn pop(&mut self) -> Option<Queued> {
        let item = self.items.pop_front()?;
        self.bytes -= Self::size(&item);
        if self.items.is_empty() {
            self.items = VecDeque::new();
        }
        Some(item)
    }

    /// Whether a frame that ends the session was read: nothing after it
    /// is read, not even by the wait of a message queued before it.
    fn stopped(&self) -> bool {
        matches!(self.items.back(), Some(Queued::Stop(_)))
    }

    /// Whether reading must stop until frames are taken.
    fn full(&self, max_message: usize) -> bool {
        self.items.len() >= MAX_BACKLOG || self.bytes > max_message
    }

    fn push(&mut self, item: Queued) {
        self.bytes += Self::size(&item);
        self.items.push_back(item);
    }

    fn size(item: &Queued) -> usize {
        match item {
            Queued::Text(bytes) | Queued::Binary(bytes) => bytes.len(),
            Queued::Stop(_) => 0,
        }
    }
}

/// Where the bytes read while waiting go.
pub enum ReadOn<'r> {
    /// The message being handled still lies in the session's reader:
    /// read on in a reader of its own, starting with these bytes (those
    /// after the message, [`Reader::unparsed`]).
    After(&'r [u8]),
    /// Into the session's reader (the message handled is not in it).
    Into(&'r mut Reader),
}

/// How a wait ended for the connection.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ended {
    /// The session goes on.
    Open,
    /// The peer's close was answered: the answer is dropped, the session
    /// is over.
    Closed,
    /// The peer did not take what was written: drop the connection.
    Broken,
}

/// What a wait leaves behind besides the handler's output.
pub struct Waited {
    /// The reader to go on with ([`Reader::take_over`]), when it was
    /// [`ReadOn::After`].
    pub reader: Option<Reader>,
    /// How the wait ended.
    pub ended: Ended,
}

/// A session's socket and its queue of frames not yet written.
pub struct Wire<'w, S> {
    /// The socket.
    pub stream: &'w mut S,
    /// Frames queued; everything in it is written before the wait reads
    /// on, and it is empty when the wait ends.
    pub outbox: &'w mut Vec<u8>,
}

/// Awaits `handling`, the handler's answer to a message. If it is not
/// ready at once, the session reads on meanwhile as the module docs say
/// (unless `read_on` is `None`: the message is not one the reader moved
/// past), and [`Waited`] says what came of it. `handling` is pinned by the
/// caller: moved in here, it would take its room twice in the session's
/// future, and so in the memory of every session, idle or not.
pub async fn answer<F, S>(
    mut handling: Pin<&mut F>,
    read_on: Option<ReadOn<'_>>,
    wire: Wire<'_, S>,
    backlog: &mut Backlog,
    limits: &Limits,
) -> (F::Output, Option<Waited>)
where
    F: Future,
    S: AsyncRead + AsyncWrite + Unpin,
{
    // The one cost a message answered at once pays: this poll.
    let polled = poll_fn(|cx| Poll::Ready(handling.as_mut().poll(cx))).await;
    match (polled, read_on) {
        (Poll::Ready(output), _) => (output, None),
        (Poll::Pending, None) => (handling.await, None),
        (Poll::Pending, Some(read_on)) => {
            // Boxed: the connection's own future stays as small as a
            // session that never waits needs.
            let (output, waited) = Box::pin(wait(handling, wire, read_on, backlog, limits)).await;
            (output, Some(waited))
        }
    }
}

/// What reading does next.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Reading {
    On,
    /// The stream ended, failed, or a frame ended the session: nothing
    /// more can be read (the read loop sees it again afterwards).
    Stopped,
    /// The peer closed and was answered.
    Closed,
}

/// Awaits `handling` while reading on from `wire` as the module docs say:
/// pongs and the replies queued before are written at once, later
/// messages go to `backlog`. A write that the peer is slow to take holds
/// up the reading, not the command (which runs in the backend); the
/// answer is taken once it is written.
async fn wait<F, S>(
    mut handling: Pin<&mut F>,
    wire: Wire<'_, S>,
    read_on: ReadOn<'_>,
    backlog: &mut Backlog,
    limits: &Limits,
) -> (F::Output, Waited)
where
    F: Future,
    S: AsyncRead + AsyncWrite + Unpin,
{
    let Wire { stream, outbox } = wire;
    let mut own = None;
    let reader = match read_on {
        ReadOn::After(rest) => {
            let mut buf = buffers::spare(rest.len());
            buf.extend_from_slice(rest);
            own.insert(Reader::new(buf, limits.max_message))
        }
        ReadOn::Into(reader) => reader,
    };
    let mut reading = if backlog.stopped() {
        Reading::Stopped
    } else {
        Reading::On
    };
    let mut ended = Ended::Open;
    let mut drained = false;
    let output = loop {
        if reading == Reading::On {
            reading = take_events(reader, outbox, backlog, limits.max_message);
        }
        // Replies queued before this command answer earlier requests:
        // they go out now, with the pongs, not after the wait.
        if !outbox.is_empty() && ended == Ended::Open {
            if !wire::write(stream, outbox, limits.io_timeout).await {
                ended = Ended::Broken;
                reading = Reading::Stopped;
            } else if reading == Reading::Closed {
                ended = Ended::Closed;
                // Our side is done: the peer learns so now, not when the
                // command ends.
                let _ = timeout(limits.io_timeout, stream.shutdown()).await;
            }
        }
        let more = reading == Reading::On && !backlog.full(limits.max_message);
        tokio::select! {
            biased;
            output = &mut handling => break output,
            read = poll_fn(|cx| wire::poll_read(stream, reader, cx, &mut drained)), if more => {
                if !matches!(read, Ok(1..)) {
                    reading = Reading::Stopped;
                }
            }
        }
    };
    outbox.clear();
    (output, Waited { reader: own, ended })
}

/// Acts on the events of the bytes `reader` holds until it needs more,
/// the backlog is full, or reading must stop.
fn take_events(
    reader: &mut Reader,
    outbox: &mut Vec<u8>,
    backlog: &mut Backlog,
    max_message: usize,
) -> Reading {
    while !backlog.full(max_message) {
        let Some(event) = reader.next_event() else {
            break;
        };
        match event {
            Event::Control(Opcode::Ping) => frame::write(outbox, Opcode::Pong, reader.control()),
            Event::Control(Opcode::Close) => {
                let code = close_reply(reader.control());
                frame::write(outbox, Opcode::Close, &code.to_be_bytes());
                return Reading::Closed;
            }
            Event::Control(_) => {}
            Event::Message => backlog.push(match reader.message() {
                Message::Text(bytes) => Queued::Text(bytes.to_vec()),
                Message::Binary(bytes) => Queued::Binary(bytes.to_vec()),
                Message::Oversized => Queued::Stop(Event::Oversized),
            }),
            Event::Oversized | Event::InvalidText | Event::Fail(_) => {
                backlog.push(Queued::Stop(event));
                return Reading::Stopped;
            }
        }
    }
    Reading::On
}
