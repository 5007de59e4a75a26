//! The receiving half of a connection: frames parsed and unmasked straight
//! out of the transport's receive buffer, data payloads gathered in the
//! message buffer (the only copy), text validated as it arrives.
//!
//! [`Reader::feed`] takes whatever contiguous bytes the transport offers,
//! consumes as many as it can and stops at the first thing the connection
//! must act on (an [`Event`]); the rest stays in the transport's buffer for
//! the next call. A frame header cut by the end of what has arrived (or by
//! the end of the ring buffer) is kept in a 14-byte carry, a control
//! frame's payload in 125 bytes of its own, so nothing waits for bytes it
//! has not consumed.
//!
//! With feature `streamed-echo`, for a service that echoes text
//! ([`Reader::stream_text`]), a text message is not gathered: the message
//! buffer holds one piece of it at a time, unmasked and checked for UTF-8
//! ([`Utf8Stream`](lluav_core::websocket::Utf8Stream)), which the
//! connection sends on ([`Event::Piece`]) before the reader goes on. A
//! text message of any length then passes through a message buffer of
//! any size (at least [`crate::MIN_MESSAGE`]); binary messages are still
//! gathered, up to the buffer's size, for the service to answer.

#[cfg(feature = "streamed-echo")]
use lluav_core::websocket::Utf8Stream;
use lluav_core::websocket::handshake::Rejection;
use lluav_core::websocket::{
    self, Fragments, Header, Interrupt, MAX_CLIENT_HEADER, MAX_CONTROL_PAYLOAD, Opcode, Verdict,
};
use lluav_core::{CloseCode, Message};

/// The longest request head read (its bytes are held in the message
/// buffer until answered); a longer one is refused with 431.
pub(crate) const MAX_REQUEST_HEAD: usize = 1024;

/// What the connection must act on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Event {
    /// Everything offered was consumed; read more.
    More,
    /// A complete message is in the message buffer.
    Message,
    /// The text message so far can never become valid UTF-8: hand it to
    /// the service now, before its remaining bytes arrive.
    InvalidText,
    /// The next frame would overflow the message buffer.
    Oversized,
    /// A complete control frame; its payload is [`Reader::control`].
    Control(Opcode),
    /// The peer broke the protocol; fail the connection with this code.
    Fail(CloseCode),
    /// The next piece of a streamed text message is in the message buffer
    /// ([`Reader::piece`]): send it on, as the last frame of the echo if
    /// `fin`, then [`Reader::piece_sent`].
    #[cfg(feature = "streamed-echo")]
    Piece {
        /// Whether it ends the message.
        fin: bool,
    },
}

/// A text message passing through the message buffer piece by piece.
#[cfg(feature = "streamed-echo")]
#[derive(Clone, Copy, Debug, Default)]
struct Stream {
    /// Whether text messages are streamed at all.
    enabled: bool,
    /// Whether the message in progress is a streamed text message.
    active: bool,
    /// Whether a piece of it was sent (the next one is a continuation).
    started: bool,
    /// Bytes of the next piece in the message buffer.
    piece: usize,
    utf8: Utf8Stream,
}

/// A frame being received.
#[derive(Clone, Copy, Debug)]
struct Current {
    header: Header,
    /// Payload bytes received so far.
    got: u64,
}

/// The receiving state of one connection.
pub(crate) struct Reader<'b> {
    message: &'b mut [u8],
    /// Bytes of the request head in `message`, until frames start.
    head: usize,
    /// The message being received; its bytes are in `message`.
    fragments: Fragments,
    carry: [u8; MAX_CLIENT_HEADER],
    carried: usize,
    frame: Option<Current>,
    control: [u8; MAX_CONTROL_PAYLOAD],
    control_len: usize,
    #[cfg(feature = "streamed-echo")]
    stream: Stream,
}

/// How far a header got.
enum Head {
    /// Complete; this many of the offered bytes were its tail.
    Done(Header, usize),
    /// Still incomplete; all offered bytes were carried.
    Partial(usize),
}

impl<'b> Reader<'b> {
    pub(crate) fn new(message: &'b mut [u8]) -> Self {
        Reader {
            message,
            head: 0,
            fragments: Fragments::new(),
            carry: [0; MAX_CLIENT_HEADER],
            carried: 0,
            frame: None,
            control: [0; MAX_CONTROL_PAYLOAD],
            control_len: 0,
            #[cfg(feature = "streamed-echo")]
            stream: Stream::default(),
        }
    }

    /// Streams text messages through the message buffer instead of
    /// gathering them (for a service that answers valid text with itself).
    #[cfg(feature = "streamed-echo")]
    pub(crate) fn stream_text(&mut self, enabled: bool) {
        self.stream.enabled = enabled;
    }

    /// The piece of the last [`Event::Piece`]: the opcode of its frame
    /// (text for the message's first, continuation after) and its bytes.
    #[cfg(feature = "streamed-echo")]
    pub(crate) fn piece(&self) -> (Opcode, &[u8]) {
        let opcode = match self.stream.started {
            true => Opcode::Continuation,
            false => Opcode::Text,
        };
        (opcode, self.message.get(..self.stream.piece).unwrap_or(&[]))
    }

    /// The piece of the last [`Event::Piece`] was sent; after the message's
    /// last one, the next data frame starts a new message.
    #[cfg(feature = "streamed-echo")]
    pub(crate) fn piece_sent(&mut self, fin: bool) {
        self.stream.piece = 0;
        self.stream.started = true;
        if fin {
            self.stream = Stream {
                enabled: self.stream.enabled,
                ..Stream::default()
            };
            self.fragments.reset();
        }
    }

    /// The size of the message buffer: the frame limit.
    pub(crate) fn capacity(&self) -> usize {
        self.message.len()
    }

    /// Gathers the upgrade request's head in the message buffer; returns
    /// the bytes consumed and, once decided, the head's length or why it
    /// was rejected. Bytes after the head stay unconsumed (a client may
    /// send its first frame without waiting for the `101`).
    pub(crate) fn head(&mut self, window: &[u8]) -> (usize, Option<Result<usize, Rejection>>) {
        let limit = self.message.len().min(MAX_REQUEST_HEAD);
        for (i, &b) in window.iter().enumerate() {
            let Some(slot) = self.message.get_mut(self.head).filter(|_| self.head < limit) else {
                return (i, Some(Err(Rejection::TooLarge)));
            };
            *slot = b;
            self.head += 1;
            if self
                .message
                .get(..self.head)
                .is_some_and(|m| m.ends_with(b"\r\n\r\n"))
            {
                return (i + 1, Some(Ok(self.head)));
            }
        }
        (window.len(), None)
    }

    /// The request head gathered by [`Reader::head`].
    pub(crate) fn request(&self) -> &[u8] {
        self.message.get(..self.head).unwrap_or(&[])
    }

    /// Forgets the request head: frames come next.
    pub(crate) fn start_frames(&mut self) {
        self.head = 0;
    }

    /// The message to hand to the service after [`Event::Message`],
    /// [`Event::InvalidText`] or [`Event::Oversized`].
    pub(crate) fn message(&self, event: Event) -> Message<'_> {
        match event {
            Event::Oversized => Message::Oversized,
            _ => {
                let body = self.message.get(..self.fragments.received()).unwrap_or(&[]);
                self.fragments.message(body)
            }
        }
    }

    /// Forgets the message handed to the service.
    pub(crate) fn finish_message(&mut self) {
        self.fragments.reset();
    }

    /// The payload of the control frame of the last [`Event::Control`].
    pub(crate) fn control(&self) -> &[u8] {
        self.control.get(..self.control_len).unwrap_or(&[])
    }

    /// Consumes bytes from `window` up to the first event; returns how many
    /// it consumed and the event.
    pub(crate) fn feed(&mut self, window: &[u8]) -> (usize, Event) {
        let mut at = 0;
        loop {
            let current = match self.frame {
                Some(current) => current,
                None => {
                    let rest = window.get(at..).unwrap_or(&[]);
                    if rest.is_empty() {
                        return (at, Event::More);
                    }
                    let header = match self.header(rest) {
                        Ok(Head::Done(header, used)) => {
                            at += used;
                            header
                        }
                        Ok(Head::Partial(used)) => return (at + used, Event::More),
                        Err(code) => return (at, Event::Fail(code)),
                    };
                    if let Some(event) = self.begin(&header) {
                        return (at, event);
                    }
                    Current { header, got: 0 }
                }
            };
            let (used, event) = self.payload(current, window.get(at..).unwrap_or(&[]));
            at += used;
            if let Some(event) = event {
                return (at, event);
            }
        }
    }

    /// Parses a header from the carried bytes and `rest`.
    fn header(&mut self, rest: &[u8]) -> Result<Head, CloseCode> {
        if self.carried == 0
            && let Some(header) = websocket::parse_header(rest)?
        {
            return Ok(Head::Done(header, header.header_len));
        }
        // Too few bytes for a header (at most 13): carry them.
        let take = (MAX_CLIENT_HEADER - self.carried).min(rest.len());
        let (Some(dst), Some(src)) = (
            self.carry.get_mut(self.carried..self.carried + take),
            rest.get(..take),
        ) else {
            return Err(CloseCode::InternalError);
        };
        dst.copy_from_slice(src);
        let had = self.carried;
        self.carried += take;
        match websocket::parse_header(self.carry.get(..self.carried).unwrap_or(&[]))? {
            Some(header) => {
                self.carried = 0;
                Ok(Head::Done(header, header.header_len.saturating_sub(had)))
            }
            None => Ok(Head::Partial(take)),
        }
    }

    /// Checks a new frame against the message in progress.
    fn begin(&mut self, header: &Header) -> Option<Event> {
        let limit = self.message.len();
        // A streamed message is never held whole: no limit of the message
        // buffer's. (Each of its frames stays within usize::MAX bytes, 4 GiB
        // on a 32-bit MCU: `Fragments` counts in usize; a longer frame is
        // oversized, 1009.)
        #[cfg(feature = "streamed-echo")]
        let limit = match header.opcode {
            Opcode::Text if self.stream.enabled => usize::MAX,
            Opcode::Continuation if self.stream.active => usize::MAX,
            _ => limit,
        };
        match self.fragments.begin(header, limit) {
            #[cfg(feature = "streamed-echo")]
            Ok(()) if header.opcode == Opcode::Text && self.stream.enabled => {
                self.stream = Stream {
                    enabled: true,
                    active: true,
                    ..Stream::default()
                };
                None
            }
            Ok(()) => None,
            Err(Interrupt::Fail(code)) => Some(Event::Fail(code)),
            Err(Interrupt::Oversized) => Some(Event::Oversized),
        }
    }

    /// Takes what `bytes` holds of the current frame's payload; returns the
    /// bytes used and an event once the frame (or the text) calls for one.
    fn payload(&mut self, mut current: Current, bytes: &[u8]) -> (usize, Option<Event>) {
        let header = current.header;
        #[cfg(feature = "streamed-echo")]
        if self.stream.active && !header.opcode.is_control() {
            return self.stream_payload(current, bytes);
        }
        let left = header.len - current.got;
        let take = usize::try_from(left).map_or(bytes.len(), |left| left.min(bytes.len()));
        let offset = current.got as usize;
        let src = bytes.get(..take).unwrap_or(&[]);
        let control = header.opcode.is_control();
        let len = self.fragments.received();
        let dst = if control {
            self.control.get_mut(offset..offset + take)
        } else {
            self.message.get_mut(len..len + take)
        };
        let Some(dst) = dst else {
            return (0, Some(Event::Fail(CloseCode::InternalError)));
        };
        dst.copy_from_slice(src);
        websocket::unmask(dst, header.mask, offset);
        current.got += take as u64;
        if !control {
            let message = self.message.get(..len + take).unwrap_or(&[]);
            let complete = header.fin && current.got == header.len;
            if self.fragments.extend(message, complete) == Verdict::Invalid {
                return (take, Some(Event::InvalidText));
            }
        }
        if current.got < header.len {
            // Every offered byte was payload: wait for the rest.
            self.frame = Some(current);
            return (take, Some(Event::More));
        }
        self.frame = None;
        let event = if control {
            self.control_len = offset + take;
            Some(Event::Control(header.opcode))
        } else {
            header.fin.then_some(Event::Message)
        };
        (take, event)
    }

    /// Takes what `bytes` holds of a streamed text frame into the piece
    /// in the message buffer; returns the bytes used and an event once the
    /// piece is to be sent (the buffer is full, or the message ended).
    /// Between frames of the message (and around control frames) the piece
    /// simply waits in the buffer: fewer, larger frames go out.
    #[cfg(feature = "streamed-echo")]
    fn stream_payload(&mut self, mut current: Current, bytes: &[u8]) -> (usize, Option<Event>) {
        let header = current.header;
        let at = self.stream.piece;
        let room = self.message.len().saturating_sub(at);
        let left = header.len - current.got;
        let take = usize::try_from(left).map_or(bytes.len(), |left| left.min(bytes.len()));
        let take = take.min(room);
        let (Some(dst), Some(src)) = (self.message.get_mut(at..at + take), bytes.get(..take)) else {
            return (0, Some(Event::Fail(CloseCode::InternalError)));
        };
        dst.copy_from_slice(src);
        websocket::unmask(dst, header.mask, current.got as usize);
        // Fail fast (RFC 6455 8.1): the rest of the message is never read,
        // and the bytes of the piece before the bad one are never sent.
        if self.stream.utf8.push(dst) == Verdict::Invalid {
            return (take, Some(Event::Fail(CloseCode::InvalidPayload)));
        }
        current.got += take as u64;
        self.stream.piece += take;
        let ended = current.got == header.len;
        self.frame = (!ended).then_some(current);
        let last = ended && header.fin;
        if last && !self.stream.utf8.complete() {
            // It ends inside a character: the echo's last frame is never sent.
            return (take, Some(Event::Fail(CloseCode::InvalidPayload)));
        }
        if last || self.stream.piece == self.message.len() {
            return (take, Some(Event::Piece { fin: last }));
        }
        // A frame that has not ended took every offered byte: read more.
        (take, (!ended).then_some(Event::More))
    }
}
