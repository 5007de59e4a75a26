//! A message across its frames (RFC 6455, section 5.4), and the answer to
//! a peer's close frame (section 5.5.1).

use super::frame::{Header, Opcode, Utf8, Verdict};
use crate::server::{CloseCode, Message};

/// Why a data frame cannot join the message in progress.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Interrupt {
    /// It breaks the fragmentation rules: fail the connection with this code.
    Fail(CloseCode),
    /// It would make the message longer than the limit: the service gets
    /// [`Message::Oversized`] (and the protocol closes with 1009).
    Oversized,
}

/// The data message being received: its kind, its length so far, and how
/// far its text is known to be valid. The adapter keeps the bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Fragments {
    kind: Option<Opcode>,
    len: usize,
    utf8: Utf8,
}

impl Fragments {
    /// No message in progress.
    pub const fn new() -> Self {
        Fragments {
            kind: None,
            len: 0,
            utf8: Utf8::new(),
        }
    }

    /// Checks a frame's header against the message in progress before its
    /// payload is read: a continuation must continue a message, a text or
    /// binary frame must start one (then it does), and the message may not
    /// grow beyond `limit` bytes. Control frames, which may come between
    /// the frames of a message, pass and change nothing.
    pub fn begin(&mut self, header: &Header, limit: usize) -> Result<(), Interrupt> {
        match (header.opcode, self.kind) {
            (opcode, _) if opcode.is_control() => return Ok(()),
            (Opcode::Continuation, Some(_)) => {}
            (Opcode::Continuation, None) | (_, Some(_)) => {
                return Err(Interrupt::Fail(CloseCode::ProtocolError));
            }
            (opcode, None) => {
                *self = Fragments {
                    kind: Some(opcode),
                    ..Fragments::new()
                };
            }
        }
        if header.len > limit.saturating_sub(self.len) as u64 {
            return Err(Interrupt::Oversized);
        }
        Ok(())
    }

    /// Takes note of the payload received: `message` is the whole message
    /// so far, unmasked, and `complete` says whether its last frame is all
    /// in. What a text message adds is checked for UTF-8 as it arrives, so
    /// invalid text fails at its first bad byte; a complete message is left
    /// to [`Message::text`], which checks every message the service gets,
    /// so that a message arriving whole is checked once, not twice.
    pub fn extend(&mut self, message: &[u8], complete: bool) -> Verdict {
        self.len = message.len();
        if self.kind == Some(Opcode::Text) && !complete {
            self.utf8.extend(message)
        } else {
            Verdict::Open
        }
    }

    /// Payload bytes of the message received so far.
    pub fn received(&self) -> usize {
        self.len
    }

    /// Whether a message has started and not been [`Fragments::reset`].
    pub fn in_progress(&self) -> bool {
        self.kind.is_some()
    }

    /// The message for the service, its bytes `body`: binary if it started
    /// with a binary frame, text otherwise.
    pub fn message<'m>(&self, body: &'m [u8]) -> Message<'m> {
        match self.kind {
            Some(Opcode::Binary) => Message::Binary(body),
            _ => Message::Text(body),
        }
    }

    /// Forgets the message: it was handed to the service, or only the
    /// peer's close frame matters any more.
    pub fn reset(&mut self) {
        *self = Fragments::new();
    }
}

/// The code to answer a peer's close frame with, given its unmasked
/// `payload`: its own code echoed (section 5.5.1), 1000 when it has none,
/// 1002 for a one-byte payload or a code no endpoint may send, 1007 for a
/// reason that is not UTF-8.
pub fn close_reply(payload: &[u8]) -> u16 {
    let code = match payload {
        [] => CloseCode::Normal,
        [_] => CloseCode::ProtocolError,
        [hi, lo, reason @ ..] => match u16::from_be_bytes([*hi, *lo]) {
            // Defined and sendable (1004-1006 and 1015 are not), registered
            // with IANA (1012-1014), or for libraries and applications.
            code @ (1000..=1003 | 1007..=1014 | 3000..=4999) => {
                if core::str::from_utf8(reason).is_ok() {
                    return code;
                }
                CloseCode::InvalidPayload
            }
            _ => CloseCode::ProtocolError,
        },
    };
    code.code()
}
