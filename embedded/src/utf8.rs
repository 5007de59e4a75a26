//! UTF-8 validation of a text message while it arrives, so that invalid
//! text fails the connection at the first bad byte (RFC 6455, section 8.1:
//! "fail fast"), not when the last fragment is in.

/// How far a growing text message is known to be valid.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Utf8 {
    /// `message[..valid]` is valid UTF-8 ending on a character boundary.
    valid: usize,
}

/// What the bytes received so far say about the message.
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

#[cfg(test)]
mod tests {
    use super::*;

    fn feed(pieces: &[&[u8]]) -> (Verdict, bool) {
        let mut message = [0u8; 64];
        let mut len = 0;
        let mut utf8 = Utf8::new();
        let mut verdict = Verdict::Open;
        for piece in pieces {
            message[len..len + piece.len()].copy_from_slice(piece);
            len += piece.len();
            verdict = utf8.extend(&message[..len]);
            if verdict == Verdict::Invalid {
                break;
            }
        }
        (verdict, utf8.complete(len))
    }

    #[test]
    fn a_character_split_between_pieces_is_valid() {
        let smiley = "\u{263A}".as_bytes();
        assert_eq!(
            feed(&[b"a", &smiley[..1], &smiley[1..2], &smiley[2..]]),
            (Verdict::Open, true)
        );
    }

    #[test]
    fn a_message_ending_inside_a_character_is_incomplete() {
        assert_eq!(
            feed(&[b"ab", &"\u{263A}".as_bytes()[..2]]),
            (Verdict::Open, false)
        );
    }

    #[test]
    fn an_invalid_byte_fails_before_the_message_ends() {
        assert_eq!(feed(&[b"valid", b"\xff", b"never read"]).0, Verdict::Invalid);
    }

    #[test]
    fn a_code_point_above_the_unicode_range_fails_at_its_second_byte() {
        // 0xF4 0x90 would start U+110000: invalid as soon as 0x90 arrives.
        assert_eq!(feed(&[b"\xf4", b"\x90"]).0, Verdict::Invalid);
    }

    #[test]
    fn surrogates_and_overlong_forms_fail() {
        assert_eq!(feed(&[b"\xed\xa0\x80"]).0, Verdict::Invalid);
        assert_eq!(feed(&[b"\xc0\xaf"]).0, Verdict::Invalid);
    }
}
