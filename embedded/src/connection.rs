//! One WebSocket connection over any `embedded_io_async` stream: our
//! handshake validation, our frame reader, embedded-websocket's `101`
//! response and frame writer, and a [`Service`] for complete messages.
//!
//! Every rule of DESIGN.md's "WebSocket behaviour" lives here: binary
//! messages, invalid UTF-8 and oversized messages are handed to the service
//! as such (the protocol answers 1003, 1007, 1009), pings are answered with
//! pongs, fragmented messages are reassembled in the message buffer, and a
//! close frame is answered with a close frame. Protocol violations fail the
//! connection with 1002. Nothing a peer sends can make this code panic.

use core::str::FromStr;

use embassy_time::{Duration, with_timeout};
use embedded_io_async::{Read, Write};
use embedded_websocket::{WebSocketCloseStatusCode, WebSocketKey, WebSocketSendMessageType, WebSocketServer};
use lluav_core::{CloseCode, Message, Outcome};

use crate::frame::{self, Header, Opcode};
use crate::handshake::{self, BAD_REQUEST, Rejection};
use crate::log::{debug, warning};
use crate::service::Service;

/// The smallest receive buffer: a whole control frame must fit, and so
/// must the `101` response embedded-websocket builds in the transmit buffer.
pub const MIN_RAW: usize = 256;

/// Room reserved in the transmit buffer for an unmasked server frame header.
pub const TX_HEADER: usize = 10;

/// The buffers of one connection, all borrowed from the caller.
pub struct Buffers<'b> {
    /// Raw bytes from the peer: the request head, then frames. At least
    /// [`MIN_RAW`] bytes; its size limits the request head.
    pub raw: &'b mut [u8],
    /// Reassembled messages: its size is the frame limit (larger messages close with 1009).
    pub message: &'b mut [u8],
    /// The service's reply; the largest reply is this size minus [`TX_HEADER`].
    pub response: &'b mut [u8],
    /// Outgoing frames; at least as large as `response`.
    pub transmit: &'b mut [u8],
}

/// Why a connection ended without a close handshake.
#[derive(Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Error<E> {
    /// The stream failed.
    Io(E),
    /// The peer closed the stream.
    PeerClosed,
    /// Nothing arrived within the idle timeout.
    Idle,
    /// The upgrade request was rejected (and answered with 400).
    Rejected(Rejection),
    /// The buffers are smaller than [`Buffers`] requires.
    Buffers,
    /// embedded-websocket refused to write a frame.
    Framing,
}

impl<E> From<E> for Error<E> {
    fn from(e: E) -> Self {
        Error::Io(e)
    }
}

/// Bytes received but not yet consumed: `raw[start..end]`.
struct Inbox<'b> {
    raw: &'b mut [u8],
    start: usize,
    end: usize,
    idle: Option<Duration>,
}

impl Inbox<'_> {
    fn pending(&self) -> &[u8] {
        self.raw.get(self.start..self.end).unwrap_or(&[])
    }

    /// Reads more bytes, first moving the pending ones to the front so that
    /// a header or control frame is always contiguous.
    async fn fill<T: Read>(&mut self, io: &mut T) -> Result<(), Error<T::Error>> {
        if self.start > 0 {
            self.raw.copy_within(self.start..self.end, 0);
            self.end -= self.start;
            self.start = 0;
        }
        let room = self
            .raw
            .get_mut(self.end..)
            .filter(|r| !r.is_empty())
            .ok_or(Error::Buffers)?;
        let n = match self.idle {
            Some(limit) => with_timeout(limit, io.read(room))
                .await
                .map_err(|_| Error::Idle)??,
            None => io.read(room).await?,
        };
        if n == 0 {
            return Err(Error::PeerClosed);
        }
        self.end += n;
        Ok(())
    }

    /// Reads until `len` bytes are pending.
    async fn want<T: Read>(&mut self, io: &mut T, len: usize) -> Result<(), Error<T::Error>> {
        while self.end - self.start < len {
            self.fill(io).await?;
        }
        Ok(())
    }
}

/// The sending side: embedded-websocket's frame writer and our stream.
struct Outbox<'b> {
    ws: WebSocketServer,
    transmit: &'b mut [u8],
}

impl Outbox<'_> {
    async fn send<T: Write>(
        &mut self,
        io: &mut T,
        kind: WebSocketSendMessageType,
        payload: &[u8],
    ) -> Result<(), Error<T::Error>> {
        let len = if payload.len() == 0xffff {
            // embedded-websocket 0.9.5 switches to the 64-bit length form
            // at 65535 instead of above it; RFC 6455 requires the minimal
            // (16-bit) form, and clients fail the connection otherwise
            // (Autobahn case 1.1.6).
            let opcode = match kind {
                WebSocketSendMessageType::Text => 0x1,
                WebSocketSendMessageType::Binary => 0x2,
                WebSocketSendMessageType::CloseReply => 0x8,
                WebSocketSendMessageType::Ping => 0x9,
                WebSocketSendMessageType::Pong => 0xa,
            };
            let frame = self.transmit.get_mut(..4 + payload.len()).ok_or(Error::Framing)?;
            frame[..4].copy_from_slice(&[0x80 | opcode, 126, 0xff, 0xff]);
            frame[4..].copy_from_slice(payload);
            frame.len()
        } else {
            self.ws
                .write(kind, true, payload, self.transmit)
                .map_err(|_| Error::Framing)?
        };
        self.flush(io, len).await
    }

    /// Carries out the service's answer; `Some(code)` when it closed.
    async fn respond<T: Write>(
        &mut self,
        io: &mut T,
        outcome: Outcome<'_>,
    ) -> Result<Option<u16>, Error<T::Error>> {
        match outcome {
            Outcome::Reply(text) => {
                self.send(io, WebSocketSendMessageType::Text, text.as_bytes())
                    .await?;
                Ok(None)
            }
            Outcome::ReplyThenClose(text, code) => {
                self.send(io, WebSocketSendMessageType::Text, text.as_bytes())
                    .await?;
                self.close(io, code).await.map(Some)
            }
            Outcome::Close(code) => self.close(io, code).await.map(Some),
            // Services wait for their backend (`Service::handle`); one that
            // did not broke its contract.
            Outcome::Pending(..) => self.close(io, CloseCode::InternalError).await.map(Some),
        }
    }

    /// Sends a close frame; returns the code for the caller to report.
    async fn close<T: Write>(&mut self, io: &mut T, code: CloseCode) -> Result<u16, Error<T::Error>> {
        let status = WebSocketCloseStatusCode::Custom(code.code());
        let len = self
            .ws
            .close(status, None, self.transmit)
            .map_err(|_| Error::Framing)?;
        self.flush(io, len).await?;
        Ok(code.code())
    }

    async fn flush<T: Write>(&mut self, io: &mut T, len: usize) -> Result<(), Error<T::Error>> {
        let bytes = self.transmit.get(..len).ok_or(Error::Framing)?;
        io.write_all(bytes).await?;
        io.flush().await?;
        Ok(())
    }
}

/// One WebSocket connection: [`Connection::accept`] the upgrade, then
/// [`Connection::run`] until it closes.
pub struct Connection<'b> {
    inbox: Inbox<'b>,
    outbox: Outbox<'b>,
    message: &'b mut [u8],
    response: &'b mut [u8],
}

impl<'b> Connection<'b> {
    /// A connection over `buffers`; `idle` closes it when nothing arrives for that long.
    pub fn new(buffers: Buffers<'b>, idle: Option<Duration>) -> Self {
        Connection {
            inbox: Inbox {
                raw: buffers.raw,
                start: 0,
                end: 0,
                idle,
            },
            outbox: Outbox {
                ws: WebSocketServer::new_server(),
                transmit: buffers.transmit,
            },
            message: buffers.message,
            response: buffers.response,
        }
    }

    /// Reads and validates the upgrade request and answers it: `101` on
    /// success, `400 Bad Request` (and an error) on anything else.
    pub async fn accept<T: Read + Write>(&mut self, io: &mut T) -> Result<(), Error<T::Error>> {
        if self.inbox.raw.len() < MIN_RAW
            || self.outbox.transmit.len() < MIN_RAW
            || self.response.len() <= TX_HEADER
        {
            return Err(Error::Buffers);
        }
        let head_len = loop {
            if let Some(n) = handshake::head_end(self.inbox.pending()) {
                break n;
            }
            if self.inbox.end == self.inbox.raw.len() {
                return reject(io, Rejection::TooLarge).await;
            }
            match self.inbox.fill(io).await {
                Err(Error::PeerClosed) => return Err(Error::Rejected(Rejection::Incomplete)),
                other => other?,
            }
        };
        let key = match handshake::parse(&self.inbox.raw[..head_len]) {
            Ok(upgrade) => WebSocketKey::from_str(upgrade.key).map_err(|()| Rejection::BadKey),
            Err(r) => Err(r),
        };
        let key = match key {
            Ok(key) => key,
            Err(r) => return reject(io, r).await,
        };
        self.inbox.start = head_len;
        // No subprotocol is selected: DESIGN.md requires none, and offered
        // names never reach embedded-websocket.
        let len = self
            .outbox
            .ws
            .server_accept(&key, None, self.outbox.transmit)
            .map_err(|_| Error::Framing)?;
        self.outbox.flush(io, len).await
    }

    /// Serves messages until the connection closes. `Ok(code)` is the close
    /// code of the close frame we sent (our own, or the answer to the
    /// peer's); the caller then closes the stream.
    pub async fn run<T: Read + Write, S: Service>(
        &mut self,
        io: &mut T,
        service: &S,
    ) -> Result<u16, Error<T::Error>> {
        let mut session = service.open();
        let reply_room = self.response.len().saturating_sub(TX_HEADER);
        // The opcode of the message being reassembled, and its length so far.
        let mut partial: Option<Opcode> = None;
        let mut len = 0usize;
        loop {
            let header = loop {
                match frame::parse_header(self.inbox.pending()) {
                    Ok(Some(h)) => break h,
                    Ok(None) => self.inbox.fill(io).await?,
                    Err(code) => return self.outbox.close(io, code).await,
                }
            };
            if header.opcode.is_control() {
                if let Some(code) = self.control(io, &header).await? {
                    return Ok(code);
                }
                continue;
            }
            match (header.opcode, partial) {
                (Opcode::Continuation, Some(_)) => {}
                (Opcode::Continuation, None) | (_, Some(_)) => {
                    return self.outbox.close(io, CloseCode::ProtocolError).await;
                }
                (opcode, None) => {
                    partial = Some(opcode);
                    len = 0;
                }
            }
            let room = self.message.len() - len;
            if header.len > room as u64 {
                let outcome = service
                    .handle(&mut session, Message::Oversized, &mut self.response[..reply_room])
                    .await;
                // The frame's payload is still unread, so the connection
                // cannot go on whatever the service answered.
                let closed = self.outbox.respond(io, outcome).await?;
                return match closed {
                    Some(code) => Ok(code),
                    None => self.outbox.close(io, CloseCode::TooBig).await,
                };
            }
            self.payload(io, &header, len).await?;
            len += header.len as usize;
            if !header.fin {
                continue;
            }
            let body = &self.message[..len];
            let message = match partial.take() {
                Some(Opcode::Binary) => Message::Binary(body),
                _ => Message::Text(body),
            };
            let outcome = service
                .handle(&mut session, message, &mut self.response[..reply_room])
                .await;
            if let Some(code) = self.outbox.respond(io, outcome).await? {
                return Ok(code);
            }
        }
    }

    /// Copies and unmasks a data frame's payload to `message[at..]`; the
    /// caller checked that it fits.
    async fn payload<T: Read>(
        &mut self,
        io: &mut T,
        header: &Header,
        at: usize,
    ) -> Result<(), Error<T::Error>> {
        self.inbox.start += header.header_len;
        let total = header.len as usize;
        let mut got = 0;
        while got < total {
            if self.inbox.start == self.inbox.end {
                self.inbox.fill(io).await?;
            }
            let take = (total - got).min(self.inbox.end - self.inbox.start);
            let dst = &mut self.message[at + got..at + got + take];
            dst.copy_from_slice(&self.inbox.raw[self.inbox.start..self.inbox.start + take]);
            frame::unmask(dst, header.mask, got);
            got += take;
            self.inbox.start += take;
        }
        Ok(())
    }

    /// Handles a control frame; `Some(code)` when the connection is closing.
    async fn control<T: Read + Write>(
        &mut self,
        io: &mut T,
        header: &Header,
    ) -> Result<Option<u16>, Error<T::Error>> {
        // parse_header bounds control payloads to MAX_CONTROL_PAYLOAD.
        let len = header.len as usize;
        self.inbox.want(io, header.header_len + len).await?;
        let from = self.inbox.start + header.header_len;
        self.inbox.start = from + len;
        let payload = &mut self.inbox.raw[from..from + len];
        frame::unmask(payload, header.mask, 0);
        match header.opcode {
            Opcode::Ping => {
                self.outbox
                    .send(io, WebSocketSendMessageType::Pong, payload)
                    .await?;
                Ok(None)
            }
            Opcode::Close => {
                let code = match payload {
                    [] => CloseCode::Normal.code(),
                    [_] => CloseCode::ProtocolError.code(),
                    [hi, lo, reason @ ..] => match u16::from_be_bytes([*hi, *lo]) {
                        code if !valid_close_code(code) => CloseCode::ProtocolError.code(),
                        _ if core::str::from_utf8(reason).is_err() => CloseCode::InvalidPayload.code(),
                        code => code,
                    },
                };
                debug!("peer closed with {}", code);
                let status = WebSocketCloseStatusCode::Custom(code);
                let n = self
                    .outbox
                    .ws
                    .close(status, None, self.outbox.transmit)
                    .map_err(|_| Error::Framing)?;
                self.outbox.flush(io, n).await?;
                Ok(Some(code))
            }
            _ => Ok(None),
        }
    }
}

async fn reject<T: Write>(io: &mut T, why: Rejection) -> Result<(), Error<T::Error>> {
    warning!("upgrade rejected: {:?}", why);
    io.write_all(BAD_REQUEST).await?;
    io.flush().await?;
    Err(Error::Rejected(why))
}

/// Close codes a peer may send (RFC 6455, section 7.4): the defined ones
/// that may appear on the wire, and the registered and private ranges.
fn valid_close_code(code: u16) -> bool {
    matches!(code, 1000..=1003 | 1007..=1011 | 3000..=4999)
}
