//! The accept loop of every slot, and a slot's buffers.

use core::net::{IpAddr, SocketAddrV4};

use embassy_futures::join::join_array;
use embassy_futures::select::{Either, select};
use embassy_net::Stack;
use embassy_net::tcp::{Error as TcpError, TcpSocket};
use embassy_time::{Instant, with_timeout};
use lluav_core::MIN_RESPONSE_CAPACITY;
use lluav_core::websocket::handshake::Upgrade;
use lluav_core::websocket::header_len;
use lluav_core::websocket::policy::Policy;

use crate::Config;
use crate::admission::{Offense, Refusal, Table};
use crate::connection::{Connection, Limits, MIN_MESSAGE};
use crate::error::Error;
use crate::log::{debug, info, warning};
use crate::service::{Handler, Service};

/// The buffers of one session: the TCP receive buffer (`RX` bytes: the
/// receive window), the TCP transmit buffer (`TX`, at least `OUT` plus
/// the frame header), and the message buffer (`FRAME`, the frame limit,
/// at least [`MIN_MESSAGE`]). `OUT` is the reply capacity the protocol
/// core gets (at least [`MIN_RESPONSE_CAPACITY`]); it is written inside
/// the transmit buffer, so it costs no memory of its own.
///
/// [`Slot::new`] is `const`, so an array of slots can live in a static
/// initialised in place (e.g. `static_cell::ConstStaticCell`), never built
/// on a task's stack first.
pub struct Slot<const RX: usize, const TX: usize, const FRAME: usize, const OUT: usize> {
    rx: [u8; RX],
    tx: [u8; TX],
    message: [u8; FRAME],
}

impl<const RX: usize, const TX: usize, const FRAME: usize, const OUT: usize> Slot<RX, TX, FRAME, OUT> {
    /// Zeroed buffers; sizes below the minimums fail to compile.
    pub const fn new() -> Self {
        const {
            assert!(RX > 0, "RX must not be empty");
            assert!(FRAME >= MIN_MESSAGE, "FRAME must hold MIN_MESSAGE bytes");
            assert!(OUT >= MIN_RESPONSE_CAPACITY, "OUT is below the core's minimum");
            assert!(
                TX >= OUT + header_len(OUT),
                "TX must hold a whole reply and its header"
            );
        }
        Slot {
            rx: [0; RX],
            tx: [0; TX],
            message: [0; FRAME],
        }
    }
}

impl<const RX: usize, const TX: usize, const FRAME: usize, const OUT: usize> Default
    for Slot<RX, TX, FRAME, OUT>
{
    fn default() -> Self {
        Slot::new()
    }
}

/// Serves `service` on `stack` with one concurrent session per slot, for
/// ever, all in the calling task. The stack needs one socket per slot
/// (plus any the firmware uses itself, e.g. DHCP). See [`crate::admission`]
/// for who gets a slot.
///
/// Every slot's loop is a future joined in this one, so the task holds them
/// all and polling them copies them through its stack frame; a firmware
/// runs [`serve_slot`] in one task per slot instead.
pub async fn serve<
    S,
    const N: usize,
    const RX: usize,
    const TX: usize,
    const FRAME: usize,
    const OUT: usize,
>(
    stack: Stack<'_>,
    config: &Config,
    service: &S,
    slots: &mut [Slot<RX, TX, FRAME, OUT>; N],
) -> !
where
    S: Service,
{
    let table = Table::<N>::new();
    let mut next = 0;
    let loops = slots.each_mut().map(|slot| {
        let index = next;
        next += 1;
        serve_slot(stack, config, &table, index, service, slot)
    });
    join_array(loops).await;
    // Only reached with N = 0: there is nothing to serve.
    loop {
        core::future::pending::<()>().await;
    }
}

/// Serves slot `index` of `table` with `slot`'s buffers, for ever: one
/// connection after another. Run one per slot, each in a task of its own
/// (on one executor: the table's cells are not shared across threads),
/// every one with the same `table`, `stack`, `config` and `service`; the
/// stack needs one socket per slot.
pub async fn serve_slot<
    S,
    const N: usize,
    const RX: usize,
    const TX: usize,
    const FRAME: usize,
    const OUT: usize,
>(
    stack: Stack<'_>,
    config: &Config,
    table: &Table<N>,
    index: usize,
    service: &S,
    slot: &mut Slot<RX, TX, FRAME, OUT>,
) -> !
where
    S: Service,
{
    let place = Place {
        stack,
        config,
        table,
        index,
    };
    place.run(service, slot).await
}

/// How a connection ended, for the teardown and the log.
enum End {
    /// Refused on arrival.
    Refused(Refusal),
    /// Evicted to keep a slot listening.
    Evicted,
    /// The handshake did not complete in time.
    Slow,
    /// The connection ran its course.
    Done(Result<u16, Error<TcpError>>),
}

/// One slot's place in the table, and what its loop needs.
struct Place<'a, const N: usize> {
    stack: Stack<'a>,
    config: &'a Config,
    table: &'a Table<N>,
    index: usize,
}

impl<const N: usize> Place<'_, N> {
    /// Accepts and serves connections in this slot, one after another.
    async fn run<S: Service, const RX: usize, const TX: usize, const FRAME: usize, const OUT: usize>(
        self,
        service: &S,
        slot: &mut Slot<RX, TX, FRAME, OUT>,
    ) -> ! {
        let config = self.config;
        loop {
            let mut socket = TcpSocket::new(self.stack, &mut slot.rx, &mut slot.tx);
            socket.set_timeout(config.tcp_timeout);
            socket.set_keep_alive(config.keep_alive);
            self.table.listening(self.index);
            if let Err(e) = socket.accept(config.port).await {
                warning!("accept failed: {:?}", e);
                self.table.ended(self.index);
                continue;
            }
            let peer: Option<IpAddr> = socket.remote_endpoint().map(|e| e.addr.into());
            debug!("connection from {:?}", peer);
            let end = match self.table.arrive(self.index, peer, config, Instant::now()) {
                Err(why) => End::Refused(why),
                Ok(victim) => {
                    if let Some(victim) = victim {
                        debug!("slot {} evicted for a newcomer", victim);
                    }
                    // The session, if the connection gets one, is closed
                    // however the connection ends.
                    let mut session = None;
                    let served =
                        self.connection(&mut socket, service, peer, &mut session, &mut slot.message, OUT);
                    let end = match select(served, self.table.evicted(self.index)).await {
                        Either::First(end) => end,
                        Either::Second(()) => End::Evicted,
                    };
                    if let Some(session) = session {
                        service.close(session).await;
                    }
                    end
                }
            };
            self.report(peer, &end);
            // Our FIN first (RFC 6455 7.1.1: the server closes TCP first),
            // then the peer's, so its last frames are not answered by a
            // RST; meanwhile the slot keeps its phase, so a rejected
            // handshake can still be evicted. Connections that got no
            // session are reset at once.
            if matches!(end, End::Done(_)) {
                self.table.closing(self.index);
                let graceful = async {
                    socket.close();
                    let _ = with_timeout(config.close_timeout, drain(&mut socket)).await;
                };
                select(graceful, self.table.evicted(self.index)).await;
            }
            socket.abort();
            let _ = with_timeout(config.close_timeout, socket.flush()).await;
            self.table.ended(self.index);
        }
    }

    /// The handshake, then the session (kept in `session` so that it is
    /// closed however the connection ends).
    async fn connection<S: Service>(
        &self,
        socket: &mut TcpSocket<'_>,
        service: &S,
        peer: Option<IpAddr>,
        session: &mut Option<S::Session>,
        message: &mut [u8],
        reply: usize,
    ) -> End {
        let config = self.config;
        let Some(local) = socket.local_endpoint() else {
            return End::Done(Err(Error::PeerClosed));
        };
        let limits = Limits {
            reply,
            idle: config.idle_timeout,
            close: config.close_timeout,
        };
        let mut conn = Connection::new(message, limits);
        let accepted = {
            let policy = Policy {
                local: local.addr.into(),
                tls: false,
                allowed_origins: config.allowed_origins,
                allowed_hosts: config.allowed_hosts,
            };
            let admit = |_: &Upgrade<'_>| self.table.may_open(self.index, peer, config);
            with_timeout(config.handshake_timeout, conn.accept(socket, &policy, admit)).await
        };
        match accepted {
            Err(_) => return End::Slow,
            Ok(Err(e)) => return End::Done(Err(e)),
            Ok(Ok(())) => {}
        }
        let remote = socket.remote_endpoint().map(|e| match e.addr {
            embassy_net::IpAddress::Ipv4(ip) => SocketAddrV4::new(ip, e.port),
        });
        let session = session.insert(service.open(remote).await);
        let admitted = service.handler().await.admitted(session);
        self.table.opened(self.index, admitted);
        if !admitted {
            conn.set_login_deadline(Some(Instant::now() + config.login_timeout));
        }
        let ended = conn
            .run(socket, service, session, |now| self.table.admit(self.index, now))
            .await;
        End::Done(ended)
    }

    /// Logs how a connection ended; offenses at most once a minute per address.
    fn report(&self, peer: Option<IpAddr>, end: &End) {
        let offense = match end {
            End::Refused(why) => Offense::Refused(*why),
            End::Evicted => Offense::Evicted,
            End::Slow => Offense::SlowHandshake,
            End::Done(Err(Error::LoginTimeout)) => Offense::NoLogin,
            End::Done(Err(Error::Rejected(why))) => Offense::Rejected(*why),
            End::Done(Ok(code)) => return info!("session closed with {}", code),
            End::Done(Err(e)) => return info!("session ended: {:?}", e),
        };
        if let Some(unlogged) = self.table.offense(peer, Instant::now()) {
            warning!("{:?}: {:?} ({} more events unlogged)", peer, offense, unlogged);
        }
    }
}

/// Discards input until the peer closes its side.
async fn drain(socket: &mut TcpSocket<'_>) {
    while let Ok(1..) = crate::transport::read(socket, &mut |bytes| bytes.len()).await {}
}
