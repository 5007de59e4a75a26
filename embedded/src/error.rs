//! Why a connection ended without a close handshake, and why an upgrade
//! request was refused (with the HTTP status it is answered with).

use lluav_core::websocket::handshake;

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
    /// The session did not log in before its deadline (a 1008 close frame
    /// was sent if the transmit buffer had room for it).
    LoginTimeout,
    /// The upgrade request was rejected (and answered with its status).
    Rejected(Rejection),
    /// The buffers are smaller than [`Limits`](crate::Limits) and
    /// [`MIN_MESSAGE`](crate::MIN_MESSAGE) require.
    Buffers,
    /// embedded-websocket refused to write a frame (never expected: its
    /// room in the transmit buffer is reserved first, and nothing is sent
    /// after a close frame).
    Framing,
}

impl<E> From<E> for Error<E> {
    fn from(e: E) -> Self {
        Error::Io(e)
    }
}

/// Why an upgrade request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// The peer closed the connection before its request head was complete
    /// (nothing is answered).
    Incomplete,
    /// The core's upgrade check or Origin/Host policy refused the request.
    Request(handshake::Rejection),
    /// A plain HTTP request: this adapter serves nothing but the protocol.
    NotUpgrade,
    /// The peer's address already holds as many sessions as one address may.
    TooManySessions,
}

impl Rejection {
    /// The HTTP status code and reason phrase it is answered with.
    pub fn status(self) -> (u16, &'static str) {
        match self {
            Rejection::Request(why) => why.status(),
            Rejection::TooManySessions => (429, "Too Many Requests"),
            Rejection::Incomplete | Rejection::NotUpgrade => (400, "Bad Request"),
        }
    }
}

impl From<handshake::Rejection> for Rejection {
    fn from(why: handshake::Rejection) -> Self {
        Rejection::Request(why)
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for Rejection {
    fn format(&self, f: defmt::Formatter<'_>) {
        match self {
            Rejection::Incomplete => defmt::write!(f, "Incomplete"),
            Rejection::Request(why) => defmt::write!(f, "Request({=u16})", why.status().0),
            Rejection::NotUpgrade => defmt::write!(f, "NotUpgrade"),
            Rejection::TooManySessions => defmt::write!(f, "TooManySessions"),
        }
    }
}
