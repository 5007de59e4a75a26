//! Incoming frame headers, validated against RFC 6455 before any payload
//! is read, and payload unmasking.
//!
//! Parsing checks every rule a server must enforce (reserved bits, masked
//! client frames, control frames unfragmented and at most 125 bytes, 64-bit
//! lengths with the top bit clear) before any payload is read, never panics
//! and never reads past the slice it is given. The header of a text reply
//! is written by [`write_text_header`] (unmasked, with the minimal length form
//! RFC 6455 requires), in front of the reply the protocol core already
//! wrote into the transmit buffer; control frames are framed by
//! embedded-websocket (see `send.rs` for why the split).

use lluav_core::CloseCode;

/// The largest payload a control frame may carry.
pub const MAX_CONTROL_PAYLOAD: usize = 125;

/// The longest client frame header: 2 bytes, 8 of extended length, 4 of mask.
pub const MAX_HEADER: usize = 14;

/// A frame's opcode (RFC 6455, section 5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
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
}

/// A validated client frame header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Whether this frame ends its message.
    pub fin: bool,
    /// The opcode.
    pub opcode: Opcode,
    /// The payload length, as sent (it may exceed the adapter's limit).
    pub len: u64,
    /// The masking key (clients must mask every frame).
    pub mask: [u8; 4],
    /// The header's length in bytes.
    pub header_len: usize,
}

/// Parses the header at the start of `buf`: `Ok(None)` when more bytes are
/// needed, `Err(code)` when the frame breaks the protocol and the
/// connection must be failed with that close code.
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
        127 => match rest.get(..8) {
            Some(bytes) => {
                let mut be = [0; 8];
                be.copy_from_slice(bytes);
                let len = u64::from_be_bytes(be);
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
    let Some(key) = rest.get(ext..ext + 4) else {
        return Ok(None);
    };
    let mut mask = [0; 4];
    mask.copy_from_slice(key);
    Ok(Some(Header {
        fin,
        opcode,
        len,
        mask,
        header_len: 2 + ext + 4,
    }))
}

/// Unmasks `payload` in place; `offset` is the position of its first byte
/// within the frame's payload (frames arrive in pieces).
pub fn unmask(payload: &mut [u8], mask: [u8; 4], offset: usize) {
    for (b, m) in payload.iter_mut().zip(mask.iter().cycle().skip(offset % 4)) {
        *b ^= m;
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

/// Writes a final (FIN) unmasked text frame header for a `len`-byte
/// payload at the start of `out`; returns its length, or `None` if `out`
/// is shorter.
pub fn write_text_header(out: &mut [u8], len: usize) -> Option<usize> {
    let n = header_len(len);
    let head = out.get_mut(..n)?;
    let (first, rest) = head.split_first_mut()?;
    *first = 0x81;
    let (second, extended) = rest.split_first_mut()?;
    match n {
        2 => *second = len as u8,
        4 => {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn waits_for_a_complete_header() {
        assert_eq!(parse_header(&[0x81]), Ok(None));
        assert_eq!(parse_header(&[0x81, 0xfe, 0x01]), Ok(None));
        assert_eq!(parse_header(&[0x81, 0x85, 1, 2, 3]), Ok(None));
    }

    #[test]
    fn reads_16_and_64_bit_lengths() {
        let h = parse_header(&[0x81, 0xfe, 0x01, 0x00, 1, 2, 3, 4])
            .unwrap()
            .unwrap();
        assert_eq!((h.len, h.header_len, h.mask), (256, 8, [1, 2, 3, 4]));
        let h = parse_header(&[0x02, 0xff, 0, 0, 0, 1, 0, 0, 0, 0, 9, 9, 9, 9])
            .unwrap()
            .unwrap();
        assert_eq!(
            (h.len, h.header_len, h.fin, h.opcode),
            (1 << 32, 14, false, Opcode::Binary)
        );
    }

    #[test]
    fn fails_frames_the_rfc_forbids() {
        let bad: [&[u8]; 6] = [
            &[0xc1, 0x80, 0, 0, 0, 0],                   // RSV1 without an extension
            &[0x83, 0x80, 0, 0, 0, 0],                   // reserved opcode
            &[0x81, 0x00],                               // unmasked client frame
            &[0x09, 0x80, 0, 0, 0, 0],                   // fragmented ping
            &[0x89, 0xfe, 0, 126, 0, 0, 0, 0],           // ping over 125 bytes
            &[0x81, 0xff, 0x80, 0, 0, 0, 0, 0, 0, 0, 0], // 64-bit length with its top bit set
        ];
        for frame in bad {
            assert_eq!(parse_header(frame), Err(CloseCode::ProtocolError), "{frame:?}");
        }
    }

    #[test]
    fn writes_the_minimal_length_form() {
        let mut out = [0u8; 10];
        assert_eq!(write_text_header(&mut out, 125), Some(2));
        assert_eq!(out[..2], [0x81, 125]);
        assert_eq!(write_text_header(&mut out, 126), Some(4));
        assert_eq!(out[..4], [0x81, 126, 0, 126]);
        // 65535 still fits the 16-bit form (Autobahn case 1.1.6).
        assert_eq!(write_text_header(&mut out, 0xffff), Some(4));
        assert_eq!(out[..4], [0x81, 126, 0xff, 0xff]);
        assert_eq!(write_text_header(&mut out, 0x10000), Some(10));
        assert_eq!(out, [0x81, 127, 0, 0, 0, 0, 0, 1, 0, 0]);
        assert_eq!(write_text_header(&mut out[..3], 126), None);
    }

    #[test]
    fn unmasks_across_pieces() {
        let mask = [0x37, 0xfa, 0x21, 0x3d];
        let mut wire = *b"\x7f\x9f\x4d\x51\x58";
        let (a, b) = wire.split_at_mut(2);
        unmask(a, mask, 0);
        unmask(b, mask, 2);
        assert_eq!(&wire, b"Hello");
    }
}
