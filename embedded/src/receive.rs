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
        match self.fragments.begin(header, self.message.len()) {
            Ok(()) => None,
            Err(Interrupt::Fail(code)) => Some(Event::Fail(code)),
            Err(Interrupt::Oversized) => Some(Event::Oversized),
        }
    }

    /// Takes what `bytes` holds of the current frame's payload; returns the
    /// bytes used and an event once the frame (or the text) calls for one.
    fn payload(&mut self, mut current: Current, bytes: &[u8]) -> (usize, Option<Event>) {
        let header = current.header;
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
}
