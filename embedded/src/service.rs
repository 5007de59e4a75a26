//! What a connection hands its complete messages to.

use core::net::{IpAddr, SocketAddrV4};

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::{Mutex, MutexGuard};
use embassy_time::{Duration, Timer};
use lluav_core::{Backend, Clock, CloseCode, Message, Outcome, Server, Session, Ticket, Via};

/// How often [`SharedServer`] asks a backend again about a command it left
/// pending.
pub const PENDING_POLL: Duration = Duration::from_millis(5);

/// Handles the complete messages of every connection.
///
/// The adapter owns sockets and framing; a service owns what a message
/// means. [`SharedServer`] is the protocol; [`Echo`] is the conformance
/// configuration (Autobahn|Testsuite) on the very same connection code.
///
/// A reply is written by the [`Handler`] straight into the connection's
/// transmit buffer, so the connection first waits (with nothing locked)
/// until that buffer has room for a whole reply, then takes the handler,
/// which holds it only for the synchronous [`Handler::handle`] call.
// Futures of embassy tasks never cross threads, so the `Send` bound that
// `async_fn_in_trait` warns about would only exclude single-core executors.
#[allow(async_fn_in_trait)]
pub trait Service {
    /// Per-connection state.
    type Session;
    /// Whether every valid text message is answered with itself (the
    /// echo). With feature `streamed-echo` the connection then streams
    /// text without asking the handler: each piece of a text message that
    /// fits the message buffer is unmasked and checked for UTF-8 there and
    /// sent on at once as a frame of a fragmented echo, so that text
    /// messages of any length (Autobahn's 16 MiB on a board) pass through
    /// buffers of a fixed size; invalid UTF-8 closes with 1007 at its
    /// first bad byte. Binary messages are still gathered and handed over.
    const ECHOES_TEXT: bool = false;
    /// Exclusive access for handling one message (e.g. a mutex guard).
    type Handler<'a>: Handler<Session = Self::Session>
    where
        Self: 'a;

    /// The state of a connection from `peer` whose upgrade was accepted.
    async fn open(&self, peer: Option<SocketAddrV4>) -> Self::Session;

    /// Waits for exclusive access to handle a message.
    async fn handler(&self) -> Self::Handler<'_>;

    /// Waits (with nothing locked) until it is time to ask again about
    /// `ticket`, which [`Handler::handle`] or [`Handler::resume`] answered
    /// [`Outcome::Pending`].
    async fn ready(&self, ticket: Ticket);

    /// The connection of `session` has ended.
    async fn close(&self, session: Self::Session);
}

/// Handles one message at a time, with exclusive access.
pub trait Handler {
    /// Per-connection state (the service's).
    type Session;

    /// Answers one complete message, writing any reply at the start of
    /// `out` (the reply must be a prefix of `out`).
    fn handle<'o>(
        &mut self,
        session: &mut Self::Session,
        message: Message<'_>,
        out: &'o mut [u8],
    ) -> Outcome<'o>;

    /// Answers the message `session` is waiting for, once
    /// [`Service::ready`] returned; like [`Handler::handle`], and it may be
    /// [`Outcome::Pending`] again.
    fn resume<'o>(&mut self, session: &mut Self::Session, out: &'o mut [u8]) -> Outcome<'o>;

    /// Whether `session` may run commands now: it has logged in, or no
    /// password is required. A connection whose session is not admitted
    /// is the first to give up its slot, and is closed at the login
    /// deadline.
    fn admitted(&self, session: &Self::Session) -> bool;
}

/// The protocol server for one vehicle, shared by every connection.
///
/// The lock is held only while one message is handled (a synchronous
/// [`Server::handle`] call writing into a transmit buffer that already has
/// room), never while waiting for the network, so a slow client never
/// delays the others. A command the backend leaves pending is asked about
/// again ([`Server::resume`], which calls `Backend::finish`, which may
/// answer pending again) every [`PENDING_POLL`], with the lock released,
/// so other sessions go on meanwhile: a board's backend needs no way to
/// wake the adapter, and one poll is a few hundred instructions.
pub struct SharedServer<M: RawMutex, B, C> {
    server: Mutex<M, Server<B, C>>,
}

impl<M: RawMutex, B: Backend, C: Clock> SharedServer<M, B, C> {
    /// Shares `server` between connections.
    pub fn new(server: Server<B, C>) -> Self {
        SharedServer {
            server: Mutex::new(server),
        }
    }

    /// Locks the server, e.g. for the firmware to update its backend.
    pub async fn lock(&self) -> MutexGuard<'_, M, Server<B, C>> {
        self.server.lock().await
    }
}

/// The protocol server, locked for one message.
pub struct Locked<'a, M: RawMutex, B, C>(MutexGuard<'a, M, Server<B, C>>);

impl<M: RawMutex, B: Backend, C: Clock> Handler for Locked<'_, M, B, C> {
    type Session = Session;

    fn handle<'o>(&mut self, session: &mut Session, message: Message<'_>, out: &'o mut [u8]) -> Outcome<'o> {
        self.0.handle(session, message, out)
    }

    fn resume<'o>(&mut self, session: &mut Session, out: &'o mut [u8]) -> Outcome<'o> {
        self.0.resume(session, out)
    }

    fn admitted(&self, session: &Session) -> bool {
        session.logged_in() || !self.0.auth().password_required()
    }
}

impl<M: RawMutex, B: Backend, C: Clock> Service for SharedServer<M, B, C> {
    type Session = Session;
    type Handler<'a>
        = Locked<'a, M, B, C>
    where
        Self: 'a;

    async fn open(&self, peer: Option<SocketAddrV4>) -> Session {
        let mut server = self.server.lock().await;
        match peer {
            Some(addr) => {
                let text = Address::of(addr);
                server.open_via(Some(IpAddr::V4(*addr.ip()).into()), Via::WebSocket(text.as_str()))
            }
            None => server.open(None),
        }
    }

    async fn handler(&self) -> Locked<'_, M, B, C> {
        Locked(self.server.lock().await)
    }

    async fn ready(&self, _ticket: Ticket) {
        Timer::after(PENDING_POLL).await;
    }

    async fn close(&self, session: Session) {
        self.server.lock().await.close(&session);
    }
}

/// Echoes every text message back; the close policy is the protocol's
/// ([`Message::text`]: binary 1003, invalid UTF-8 1007, oversized 1009).
#[derive(Clone, Copy, Debug, Default)]
pub struct Echo;

impl Handler for Echo {
    type Session = ();

    fn handle<'o>(&mut self, _: &mut (), message: Message<'_>, out: &'o mut [u8]) -> Outcome<'o> {
        let text = match message.text() {
            Ok(text) => text,
            Err(code) => return Outcome::Close(code),
        };
        let Some(dst) = out.get_mut(..text.len()) else {
            return Outcome::Close(CloseCode::TooBig);
        };
        dst.copy_from_slice(text.as_bytes());
        match core::str::from_utf8(dst) {
            Ok(echo) => Outcome::Reply(echo),
            Err(_) => Outcome::Close(CloseCode::InternalError),
        }
    }

    /// Never called: the echo never pends.
    fn resume<'o>(&mut self, _: &mut (), _: &'o mut [u8]) -> Outcome<'o> {
        Outcome::Close(CloseCode::InternalError)
    }

    fn admitted(&self, _: &()) -> bool {
        true
    }
}

impl Service for Echo {
    type Session = ();
    const ECHOES_TEXT: bool = true;
    type Handler<'a> = Echo;

    async fn open(&self, _peer: Option<SocketAddrV4>) {}

    async fn handler(&self) -> Echo {
        Echo
    }

    async fn ready(&self, _ticket: Ticket) {}

    async fn close(&self, _session: ()) {}
}

/// An IPv4 address and port as text (`192.0.2.7:51234`), for a session's
/// label: written digit by digit, since `core::fmt` would cost the
/// firmware kilobytes of flash.
struct Address {
    bytes: [u8; 21],
    len: usize,
}

impl Address {
    fn of(addr: SocketAddrV4) -> Address {
        let mut a = Address {
            bytes: [0; 21],
            len: 0,
        };
        for (i, octet) in addr.ip().octets().into_iter().enumerate() {
            if i > 0 {
                a.push(b'.');
            }
            a.number(u32::from(octet));
        }
        a.push(b':');
        a.number(u32::from(addr.port()));
        a
    }

    fn push(&mut self, b: u8) {
        if let Some(slot) = self.bytes.get_mut(self.len) {
            *slot = b;
            self.len += 1;
        }
    }

    fn number(&mut self, n: u32) {
        let mut digits = [0u8; 5];
        let mut i = digits.len();
        let mut n = n;
        loop {
            i -= 1;
            if let Some(d) = digits.get_mut(i) {
                *d = b'0' + (n % 10) as u8;
            }
            n /= 10;
            if n == 0 || i == 0 {
                break;
            }
        }
        for &d in digits.get(i..).unwrap_or_default() {
            self.push(d);
        }
    }

    fn as_str(&self) -> &str {
        self.bytes
            .get(..self.len)
            .and_then(|b| core::str::from_utf8(b).ok())
            .unwrap_or("")
    }
}

#[cfg(test)]
mod tests {
    use core::net::{Ipv4Addr, SocketAddrV4};

    use super::Address;

    fn assert_written(address: SocketAddrV4, expected: &str) {
        assert_eq!(Address::of(address).as_str(), expected);
    }

    #[test]
    fn an_address_is_written_as_a_client_would_read_it() {
        assert_written(
            SocketAddrV4::new(Ipv4Addr::new(192, 0, 2, 7), 51234),
            "192.0.2.7:51234",
        );
        assert_written(SocketAddrV4::new(Ipv4Addr::new(10, 0, 0, 0), 0), "10.0.0.0:0");
        assert_written(
            SocketAddrV4::new(Ipv4Addr::BROADCAST, 65535),
            "255.255.255.255:65535",
        );
    }
}
