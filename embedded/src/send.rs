//! The sending half of a connection: the `101` answer, control frames and
//! text replies, each written straight into the transport's transmit
//! buffer.
//!
//! # What embedded-websocket does, and what it never sees
//!
//! embedded-websocket 0.9.5 (no default features) builds the `101
//! Switching Protocols` answer with its `Sec-WebSocket-Accept` value (the
//! SHA-1 and base64 of the client's key and the protocol's GUID:
//! `WebSocketServer::server_accept`), frames every pong and close frame
//! (`write`: ours and the answer to the peer's are the same frame), and
//! its state refuses any frame after a close frame. All of that is written
//! by it straight into the socket's transmit buffer, in the space
//! [`transport::reserve`] made contiguous (so are our own refusals: the
//! status of a [`Rejection`], no body).
//!
//! It is wrapped so that none of its hazards reaches a board:
//!
//! - It never reads a byte from the peer. Its header reader
//!   (`read_http_header`, whose 24-byte strings `unwrap` an over-long
//!   `Sec-WebSocket-Key` or `Sec-WebSocket-Protocol`: a halted board) and
//!   its frame reader (which lets through reserved bits, unmasked client
//!   frames and over-long or fragmented control frames) are not used:
//!   the core's [`lluav_core::websocket`] (the upgrade check, the
//!   Origin/Host policy, frames) stays in front, and hands it only a key
//!   the core accepted (24 base64 characters) and no subprotocol (none is
//!   selected).
//! - Its `WebSocketKey` is a 24-byte heapless string whose `From<&str>`
//!   panics on a longer one: the key is converted with `parse`, which
//!   fails instead ([`websocket_key`]).
//! - `server_accept` copies its answer into its output with a slice
//!   index, a panic if the output is short: it is given exactly
//!   [`ANSWER_LEN`] bytes, the length of its answer (a test pins it). It
//!   builds that answer in a 1 KiB string on the stack first: 1.5 KB of
//!   stack for [`Sender::send`], during the handshake only.
//! - It writes a 65,535-byte payload with the 64-bit length form (RFC 6455
//!   requires the 16-bit one; Autobahn case 1.1.6): it only frames control
//!   payloads, at most 125 bytes, so that never shows.
//!
//! # Text replies: framed in place, the header ours
//!
//! The protocol core writes its reply straight into the transmit buffer,
//! behind room for the frame header ([`write_reply`]), so a reply is
//! never copied. embedded-websocket's `write` takes the payload as a slice
//! of its own (`from: &[u8]`) and copies it behind the header it writes
//! into `to: &mut [u8]`: a payload already lying in `to` cannot be handed
//! to it (a buffer is lent either shared or mutable, and this crate has no
//! `unsafe`), and it has no call that writes a header alone (it takes the
//! length from the payload). Framing replies with it would take a second
//! reply buffer for the core to write into (2 KiB of RAM on the firmware,
//! even shared by every session under the service's lock) and a copy of
//! every reply, so a text frame's 2 or 4 header bytes are written by
//! [`write_header`].

use embedded_websocket::{WebSocketKey, WebSocketSendMessageType, WebSocketServer};
use lluav_core::websocket::handshake::KEY_LEN;
use lluav_core::websocket::{MAX_CONTROL_PAYLOAD, Opcode, header_len, write_header};
use lluav_core::{CloseCode, Outcome, Ticket};

use crate::error::{Error, Rejection};
use crate::transport::{self, Transport};

/// The length of embedded-websocket's `101` answer without a subprotocol:
/// the status line, `Connection`, `Upgrade`, and the 28-character
/// `Sec-WebSocket-Accept` value.
pub(crate) const ANSWER_LEN: usize = 129;

/// embedded-websocket's form of a key the core's upgrade check accepted
/// (24 base64 characters, so it always fits).
pub(crate) fn websocket_key(key: &[u8; KEY_LEN]) -> Option<WebSocketKey> {
    core::str::from_utf8(key).ok()?.parse().ok()
}

/// What a reply written in place asks for next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Sent {
    /// The reply was written; the connection goes on.
    Reply,
    /// The reply was written; close with this code.
    ReplyThenClose(CloseCode),
    /// Nothing was written; close with this code.
    Close(CloseCode),
    /// Nothing written: ask again once the service says the ticket is ready.
    Pending(Ticket),
}

/// The sending state of one connection: embedded-websocket's server.
pub(crate) struct Sender {
    ws: WebSocketServer,
}

impl Sender {
    pub(crate) fn new() -> Self {
        Sender {
            ws: WebSocketServer::new_server(),
        }
    }

    /// Writes `what` straight into the transmit buffer, once a contiguous
    /// run of it can hold all of it.
    pub(crate) async fn send<T: Transport>(
        &mut self,
        io: &mut T,
        what: Outgoing<'_>,
    ) -> Result<(), Error<T::Error>> {
        let len = what.len();
        if !transport::reserve(io, len).await? {
            return Err(Error::Buffers);
        }
        let ws = &mut self.ws;
        let mut written = false;
        transport::write(
            io,
            &mut |room| match room.get_mut(..len).and_then(|out| what.write(ws, out)) {
                Some(n) => {
                    written = true;
                    n
                }
                None => 0,
            },
        )
        .await?;
        if written { Ok(()) } else { Err(Error::Framing) }
    }
}

/// What the connection sends in one piece, besides text replies.
#[derive(Clone, Copy, Debug)]
pub(crate) enum Outgoing<'a> {
    /// The HTTP status refusing an upgrade request (ours).
    Refusal(Rejection),
    /// The `101 Switching Protocols` answer to a request with this key
    /// (validated by the core's upgrade check); frames may be sent from
    /// then on.
    Switch(&'a [u8; KEY_LEN]),
    /// A pong carrying a ping's payload (at most 125 bytes, as
    /// [`lluav_core::websocket`] checked).
    Pong(&'a [u8]),
    /// A close frame with this code: ours, starting the closing
    /// handshake, or the answer to the peer's, ending it (the same frame;
    /// embedded-websocket frames nothing after it either way).
    Close(u16),
}

impl Outgoing<'_> {
    /// Its length in bytes.
    fn len(&self) -> usize {
        match self {
            Outgoing::Refusal(_) => REFUSAL.len(),
            Outgoing::Switch(_) => ANSWER_LEN,
            Outgoing::Pong(payload) => 2 + payload.len(),
            Outgoing::Close(_) => 4,
        }
    }

    /// Writes it into `out`, which is [`Outgoing::len`] bytes long;
    /// `None` if embedded-websocket refuses (a frame after a close frame,
    /// or a payload over 125 bytes).
    fn write(self, ws: &mut WebSocketServer, out: &mut [u8]) -> Option<usize> {
        let code;
        let (kind, payload) = match self {
            Outgoing::Refusal(why) => return Some(write_refusal(why, out)),
            Outgoing::Switch(key) => {
                let n = ws.server_accept(&websocket_key(key)?, None, out).ok()?;
                return (n == ANSWER_LEN).then_some(n);
            }
            Outgoing::Pong(payload) if payload.len() <= MAX_CONTROL_PAYLOAD => {
                (WebSocketSendMessageType::Pong, payload)
            }
            Outgoing::Pong(_) => return None,
            Outgoing::Close(c) => {
                code = c.to_be_bytes();
                (WebSocketSendMessageType::CloseReply, &code[..])
            }
        };
        let n = ws.write(kind, true, payload, out).ok()?;
        (n == 2 + payload.len()).then_some(n)
    }
}

/// Every refusal: its status code goes in place of the zeros. No reason
/// phrase (RFC 9112 allows an empty one, and clients ignore it), no body,
/// and the connection closes: one template for every status.
const REFUSAL: &[u8; 55] = b"HTTP/1.1 000 \r\nConnection: close\r\nContent-Length: 0\r\n\r\n";

/// Writes the answer refusing a request for `why` into `out`, which is
/// [`REFUSAL`]'s length; returns that length.
fn write_refusal(why: Rejection, out: &mut [u8]) -> usize {
    let (code, _) = why.status();
    out.copy_from_slice(REFUSAL);
    for (digit, unit) in out.iter_mut().skip(9).zip([100, 10, 1]) {
        *digit = b'0' + (code / unit % 10) as u8;
    }
    REFUSAL.len()
}

/// Runs `handle` on the reply room of `room` (`capacity` bytes behind room
/// for the longest header) and frames its reply in place; returns the
/// bytes to send and what comes next.
pub(crate) fn write_reply(
    room: &mut [u8],
    capacity: usize,
    handle: impl for<'o> FnOnce(&'o mut [u8]) -> Outcome<'o>,
) -> (usize, Sent) {
    let reserve = header_len(capacity);
    let Some(window) = room.get_mut(..reserve + capacity) else {
        return (0, Sent::Close(CloseCode::InternalError));
    };
    let Some(body) = window.get_mut(reserve..) else {
        return (0, Sent::Close(CloseCode::InternalError));
    };
    let start = body.as_ptr();
    let (len, sent) = match handle(body) {
        Outcome::Close(code) => return (0, Sent::Close(code)),
        Outcome::Pending(ticket, _) => return (0, Sent::Pending(ticket)),
        // A reply must be written where the handler was asked to write it.
        Outcome::Reply(r) if core::ptr::eq(r.as_ptr(), start) => (r.len(), Sent::Reply),
        Outcome::ReplyThenClose(r, code) if core::ptr::eq(r.as_ptr(), start) => {
            (r.len(), Sent::ReplyThenClose(code))
        }
        _ => return (0, Sent::Close(CloseCode::InternalError)),
    };
    let header = header_len(len);
    if len > capacity {
        return (0, Sent::Close(CloseCode::InternalError));
    }
    // The header was given room for the longest reply; a shorter one
    // moves the reply up to meet it.
    window.copy_within(reserve..reserve + len, header);
    match write_header(window, Opcode::Text, len) {
        Some(_) => (header + len, sent),
        None => (0, Sent::Close(CloseCode::InternalError)),
    }
}

#[cfg(feature = "streamed-echo")]
/// Sends `payload` as one text frame, copied into the transmit buffer in
/// as many pieces as its free space takes: for an answer that already
/// lies elsewhere (an echo, in the message buffer), which the transmit
/// buffer then need not hold whole.
pub(crate) async fn write_text<T: Transport>(io: &mut T, payload: &[u8]) -> Result<(), Error<T::Error>> {
    let head = header_len(payload.len());
    if !transport::reserve(io, head).await? {
        return Err(Error::Buffers);
    }
    let mut framed = false;
    transport::write(io, &mut |room| match room
        .get_mut(..head)
        .and_then(|out| write_header(out, Opcode::Text, payload.len()))
    {
        Some(n) => {
            framed = true;
            n
        }
        None => 0,
    })
    .await?;
    if !framed {
        return Err(Error::Framing);
    }
    let mut rest = payload;
    while !rest.is_empty() {
        let mut copied = 0;
        transport::write(io, &mut |room| {
            let n = room.len().min(rest.len());
            if let (Some(to), Some(from)) = (room.get_mut(..n), rest.get(..n)) {
                to.copy_from_slice(from);
                copied = n;
            }
            copied
        })
        .await?;
        rest = rest.get(copied..).unwrap_or_default();
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use lluav_core::websocket::handshake;

    use super::*;

    /// The RFC 6455 example: its key and the accept value answering it.
    const KEY: &[u8; KEY_LEN] = b"dGhlIHNhbXBsZSBub25jZQ==";

    fn open() -> WebSocketServer {
        let mut ws = WebSocketServer::new_server();
        ws.server_accept(&websocket_key(KEY).unwrap(), None, &mut [0; ANSWER_LEN])
            .unwrap();
        ws
    }

    #[test]
    fn the_101_answer_carries_the_rfc_accept_value_in_answer_len_bytes() {
        let mut out = [0u8; 512];
        let n = WebSocketServer::new_server()
            .server_accept(&websocket_key(KEY).unwrap(), None, &mut out)
            .unwrap();
        assert_eq!(n, ANSWER_LEN);
        assert_eq!(
            &out[..n],
            b"HTTP/1.1 101 Switching Protocols\r\nConnection: Upgrade\r\nUpgrade: websocket\r\n\
Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n\r\n"
        );
    }

    #[test]
    fn control_frames_are_unmasked_and_final() {
        let mut out = [0u8; 127];
        let mut ws = open();
        let n = ws
            .write(WebSocketSendMessageType::Pong, true, &[7; 125], &mut out)
            .unwrap();
        assert_eq!((n, out[0], out[1]), (127, 0x8a, 125));
        assert!(out[2..n].iter().all(|&b| b == 7));
        let n = ws
            .write(
                WebSocketSendMessageType::CloseReply,
                true,
                &1001u16.to_be_bytes(),
                &mut out,
            )
            .unwrap();
        assert_eq!(out[..n], [0x88, 2, 0x03, 0xe9]);
    }

    #[test]
    fn nothing_is_framed_after_a_close_frame() {
        let mut out = [0u8; 8];
        let mut ws = open();
        let n = Outgoing::Close(4000).write(&mut ws, &mut out[..4]).unwrap();
        assert_eq!(out[..n], [0x88, 2, 0x0f, 0xa0]);
        assert_eq!(Outgoing::Pong(&[]).write(&mut ws, &mut out[..2]), None);
        assert_eq!(Outgoing::Close(1000).write(&mut ws, &mut out[..4]), None);
    }

    #[test]
    fn refusals_carry_their_status_and_close() {
        let mut out = [0u8; REFUSAL.len()];
        let refused = Rejection::Request(handshake::Rejection::UpgradeRequired);
        let n = Outgoing::Refusal(refused).write(&mut open(), &mut out).unwrap();
        assert_eq!(n, REFUSAL.len());
        assert_eq!(
            &out[..],
            b"HTTP/1.1 426 \r\nConnection: close\r\nContent-Length: 0\r\n\r\n"
        );
        let n = Outgoing::Refusal(Rejection::TooManySessions)
            .write(&mut open(), &mut out)
            .unwrap();
        assert!(out[..n].starts_with(b"HTTP/1.1 429 \r\n"));
    }

    #[test]
    fn a_short_output_is_an_error_not_a_panic() {
        let mut ws = open();
        assert!(
            ws.write(WebSocketSendMessageType::Pong, true, &[1, 2, 3], &mut [0; 4])
                .is_err()
        );
    }
}
