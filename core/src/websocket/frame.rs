//! Frames on the wire (RFC 6455, section 5).
//!
//! [`parse_header`] enforces every rule a server must before any payload
//! is read (reserved bits clear, client frames masked, control frames
//! unfragmented and at most 125 bytes, lengths in their minimal form with
//! the top bit of a 64-bit one clear), never panics and never reads past
//! the slice it is given. [`write_header`] frames a server payload with
//! the minimal length form. [`Utf8`] checks a text message while its
//! pieces arrive, so invalid text fails the connection at its first bad
//! byte (section 8.1, "fail fast"), not when the last fragment is in;
//! [`Utf8Stream`] does the same for a message whose bytes are not kept.

use crate::server::CloseCode;

/// The largest payload a control frame may carry.
pub const MAX_CONTROL_PAYLOAD: usize = 125;

/// The longest client frame header: 2 bytes, 8 of extended length, 4 of mask.
pub const MAX_CLIENT_HEADER: usize = 14;

/// The longest server frame header: 2 bytes and a 64-bit length.
pub const MAX_SERVER_HEADER: usize = 10;

/// A frame's opcode (RFC 6455, section 5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Opcode {
    /// A continuation of a fragmented message.
    Continuation,
    /// The first frame of a text message.
    Text,
    /// The first frame of a binary message.
    Binary,
    /// A close frame.
    Close,
    /// A ping.
    Ping,
    /// A pong.
    Pong,
}

impl Opcode {
    /// Whether this is a control frame (close, ping, pong).
    pub fn is_control(self) -> bool {
        matches!(self, Opcode::Close | Opcode::Ping | Opcode::Pong)
    }

    /// The opcode's four bits, as they are sent.
    pub fn bits(self) -> u8 {
        match self {
            Opcode::Continuation => 0x0,
            Opcode::Text => 0x1,
            Opcode::Binary => 0x2,
            Opcode::Close => 0x8,
            Opcode::Ping => 0x9,
            Opcode::Pong => 0xa,
        }
    }

    fn from_bits(bits: u8) -> Option<Self> {
        Some(match bits {
            0x0 => Opcode::Continuation,
            0x1 => Opcode::Text,
            0x2 => Opcode::Binary,
            0x8 => Opcode::Close,
            0x9 => Opcode::Ping,
            0xa => Opcode::Pong,
            _ => return None,
        })
    }
}

/// A validated client frame header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Whether this frame ends its message.
    pub fin: bool,
    /// The opcode.
    pub opcode: Opcode,
    /// The payload length, as sent (it may exceed any limit).
    pub len: u64,
    /// The masking key (clients must mask every frame).
    pub mask: [u8; 4],
    /// The header's length in bytes.
    pub header_len: usize,
}

/// Parses the client frame header at the start of `buf`: `Ok(None)` when
/// more bytes are needed, `Err(code)` when the frame breaks the protocol
/// and the connection must be failed with that close code.
pub fn parse_header(buf: &[u8]) -> Result<Option<Header>, CloseCode> {
    let [b0, b1, rest @ ..] = buf else {
        return Ok(None);
    };
    // No extension is negotiated, so every reserved bit must be clear.
    if b0 & 0x70 != 0 {
        return Err(CloseCode::ProtocolError);
    }
    let opcode = Opcode::from_bits(b0 & 0x0f).ok_or(CloseCode::ProtocolError)?;
    let fin = b0 & 0x80 != 0;
    if b1 & 0x80 == 0 {
        return Err(CloseCode::ProtocolError);
    }
    // Section 5.2: "the minimal number of bytes MUST be used to encode
    // the length": a 16-bit length is at least 126, a 64-bit one at least
    // 65,536 (and its top bit is clear).
    let (len, ext, least) = match b1 & 0x7f {
        126 => match rest {
            [a, b, ..] => (u64::from(u16::from_be_bytes([*a, *b])), 2, 126),
            _ => return Ok(None),
        },
        127 => match rest.first_chunk::<8>() {
            Some(bytes) => (u64::from_be_bytes(*bytes), 8, 0x1_0000),
            None => return Ok(None),
        },
        short => (u64::from(short), 0, 0),
    };
    if len < least || len >> 63 != 0 {
        return Err(CloseCode::ProtocolError);
    }
    if opcode.is_control() && (!fin || len > MAX_CONTROL_PAYLOAD as u64) {
        return Err(CloseCode::ProtocolError);
    }
    let Some(mask) = rest.get(ext..).and_then(|r| r.first_chunk::<4>()) else {
        return Ok(None);
    };
    Ok(Some(Header {
        fin,
        opcode,
        len,
        mask: *mask,
        header_len: 2 + ext + 4,
    }))
}

/// Unmasks `payload` in place; `offset` is the position of its first byte
/// within the frame's payload (frames arrive in pieces). Eight bytes at a
/// time where words are that wide: on lluavd a byte loop costs more than
/// the rest of a short frame's handling. A 32-bit MCU takes the byte loop,
/// 200 bytes smaller in its flash.
pub fn unmask(payload: &mut [u8], mask: [u8; 4], offset: usize) {
    let mut key = mask;
    key.rotate_left(offset % 4);
    #[cfg(target_pointer_width = "64")]
    let payload = {
        let [a, b, c, d] = key;
        let word = u64::from_ne_bytes([a, b, c, d, a, b, c, d]);
        let mut words = payload.chunks_exact_mut(8);
        for chunk in &mut words {
            let mut bytes = [0; 8];
            bytes.copy_from_slice(chunk);
            chunk.copy_from_slice(&(u64::from_ne_bytes(bytes) ^ word).to_ne_bytes());
        }
        // The tail starts a multiple of 8 (so of 4) bytes in: the same phase.
        words.into_remainder()
    };
    for (byte, k) in payload.iter_mut().zip(key.iter().cycle()) {
        *byte ^= k;
    }
}

/// The length of a server frame header for a `len`-byte payload.
pub const fn header_len(len: usize) -> usize {
    match len {
        0..=125 => 2,
        126..=0xffff => 4,
        _ => 10,
    }
}

/// Writes the header of a final (FIN), unmasked server frame with a
/// `len`-byte payload at the start of `out`, in the minimal length form
/// RFC 6455 requires; returns its length, or `None` if `out` is shorter.
pub fn write_header(out: &mut [u8], opcode: Opcode, len: usize) -> Option<usize> {
    let n = header_len(len);
    let [first, second, extended @ ..] = out.get_mut(..n)? else {
        return None;
    };
    *first = 0x80 | opcode.bits();
    match extended.len() {
        0 => *second = len as u8,
        2 => {
            *second = 126;
            extended.copy_from_slice(&(len as u16).to_be_bytes());
        }
        _ => {
            *second = 127;
            extended.copy_from_slice(&(len as u64).to_be_bytes());
        }
    }
    Some(n)
}

/// How far a growing text message is known to be valid UTF-8.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Utf8 {
    /// `message[..valid]` is valid UTF-8 ending on a character boundary.
    valid: usize,
}

/// What the bytes received so far say about a text message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Valid so far; the message may still end in the middle of a
    /// character that later bytes complete.
    Open,
    /// No continuation can make this message valid.
    Invalid,
}

impl Utf8 {
    /// A new, empty message.
    pub const fn new() -> Self {
        Utf8 { valid: 0 }
    }

    /// Checks the bytes appended since the last call: `message` is the
    /// whole message so far. Each byte is examined about once (the up to
    /// three bytes of an unfinished character are examined again).
    pub fn extend(&mut self, message: &[u8]) -> Verdict {
        let Some(new) = message.get(self.valid..) else {
            return Verdict::Invalid;
        };
        match core::str::from_utf8(new) {
            Ok(_) => {
                self.valid = message.len();
                Verdict::Open
            }
            // `error_len` is `None` when the input ends inside a character
            // that more bytes may complete.
            Err(e) if e.error_len().is_none() => {
                self.valid += e.valid_up_to();
                Verdict::Open
            }
            Err(_) => Verdict::Invalid,
        }
    }

    /// Whether a message of `len` bytes, all passed to [`Utf8::extend`],
    /// ends on a character boundary (a message may not end inside one).
    pub fn complete(&self, len: usize) -> bool {
        self.valid == len
    }
}

/// A text message checked piece by piece when its bytes are not kept (an
/// echo that sends each piece on before the next arrives): [`Utf8`] needs
/// the whole message so far, this only the up to three bytes of a
/// character that a piece's end cut, carried to the next piece. Each byte
/// is examined about once (a carried character's bytes twice).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Utf8Stream {
    /// The start of a character the last piece ended inside.
    carry: [u8; 4],
    carried: usize,
}

impl Utf8Stream {
    /// A new, empty message.
    pub const fn new() -> Self {
        Utf8Stream {
            carry: [0; 4],
            carried: 0,
        }
    }

    /// Checks the next `piece` of the message.
    pub fn push(&mut self, piece: &[u8]) -> Verdict {
        let mut rest = piece;
        if self.carried > 0 {
            // The carried character with the bytes that may finish it: a
            // character has at most four, so four decide it.
            let take = (self.carry.len() - self.carried).min(rest.len());
            let (Some(room), Some(next)) = (
                self.carry.get_mut(self.carried..self.carried + take),
                rest.get(..take),
            ) else {
                return Verdict::Invalid;
            };
            room.copy_from_slice(next);
            let joined = self.carry.get(..self.carried + take).unwrap_or(&[]);
            let finished = match core::str::from_utf8(joined) {
                Ok(_) => joined.len(),
                // The carried character is complete (and valid_up_to
                // counts past it); what follows is checked with the rest.
                Err(e) if e.valid_up_to() > 0 => e.valid_up_to(),
                // Still unfinished: four bytes would have finished it, so
                // the whole piece was taken.
                Err(e) if e.error_len().is_none() && take == rest.len() => {
                    self.carried += take;
                    return Verdict::Open;
                }
                Err(_) => return Verdict::Invalid,
            };
            rest = rest.get(finished.saturating_sub(self.carried)..).unwrap_or(&[]);
            self.carried = 0;
        }
        match core::str::from_utf8(rest) {
            Ok(_) => Verdict::Open,
            // `error_len` is `None` when the piece ends inside a character
            // that the next piece may finish.
            Err(e) if e.error_len().is_none() => {
                let tail = rest.get(e.valid_up_to()..).unwrap_or(&[]);
                match self.carry.get_mut(..tail.len()) {
                    Some(room) => {
                        room.copy_from_slice(tail);
                        self.carried = tail.len();
                        Verdict::Open
                    }
                    None => Verdict::Invalid,
                }
            }
            Err(_) => Verdict::Invalid,
        }
    }

    /// Whether the message, all of it pushed, ends on a character boundary
    /// (a message may not end inside one).
    pub fn complete(&self) -> bool {
        self.carried == 0
    }
}
