//! The daemon's network layer: accepting, TLS, the HTTP upgrade, framing,
//! limits and shutdown. Everything here is about sockets; nothing is about
//! the protocol.
//!
//! - [`listener`]: the accept loop, the handshake and session pools and
//!   the per-address limits ([`slots`]), shutdown;
//! - [`handshake`]: the request head, read, judged by the core (RFC 6455,
//!   the `Origin` and `Host` rules with the operator's [`policy`] lists and
//!   the address the connection arrived on), answered `101` or refused; a
//!   plain HTTP request goes to the daemon's [`Http`] handler;
//! - [`connection`]: one session after its `101`, the [`Connection`]:
//!   WebSocket frames (the core's [`lluav_core::websocket`] codec) read
//!   and assembled by a [`reader`], written by [`frame`] (the socket
//!   I/O: [`wire`]), replies written into [`buffers`] lent per message;
//!   while a command is pending the session reads on ([`waiting`]);
//! - [`tls`]: `wss://` with rustls;
//! - [`report`]: log lines about misbehaving clients, rate-limited.
//!
//! Each connection hands every complete message to a [`Handler`] as a core
//! [`Message`] and carries out the [`Outcome`]. The protocol handler
//! ([`crate::daemon::Protocol`]) and the Autobahn echo handler ([`Echo`])
//! share this code path, so what Autobahn tests is what clients get.

pub mod buffers;
pub mod connection;
pub mod frame;
pub mod handshake;
pub mod listener;
pub mod policy;
pub mod reader;
pub mod report;
pub mod slots;
pub mod subscriber;
pub mod tls;
pub mod waiting;
pub mod wire;
pub mod woken;

use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use lluav_core::{Message, Outcome};

pub use connection::Connection;
pub use listener::{Config, serve, serve_stream};
pub use policy::Policy;

/// Answers a plain HTTP request (anything but a WebSocket upgrade) on the
/// WebSocket port, given its method and target as sent: the whole answer,
/// ready to write (the connection then closes). The daemon passes the
/// console's, so that this layer knows nothing of the application.
pub type Http = Arc<dyn Fn(&str, &str) -> Vec<u8> + Send + Sync>;

/// What a connection does with each complete message.
pub trait Handler: Send + Sync + 'static {
    /// Per-connection state (for the protocol: the login [`lluav_core::Session`]).
    type Session: Send + 'static;

    /// State for a new connection from `peer`.
    fn session(&self, peer: SocketAddr) -> Self::Session;

    /// Whether the session may stay without a login deadline and may not
    /// be reclaimed for a newcomer: logged in, or no login needed.
    fn admitted(&self, session: &Self::Session) -> bool;

    /// Handles one message; the reply may borrow from `message` or `out`.
    /// `out` holds [`Limits::response_capacity`] bytes. The answer may take
    /// a while (an autopilot's acknowledgement); other connections are
    /// served meanwhile, and this one answers pings and reads on, its later
    /// messages waiting their turn ([`waiting`]). The future is run to its
    /// end even if the peer closes meanwhile. Never [`Outcome::Pending`].
    fn handle<'o>(
        &'o self,
        session: &'o mut Self::Session,
        message: Message<'o>,
        out: &'o mut [u8],
    ) -> impl Future<Output = Outcome<'o>> + Send + 'o;

    /// The replies queued for `session` were written to its socket (what
    /// a reply caused may now be told to others: the events stream).
    fn written(&self, session: &Self::Session) {
        let _ = session;
    }

    /// The connection of `session` has ended.
    fn closed(&self, session: Self::Session) {
        let _ = session;
    }

    /// A subscription to the vehicle's events, for an admitted session of
    /// the `/events` endpoint ([`subscriber`]); `None` when this handler
    /// has none (the endpoint then answers 404).
    fn subscribe(&self) -> Option<crate::events::Subscriber> {
        None
    }
}

/// Echoes every text message back unchanged and otherwise follows the
/// core's close policy ([`Message::text`]: binary → 1003, oversized →
/// 1009). Used to run the Autobahn|Testsuite against this module's
/// connection code.
#[derive(Clone, Copy, Debug, Default)]
pub struct Echo;

impl Handler for Echo {
    type Session = ();

    fn session(&self, _: SocketAddr) {}

    fn admitted(&self, _: &()) -> bool {
        true
    }

    async fn handle<'o>(&'o self, _: &'o mut (), message: Message<'o>, _: &'o mut [u8]) -> Outcome<'o> {
        match message.text() {
            Ok(text) => Outcome::Reply(text),
            Err(code) => Outcome::Close(code),
        }
    }
}

/// After refusing a request or closing a session, how long the rest of what
/// the client sent is read and discarded, so that closing does not reset
/// the connection before the client has read the answer.
const LINGER: Duration = Duration::from_secs(1);

/// Connection limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Limits {
    /// Largest message (and frame) accepted, in bytes; larger closes with 1009.
    pub max_message: usize,
    /// Most sessions served at once; more are refused with HTTP 503 (after
    /// reclaiming sessions that have not logged in).
    pub max_connections: usize,
    /// Most sessions from one client address.
    pub max_sessions_per_ip: usize,
    /// Most handshakes in progress at once; beyond it the oldest is dropped.
    pub max_handshakes: usize,
    /// Most handshakes in progress from one client address.
    pub max_handshakes_per_ip: usize,
    /// Time from accept to a complete request head (TLS included).
    pub handshake_timeout: Duration,
    /// With a password configured, a session not logged in after this long
    /// is closed with 1008; pings do not extend it.
    pub login_timeout: Duration,
    /// A connection that sends nothing for this long is closed.
    pub idle_timeout: Duration,
    /// Bytes of the per-connection response buffer.
    pub response_capacity: usize,
    /// Time allowed for a peer to take one reply or answer a close.
    pub io_timeout: Duration,
    /// At shutdown, time allowed for connections to finish before they are
    /// dropped.
    pub shutdown_grace: Duration,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            max_message: 64 * 1024,
            max_connections: 256,
            max_sessions_per_ip: 8,
            max_handshakes: 128,
            max_handshakes_per_ip: 8,
            handshake_timeout: Duration::from_secs(5),
            login_timeout: Duration::from_secs(10),
            idle_timeout: Duration::from_secs(300),
            response_capacity: 64 * 1024,
            io_timeout: Duration::from_secs(10),
            shutdown_grace: Duration::from_secs(10),
        }
    }
}
