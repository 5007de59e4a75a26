//! What a connection hands its complete messages to.

use embassy_sync::blocking_mutex::raw::RawMutex;
use embassy_sync::mutex::{Mutex, MutexGuard};
use embassy_time::{Duration, Timer};
use lluav_core::{Backend, Clock, CloseCode, Message, Outcome, Server};

/// How often a command the backend left pending is asked again.
const PENDING_POLL: Duration = Duration::from_millis(5);

/// Handles the complete messages of every connection.
///
/// The adapter owns sockets and framing; a service owns what a message
/// means. [`SharedServer`] is the protocol; [`Echo`] is the conformance
/// configuration (Autobahn|Testsuite) on the very same connection code.
// Futures of embassy tasks never cross threads, so the `Send` bound that
// `async_fn_in_trait` warns about would only exclude single-core executors.
#[allow(async_fn_in_trait)]
pub trait Service {
    /// Per-connection state.
    type Session;

    /// The state of a newly accepted connection.
    fn open(&self) -> Self::Session;

    /// Answers one complete message, writing any reply into `out`; never
    /// [`Outcome::Pending`].
    async fn handle<'o>(
        &self,
        session: &mut Self::Session,
        message: Message<'_>,
        out: &'o mut [u8],
    ) -> Outcome<'o>;
}

/// The protocol server for one vehicle, shared by every connection.
///
/// The lock is held only for the synchronous [`Server::handle`] call, never
/// across network I/O, so a slow client never delays the others. A command
/// the backend leaves pending is asked again every [`PENDING_POLL`] with the
/// lock released, so other sessions go on meanwhile.
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

impl<M: RawMutex, B: Backend, C: Clock> Service for SharedServer<M, B, C> {
    type Session = lluav_core::Session;

    fn open(&self) -> Self::Session {
        lluav_core::Session::new()
    }

    async fn handle<'o>(
        &self,
        session: &mut Self::Session,
        message: Message<'_>,
        out: &'o mut [u8],
    ) -> Outcome<'o> {
        let mut outcome = self.server.lock().await.handle(session, message, out);
        while let Outcome::Pending(_, buf) = outcome {
            Timer::after(PENDING_POLL).await;
            outcome = self.server.lock().await.resume(session, buf);
        }
        outcome
    }
}

/// Echoes every text message back; the close policy is the protocol's
/// (binary 1003, invalid UTF-8 1007, oversized 1009).
#[derive(Clone, Copy, Debug, Default)]
pub struct Echo;

impl Service for Echo {
    type Session = ();

    fn open(&self) -> Self::Session {}

    async fn handle<'o>(&self, _: &mut (), message: Message<'_>, out: &'o mut [u8]) -> Outcome<'o> {
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
}
