//! The receiving half of a session, without I/O: bytes from the socket go
//! in ([`Reader::buffer`]), events come out ([`Reader::next_event`]).
//!
//! Frames are unmasked in place and a message is assembled where it
//! arrived: a message in one frame is never copied, the payloads of a
//! fragmented one are moved down over the headers between them. What a
//! frame may be and how frames make a message are the core's rules
//! ([`lluav_core::websocket`]: its header checks and [`Fragments`], the
//! MCU's too): text is checked for UTF-8 as each piece arrives, so a
//! message that can never be valid fails at its first bad byte, before the
//! rest is read (RFC 6455, section 8.1: "fail fast"), and a whole message
//! is left to the handler, which checks every message anyway
//! ([`Message::text`]): a message that arrives whole is checked once.
//!
//! The buffer is held only while bytes are waiting to be handled:
//! [`Reader::release`] gives it back ([`buffers::recycle`]), so an idle
//! session holds no read buffer.

use std::ops::Range;

use lluav_core::websocket::{self, Fragments, Header, Interrupt, Opcode, Verdict};
use lluav_core::{CloseCode, Message};

use super::buffers;

/// Bytes asked of the socket per read when no frame says how many are
/// coming: a page, several of the protocol's usual requests.
pub const READ_CHUNK: usize = 4096;

/// At most this many bytes are reserved at once for the rest of a long
/// frame (a frame that announces megabytes gets them as they arrive).
const MAX_RESERVE: usize = 1 << 20;

/// What the session must act on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Event {
    /// A complete data message: [`Reader::message`]. A text message may
    /// still be invalid UTF-8 at its end (its last piece is not checked
    /// here): [`Message::text`] decides.
    Message,
    /// The text message so far can never become valid UTF-8 (a complete
    /// message is not checked here: see [`Event::Message`]).
    InvalidText,
    /// The next data frame would make the message longer than the limit.
    Oversized,
    /// A complete control frame; its payload is [`Reader::control`].
    Control(Opcode),
    /// The peer broke the protocol: fail the connection with this code.
    Fail(CloseCode),
}

/// A data frame being received.
#[derive(Clone, Copy, Debug)]
struct Current {
    header: Header,
    /// Payload bytes received so far.
    got: u64,
}

/// How far one step of parsing got.
enum Step {
    /// Go on with the bytes that are left.
    Next,
    /// Every byte was used; read more.
    More,
    /// Stop here and act.
    Event(Event),
}

/// The receiving state of one session.
#[derive(Debug)]
pub struct Reader {
    /// Bytes read and not yet consumed; the message being assembled is in
    /// `buf[start..start + fragments.received()]`, the unparsed bytes in
    /// `buf[pos..]`.
    buf: Vec<u8>,
    pos: usize,
    start: usize,
    /// Largest message accepted.
    limit: usize,
    frame: Option<Current>,
    /// The message being received, by the core's rules.
    fragments: Fragments,
    control: Range<usize>,
    /// The last event handed out the message; forget it on the next call.
    delivered: bool,
    /// After our close frame: data is skipped until the peer's close.
    discarding: bool,
}

impl Reader {
    /// A reader for messages of at most `limit` bytes; `leftover` is what
    /// arrived after the request head.
    pub fn new(leftover: Vec<u8>, limit: usize) -> Self {
        Reader {
            buf: leftover,
            pos: 0,
            start: 0,
            limit,
            frame: None,
            fragments: Fragments::new(),
            control: 0..0,
            delivered: false,
            discarding: false,
        }
    }

    /// The message of the last [`Event::Message`] (or, after
    /// [`Event::InvalidText`], the text so far).
    pub fn message(&self) -> Message<'_> {
        let end = self.start + self.fragments.received();
        self.fragments
            .message(self.buf.get(self.start..end).unwrap_or_default())
    }

    /// The bytes read and not parsed yet. After an [`Event::Message`] they
    /// begin with a frame's header: a new reader given them reads on from
    /// where this one stands, while this one's message is still in use.
    pub fn unparsed(&self) -> &[u8] {
        self.buf.get(self.pos..).unwrap_or_default()
    }

    /// Goes on as `next`, a reader that read on from [`Reader::unparsed`]
    /// while this one's last message was in use; this one's buffer is
    /// recycled.
    pub fn take_over(&mut self, next: Reader) {
        let old = std::mem::replace(self, next);
        buffers::recycle(old.buf);
    }

    /// The payload of the control frame of the last [`Event::Control`].
    pub fn control(&self) -> &[u8] {
        self.buf.get(self.control.clone()).unwrap_or_default()
    }

    /// From now on, data frames are skipped rather than assembled: after
    /// our close frame only the peer's close matters.
    pub fn discard(&mut self) {
        self.discarding = true;
        self.fragments.reset();
    }

    /// The buffer to append the socket's next bytes to, with room for
    /// them: a page, or what the frame in progress still needs.
    pub fn buffer(&mut self) -> &mut Vec<u8> {
        self.settle();
        let want = match self.frame {
            Some(f) if !self.discarding => usize::try_from(f.header.len - f.got)
                .unwrap_or(MAX_RESERVE)
                .clamp(READ_CHUNK, MAX_RESERVE),
            _ => READ_CHUNK,
        };
        if self.buf.capacity() == 0 {
            self.buf = buffers::spare(want);
        } else if self.buf.capacity() - self.buf.len() < want {
            self.compact();
            self.buf.reserve(want);
        }
        &mut self.buf
    }

    /// Frees the buffer if it holds nothing: a session waiting for its
    /// next request costs no read buffer.
    pub fn release(&mut self) {
        self.settle();
        if self.buf.is_empty() {
            buffers::recycle(std::mem::take(&mut self.buf));
        }
    }

    /// The next event the bytes read so far make, or `None` when more
    /// bytes are needed.
    pub fn next_event(&mut self) -> Option<Event> {
        self.settle();
        loop {
            let step = match self.frame {
                Some(current) => self.payload(current),
                None => self.header(),
            };
            match step {
                Step::Next => {}
                Step::More => return None,
                Step::Event(event) => return Some(event),
            }
        }
    }

    /// Forgets a message that was handed out, and bytes all consumed.
    fn settle(&mut self) {
        if std::mem::take(&mut self.delivered) {
            self.fragments.reset();
        }
        if !self.fragments.in_progress() && self.pos == self.buf.len() {
            self.buf.clear();
            self.pos = 0;
            self.start = 0;
        }
    }

    /// Moves the message being assembled and the unparsed bytes to the
    /// front of the buffer.
    fn compact(&mut self) {
        let (start, len) = if self.fragments.in_progress() {
            (self.start, self.fragments.received())
        } else {
            (self.pos, 0)
        };
        self.buf.copy_within(start..start + len, 0);
        self.buf.copy_within(self.pos.., len);
        self.buf.truncate(len + self.buf.len() - self.pos);
        self.start = 0;
        self.pos = len;
    }

    /// Parses the header at `pos` and starts its frame.
    fn header(&mut self) -> Step {
        let rest = self.buf.get(self.pos..).unwrap_or_default();
        let header = match websocket::parse_header(rest) {
            Ok(Some(header)) => header,
            Ok(None) => return Step::More,
            Err(code) => return Step::Event(Event::Fail(code)),
        };
        if header.opcode.is_control() {
            return self.control_frame(&header);
        }
        if !self.discarding {
            match self.fragments.begin(&header, self.limit) {
                Ok(()) => {}
                Err(Interrupt::Fail(code)) => return Step::Event(Event::Fail(code)),
                Err(Interrupt::Oversized) => return Step::Event(Event::Oversized),
            }
            if header.opcode != Opcode::Continuation {
                // The first frame of a message: it is assembled from here.
                self.start = self.pos + header.header_len;
            }
        }
        self.pos += header.header_len;
        self.frame = Some(Current { header, got: 0 });
        Step::Next
    }

    /// A control frame is handled once it is all here (at most 139 bytes).
    fn control_frame(&mut self, header: &Header) -> Step {
        let from = self.pos + header.header_len;
        // At most 125 by `parse_header`.
        let to = from + header.len as usize;
        let Some(payload) = self.buf.get_mut(from..to) else {
            return Step::More;
        };
        websocket::unmask(payload, header.mask, 0);
        self.control = from..to;
        self.pos = to;
        Step::Event(Event::Control(header.opcode))
    }

    /// Takes what has arrived of the current data frame's payload.
    fn payload(&mut self, mut current: Current) -> Step {
        let header = current.header;
        let available = self.buf.len() - self.pos;
        let take = usize::try_from(header.len - current.got).map_or(available, |left| left.min(available));
        let from = self.pos;
        let offset = (current.got % 4) as usize;
        self.pos += take;
        current.got += take as u64;
        let complete = current.got == header.len;
        self.frame = (!complete).then_some(current);
        if !self.discarding {
            if let Some(piece) = self.buf.get_mut(from..from + take) {
                websocket::unmask(piece, header.mask, offset);
            }
            let to = self.start + self.fragments.received();
            if to != from {
                self.buf.copy_within(from..from + take, to);
            }
            // What has arrived of a text message is checked, to fail it
            // early; a whole one is left to the handler (`Message::text`).
            let message = self.buf.get(self.start..to + take).unwrap_or_default();
            if self.fragments.extend(message, complete && header.fin) == Verdict::Invalid {
                return Step::Event(Event::InvalidText);
            }
        }
        match (complete, header.fin && !self.discarding) {
            (false, _) => Step::More,
            (true, false) => Step::Next,
            (true, true) => {
                self.delivered = true;
                Step::Event(Event::Message)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MASK: [u8; 4] = [0x37, 0xfa, 0x21, 0x3d];

    /// A masked client frame.
    fn frame(first: u8, payload: &[u8]) -> Vec<u8> {
        let mut out = vec![first];
        match payload.len() {
            n @ 0..=125 => out.push(0x80 | n as u8),
            n @ 126..=0xffff => {
                out.push(0x80 | 126);
                out.extend_from_slice(&(n as u16).to_be_bytes());
            }
            n => {
                out.push(0x80 | 127);
                out.extend_from_slice(&(n as u64).to_be_bytes());
            }
        }
        out.extend_from_slice(&MASK);
        out.extend(payload.iter().enumerate().map(|(i, b)| b ^ MASK[i % 4]));
        out
    }

    /// Feeds `wire` in pieces of `piece` bytes; every event with the
    /// message or control payload it came with.
    fn events(wire: &[u8], piece: usize, limit: usize) -> Vec<(Event, Vec<u8>)> {
        let mut reader = Reader::new(Vec::new(), limit);
        let mut seen = Vec::new();
        for chunk in wire.chunks(piece) {
            reader.buffer().extend_from_slice(chunk);
            while let Some(event) = reader.next_event() {
                let body = match (event, reader.message()) {
                    (Event::Control(_), _) => reader.control().to_vec(),
                    (Event::Message | Event::InvalidText, Message::Text(b) | Message::Binary(b)) => {
                        b.to_vec()
                    }
                    _ => Vec::new(),
                };
                seen.push((event, body));
                if matches!(event, Event::Fail(_) | Event::Oversized | Event::InvalidText) {
                    return seen;
                }
            }
            reader.release();
        }
        seen
    }

    #[test]
    fn messages_in_one_or_many_frames_come_out_whole_however_the_bytes_arrive() {
        let mut wire = frame(0x81, b"state");
        wire.extend(frame(0x01, b"set_sp_ned "));
        wire.extend(frame(0x89, b"ping!"));
        wire.extend(frame(0x00, b"1:2:"));
        wire.extend(frame(0x80, b"-3:0.5"));
        wire.extend(frame(0x82, &[0, 1, 2]));
        wire.extend(frame(0x81, &[b'x'; 300]));
        for piece in [1, 2, 5, 7, 64, wire.len()] {
            let got = events(&wire, piece, 1000);
            let want = [
                (Event::Message, b"state".to_vec()),
                (Event::Control(Opcode::Ping), b"ping!".to_vec()),
                (Event::Message, b"set_sp_ned 1:2:-3:0.5".to_vec()),
                (Event::Message, vec![0, 1, 2]),
                (Event::Message, vec![b'x'; 300]),
            ];
            assert_eq!(got, want, "pieces of {piece}");
        }
    }

    #[test]
    fn invalid_text_fails_at_its_first_bad_byte() {
        // Autobahn 6.4.3: one frame, its invalid byte in the second piece.
        let payload = "κόσμε\u{10FFFF}".as_bytes();
        let mut bad = payload.to_vec();
        bad.extend_from_slice(b"\xf4\x90\x80\x80edited");
        let wire = frame(0x81, &bad);
        let header = 6;
        let cut = header + payload.len() + 2;
        let mut reader = Reader::new(wire[..cut - 1].to_vec(), 1000);
        assert_eq!(reader.next_event(), None, "valid so far");
        reader.buffer().extend_from_slice(&wire[cut - 1..cut]);
        assert_eq!(
            reader.next_event(),
            Some(Event::InvalidText),
            "before the rest arrives"
        );
    }

    #[test]
    fn a_character_split_across_frames_is_valid_and_one_cut_at_the_end_is_not() {
        let smiley = "\u{263A}".as_bytes();
        let mut wire = frame(0x01, &smiley[..1]);
        wire.extend(frame(0x00, &smiley[1..2]));
        wire.extend(frame(0x80, &smiley[2..]));
        assert_eq!(events(&wire, 1, 100), [(Event::Message, smiley.to_vec())]);
        // Complete, so left to the core's check, which refuses it.
        let cut = frame(0x81, &smiley[..2]);
        let mut reader = Reader::new(cut, 100);
        assert_eq!(reader.next_event(), Some(Event::Message));
        assert_eq!(reader.message().text(), Err(CloseCode::InvalidPayload));
    }

    #[test]
    fn a_message_over_the_limit_is_refused_at_the_header_of_its_frame() {
        assert_eq!(events(&frame(0x81, &[b'a'; 11]), 3, 10)[0].0, Event::Oversized);
        let mut wire = frame(0x01, &[b'a'; 6]);
        wire.extend(frame(0x80, &[b'a'; 5]));
        let got = events(&wire, 100, 10);
        assert_eq!(got.last().map(|e| e.0), Some(Event::Oversized));
    }

    #[test]
    fn continuations_out_of_place_fail_with_1002() {
        let fail = (Event::Fail(CloseCode::ProtocolError), Vec::new());
        assert_eq!(events(&frame(0x80, b"x"), 100, 100), std::slice::from_ref(&fail));
        let mut wire = frame(0x01, b"a");
        wire.extend(frame(0x81, b"b"));
        assert_eq!(events(&wire, 100, 100), [fail]);
    }

    #[test]
    fn after_our_close_data_is_skipped_until_the_peers_close() {
        let mut wire = frame(0x82, &[7; 5000]);
        wire.extend(frame(0x81, b"\xff not text"));
        wire.extend(frame(0x88, &[0x03, 0xe8]));
        let mut reader = Reader::new(Vec::new(), 10);
        reader.discard();
        let mut got = None;
        for chunk in wire.chunks(999) {
            reader.buffer().extend_from_slice(chunk);
            if let Some(event) = reader.next_event() {
                got = Some((event, reader.control().to_vec()));
            }
        }
        assert_eq!(got, Some((Event::Control(Opcode::Close), vec![0x03, 0xe8])));
    }

    #[test]
    fn an_idle_reader_holds_no_buffer() {
        let mut reader = Reader::new(frame(0x81, b"state"), 100);
        assert_eq!(reader.next_event(), Some(Event::Message));
        assert_eq!(reader.next_event(), None);
        reader.release();
        assert_eq!(reader.buf.capacity(), 0);
    }
}
