//! What a connection hands its complete messages to.

use core::net::SocketAddr;

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
    async fn open(&self, peer: Option<SocketAddr>) -> Self::Session;

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

    async fn open(&self, peer: Option<SocketAddr>) -> Session {
        let mut server = self.server.lock().await;
        match peer {
            Some(addr) => server.open_via(Some(addr.ip().into()), Via::WebSocket(addr)),
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

    async fn open(&self, _peer: Option<SocketAddr>) {}

    async fn handler(&self) -> Echo {
        Echo
    }

    async fn ready(&self, _ticket: Ticket) {}

    async fn close(&self, _session: ()) {}
}
