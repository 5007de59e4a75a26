//! LLUAV on embassy: the companion-microcontroller adapter.
//!
//! [`serve`] runs `N` concurrent WebSocket sessions on an embassy-net
//! [`Stack`] (port [`PORT`] by default), each in a [`Slot`] of buffers the
//! firmware allocates statically, and hands every complete message to a
//! [`Service`]: [`SharedServer`] (lluav-core's [`Server`](lluav_core::Server)
//! behind an embassy-sync mutex) for the protocol, [`Echo`] for conformance
//! testing on the same code path. The crate is `no_std` and allocates
//! nothing; it runs on a board and, unchanged, on embassy's std platform.
//!
//! The upgrade request is validated by [`handshake`], frames by [`frame`]:
//! no peer input reaches embedded-websocket's panicking header parser or its
//! lenient frame reader (see those modules). embedded-websocket builds the
//! `101` response and writes outgoing frames.
//!
//! ```no_run
//! # async fn firmware(stack: embassy_net::Stack<'static>, server: lluav_core::Server<impl lluav_core::Backend, impl lluav_core::Clock>) -> ! {
//! use embassy_sync::blocking_mutex::raw::NoopRawMutex;
//! use lluav_embedded::{Config, SharedServer, Slot, serve};
//!
//! static SLOTS: static_cell::ConstStaticCell<[Slot<2048, 1024, 4096, 2048>; 4]> =
//!     static_cell::ConstStaticCell::new([const { Slot::new() }; 4]);
//! let shared = SharedServer::<NoopRawMutex, _, _>::new(server);
//! serve(stack, &Config::new(), &shared, SLOTS.take()).await
//! # }
//! ```
#![no_std]
#![warn(missing_docs)]

mod log;

pub mod board;
pub mod connection;
pub mod frame;
pub mod handshake;
pub mod service;

use embassy_futures::join::join_array;
use embassy_net::Stack;
use embassy_net::tcp::TcpSocket;
use embassy_time::{Duration, with_timeout};
use lluav_core::MIN_RESPONSE_CAPACITY;

pub use connection::{Buffers, Connection, Error, MIN_RAW, TX_HEADER};
pub use lluav_core;
pub use service::{Echo, Service, SharedServer};

use crate::log::{debug, info, warning};

/// The protocol's TCP port.
pub const PORT: u16 = 53001;

/// Connection settings.
#[derive(Clone, Copy, Debug)]
pub struct Config {
    /// The TCP port to listen on.
    pub port: u16,
    /// How long a client may take to send its upgrade request.
    pub handshake_timeout: Duration,
    /// Close a session when nothing arrives for this long (`None`: never).
    pub idle_timeout: Option<Duration>,
    /// How long to wait for the peer to close after our close frame.
    pub close_timeout: Duration,
    /// TCP keep-alive interval, so that vanished peers free their slot.
    pub keep_alive: Option<Duration>,
    /// Abort the TCP connection when sent data stays unacknowledged this long.
    pub tcp_timeout: Option<Duration>,
}

impl Config {
    /// Port [`PORT`], 10 s for the handshake, 5 min idle, 2 s to close,
    /// keep-alive every 30 s, 60 s TCP timeout.
    pub const fn new() -> Self {
        Config {
            port: PORT,
            handshake_timeout: Duration::from_secs(10),
            idle_timeout: Some(Duration::from_secs(300)),
            close_timeout: Duration::from_secs(2),
            keep_alive: Some(Duration::from_secs(30)),
            tcp_timeout: Some(Duration::from_secs(60)),
        }
    }
}

impl Default for Config {
    fn default() -> Self {
        Config::new()
    }
}

/// The buffers of one session: TCP receive and transmit (`TCP` bytes each),
/// raw WebSocket input (`RAW`, at least [`MIN_RAW`]; it also bounds the
/// upgrade request), the frame limit (`FRAME`) and the response buffer
/// (`OUT`, at least [`MIN_RESPONSE_CAPACITY`] + [`TX_HEADER`]).
///
/// [`Slot::new`] is `const`, so an array of slots can live in a static
/// initialised in place (e.g. `static_cell::ConstStaticCell`), never built
/// on a task's stack first.
pub struct Slot<const TCP: usize, const RAW: usize, const FRAME: usize, const OUT: usize> {
    tcp_rx: [u8; TCP],
    tcp_tx: [u8; TCP],
    raw: [u8; RAW],
    message: [u8; FRAME],
    response: [u8; OUT],
    transmit: [u8; OUT],
}

impl<const TCP: usize, const RAW: usize, const FRAME: usize, const OUT: usize> Slot<TCP, RAW, FRAME, OUT> {
    /// Zeroed buffers; sizes below the minimums fail to compile.
    pub const fn new() -> Self {
        const {
            assert!(RAW >= MIN_RAW, "RAW must hold MIN_RAW bytes");
            assert!(
                OUT >= MIN_RESPONSE_CAPACITY + TX_HEADER,
                "OUT is below the core's minimum"
            );
        }
        Slot {
            tcp_rx: [0; TCP],
            tcp_tx: [0; TCP],
            raw: [0; RAW],
            message: [0; FRAME],
            response: [0; OUT],
            transmit: [0; OUT],
        }
    }
}

impl<const TCP: usize, const RAW: usize, const FRAME: usize, const OUT: usize> Default
    for Slot<TCP, RAW, FRAME, OUT>
{
    fn default() -> Self {
        Slot::new()
    }
}

/// Serves `service` on `stack` with one concurrent session per slot, for
/// ever. The stack needs one socket per slot (plus any the firmware uses
/// itself, e.g. DHCP).
pub async fn serve<
    S,
    const N: usize,
    const TCP: usize,
    const RAW: usize,
    const FRAME: usize,
    const OUT: usize,
>(
    stack: Stack<'_>,
    config: &Config,
    service: &S,
    slots: &mut [Slot<TCP, RAW, FRAME, OUT>; N],
) -> !
where
    S: Service,
{
    join_array(slots.each_mut().map(|slot| session(stack, config, service, slot))).await;
    // Only reached with N = 0: there is nothing to serve.
    loop {
        core::future::pending::<()>().await;
    }
}

/// Accepts and serves connections in one slot, one after another.
async fn session<S: Service, const TCP: usize, const RAW: usize, const FRAME: usize, const OUT: usize>(
    stack: Stack<'_>,
    config: &Config,
    service: &S,
    slot: &mut Slot<TCP, RAW, FRAME, OUT>,
) {
    loop {
        let mut socket = TcpSocket::new(stack, &mut slot.tcp_rx, &mut slot.tcp_tx);
        socket.set_timeout(config.tcp_timeout);
        socket.set_keep_alive(config.keep_alive);
        if let Err(e) = socket.accept(config.port).await {
            warning!("accept failed: {:?}", e);
            continue;
        }
        debug!("connection from {:?}", socket.remote_endpoint());
        let buffers = Buffers {
            raw: &mut slot.raw,
            message: &mut slot.message,
            response: &mut slot.response,
            transmit: &mut slot.transmit,
        };
        let mut connection = Connection::new(buffers, config.idle_timeout);
        let ended = match with_timeout(config.handshake_timeout, connection.accept(&mut socket)).await {
            Ok(Ok(())) => connection.run(&mut socket, service).await,
            Ok(Err(e)) => Err(e),
            Err(_) => Err(Error::Idle),
        };
        match ended {
            Ok(code) => info!("session closed with {}", code),
            Err(e) => info!("session ended: {:?}", e),
        }
        // Our FIN first (RFC 6455 7.1.1: the server closes TCP first), then
        // wait for the peer's, so its last frames are not answered by a RST.
        socket.close();
        let _ = with_timeout(config.close_timeout, drain(&mut socket)).await;
        socket.abort();
        let _ = with_timeout(config.close_timeout, socket.flush()).await;
    }
}

/// Discards input until the peer closes its side.
async fn drain(socket: &mut TcpSocket<'_>) {
    let mut sink = [0u8; 64];
    while let Ok(n @ 1..) = socket.read(&mut sink).await {
        let _ = n;
    }
}
