//! WebSocket frames on the wire (RFC 6455, section 5): client frame
//! headers validated before any payload is read, payload unmasking, and
//! server frame headers.
//!
//! [`parse_header`] enforces every rule a server must (reserved bits
//! clear, client frames masked, control frames unfragmented and at most
//! 125 bytes, 64-bit lengths with the top bit clear), never panics and
//! never reads past the slice it is given.

use lluav_core::CloseCode;

/// The largest payload a control frame may carry.
pub const MAX_CONTROL_PAYLOAD: usize = 125;

/// The longest server frame header (2 bytes and a 64-bit length).
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

    fn bits(self) -> u8 {
        match self {
            Opcode::Continuation => 0x0,
            Opcode::Text => 0x1,
            Opcode::Binary => 0x2,
            Opcode::Close => 0x8,
            Opcode::Ping => 0x9,
            Opcode::Pong => 0xa,
        }
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
    if b0 & 0x70 != 0 {
        return Err(CloseCode::ProtocolError);
    }
    let opcode = match b0 & 0x0f {
        0 => Opcode::Continuation,
        1 => Opcode::Text,
        2 => Opcode::Binary,
        8 => Opcode::Close,
        9 => Opcode::Ping,
        10 => Opcode::Pong,
        _ => return Err(CloseCode::ProtocolError),
    };
    let fin = b0 & 0x80 != 0;
    if b1 & 0x80 == 0 {
        return Err(CloseCode::ProtocolError);
    }
    let (len, ext) = match b1 & 0x7f {
        126 => match rest {
            [a, b, ..] => (u64::from(u16::from_be_bytes([*a, *b])), 2),
            _ => return Ok(None),
        },
        127 => match rest.first_chunk::<8>() {
            Some(bytes) => {
                let len = u64::from_be_bytes(*bytes);
                if len >> 63 != 0 {
                    return Err(CloseCode::ProtocolError);
                }
                (len, 8)
            }
            None => return Ok(None),
        },
        short => (u64::from(short), 0),
    };
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
/// time: a byte loop costs more than the rest of a short frame's handling.
pub fn unmask(payload: &mut [u8], mask: [u8; 4], offset: usize) {
    let mut key = mask;
    key.rotate_left(offset % 4);
    let [a, b, c, d] = key;
    let word = u64::from_ne_bytes([a, b, c, d, a, b, c, d]);
    let mut words = payload.chunks_exact_mut(8);
    for chunk in &mut words {
        let mut bytes = [0; 8];
        bytes.copy_from_slice(chunk);
        chunk.copy_from_slice(&(u64::from_ne_bytes(bytes) ^ word).to_ne_bytes());
    }
    // The tail starts a multiple of 8 (so of 4) bytes in: the same phase.
    for (byte, k) in words.into_remainder().iter_mut().zip(key.iter().cycle()) {
        *byte ^= k;
    }
}

/// Appends a final (FIN), unmasked server frame with `payload` to `out`.
pub fn write(out: &mut Vec<u8>, opcode: Opcode, payload: &[u8]) {
    let first = 0x80 | opcode.bits();
    let len = payload.len();
    out.reserve(MAX_SERVER_HEADER + len);
    match u16::try_from(len) {
        // The minimal length form, as RFC 6455 requires.
        Ok(short @ 0..=125) => out.extend_from_slice(&[first, short as u8]),
        Ok(medium) => {
            let [hi, lo] = medium.to_be_bytes();
            out.extend_from_slice(&[first, 126, hi, lo]);
        }
        Err(_) => {
            out.extend_from_slice(&[first, 127]);
            out.extend_from_slice(&(len as u64).to_be_bytes());
        }
    }
    out.extend_from_slice(payload);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_header_cut_short_waits_for_more_bytes() {
        assert_eq!(parse_header(&[0x81]), Ok(None));
        assert_eq!(parse_header(&[0x81, 0xfe, 0x01]), Ok(None));
        assert_eq!(parse_header(&[0x81, 0x85, 1, 2, 3]), Ok(None));
    }

    #[test]
    fn sixteen_and_sixty_four_bit_lengths_are_read() {
        let h = parse_header(&[0x81, 0xfe, 0x01, 0x00, 1, 2, 3, 4]);
        let h = h.ok().flatten().expect("a whole header");
        assert_eq!((h.len, h.header_len, h.mask), (256, 8, [1, 2, 3, 4]));
        let h = parse_header(&[0x02, 0xff, 0, 0, 0, 1, 0, 0, 0, 0, 9, 9, 9, 9]);
        let h = h.ok().flatten().expect("a whole header");
        assert_eq!(
            (h.len, h.header_len, h.fin, h.opcode),
            (1 << 32, 14, false, Opcode::Binary)
        );
    }

    #[test]
    fn frames_the_rfc_forbids_fail_with_1002() {
        let bad: [&[u8]; 6] = [
            &[0xc1, 0x80, 0, 0, 0, 0],                   // RSV1 without an extension
            &[0x83, 0x80, 0, 0, 0, 0],                   // reserved opcode
            &[0x81, 0x00],                               // unmasked client frame
            &[0x09, 0x80, 0, 0, 0, 0],                   // fragmented ping
            &[0x89, 0xfe, 0, 126, 0, 0, 0, 0],           // ping over 125 bytes
            &[0x81, 0xff, 0x80, 0, 0, 0, 0, 0, 0, 0, 0], // 64-bit length, top bit set
        ];
        for frame in bad {
            assert_eq!(parse_header(frame), Err(CloseCode::ProtocolError), "{frame:?}");
        }
    }

    #[test]
    fn server_frames_use_the_minimal_length_form() {
        let framed = |len: usize| {
            let mut out = Vec::new();
            write(&mut out, Opcode::Text, &vec![b'x'; len]);
            out.truncate(out.len() - len);
            out
        };
        assert_eq!(framed(125), [0x81, 125]);
        assert_eq!(framed(126), [0x81, 126, 0, 126]);
        // 65535 still fits the 16-bit form (Autobahn case 1.1.6).
        assert_eq!(framed(0xffff), [0x81, 126, 0xff, 0xff]);
        assert_eq!(framed(0x10000), [0x81, 127, 0, 0, 0, 0, 0, 1, 0, 0]);
        let mut pong = Vec::new();
        write(&mut pong, Opcode::Pong, b"hi");
        assert_eq!(pong, [0x8a, 2, b'h', b'i']);
    }

    #[test]
    fn unmasking_in_pieces_of_any_size_equals_unmasking_at_once() {
        let mask = [0x37, 0xfa, 0x21, 0x3d];
        let clear: Vec<u8> = (0..=255u8).cycle().take(300).collect();
        let mut masked = clear.clone();
        for (i, b) in masked.iter_mut().enumerate() {
            *b ^= mask[i % 4];
        }
        for piece in [1, 3, 7, 8, 13, 64, 300] {
            let mut wire = masked.clone();
            let mut at = 0;
            for chunk in wire.chunks_mut(piece) {
                unmask(chunk, mask, at);
                at += chunk.len();
            }
            assert_eq!(wire, clear, "pieces of {piece}");
        }
    }
}
