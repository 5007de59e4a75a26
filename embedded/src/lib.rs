//! LLUAV on embassy: the companion-microcontroller adapter.
//!
//! [`serve`] runs `N` concurrent WebSocket sessions on an embassy-net
//! [`Stack`](embassy_net::Stack) (port [`PORT`] by default), each in a
//! [`Slot`] the firmware allocates statically, and hands every complete
//! message to a [`Service`]: [`SharedServer`] (lluav-core's
//! [`Server`](lluav_core::Server) behind an embassy-sync mutex) for the
//! protocol, [`Echo`] for conformance testing on the same code path. The
//! crate is `no_std`, allocates nothing and has no `unsafe`; it runs on a
//! board and, unchanged, on embassy's std platform.
//!
//! A slot is the session's two TCP buffers and its message buffer: frames
//! are read straight out of the socket's receive buffer and replies written
//! straight into its transmit buffer ([`connection`] says how, and why the
//! message buffer remains). The upgrade request (its form and the Origin
//! and Host policy) and the frames are judged by the core's
//! [`lluav_core::websocket`], shared with lluavd, given the address each
//! connection arrived on; [`admission`] decides who gets the few slots (a spare listener,
//! eviction of half-open and not-logged-in connections, per-address
//! limits, deadlines). embedded-websocket builds the `101` answer (its
//! `Sec-WebSocket-Accept` value) and frames pongs and close frames; it
//! never sees a byte the peer sent before our own validation did.
//!
//! ```no_run
//! # async fn firmware(stack: embassy_net::Stack<'static>, server: lluav_core::Server<impl lluav_core::Backend, impl lluav_core::Clock>) -> ! {
//! use embassy_sync::blocking_mutex::raw::NoopRawMutex;
//! use lluav_embedded::{Config, SharedServer, Slot, serve};
//!
//! static SLOTS: static_cell::ConstStaticCell<[Slot<1024, 2304, 4096, 2048>; 4]> =
//!     static_cell::ConstStaticCell::new([const { Slot::new() }; 4]);
//! let shared = SharedServer::<NoopRawMutex, _, _>::new(server);
//! serve(stack, &Config::new(), &shared, SLOTS.take()).await
//! # }
//! ```
#![no_std]
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![deny(
    clippy::indexing_slicing,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic
)]
#![cfg_attr(
    test,
    allow(
        clippy::indexing_slicing,
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic
    )
)]

#[cfg(any(test, feature = "testing"))]
extern crate std;

mod log;

pub mod admission;
pub mod board;
pub mod connection;
pub mod error;
pub mod firmware;
mod receive;
mod send;
mod serve;
pub mod service;
#[cfg(feature = "testing")]
pub mod testing;
pub mod transport;

use embassy_time::Duration;

pub use connection::{Connection, Limits, MIN_MESSAGE};
pub use error::{Error, Rejection};
pub use lluav_core;
pub use serve::{Slot, serve, serve_slot};
pub use service::{Echo, Handler, Service, SharedServer};
pub use transport::Transport;

/// The protocol's TCP port.
pub const PORT: u16 = 53001;

/// Connection settings.
#[derive(Clone, Copy, Debug)]
pub struct Config {
    /// The TCP port to listen on.
    pub port: u16,
    /// How long a client may take to send its whole upgrade request,
    /// from the moment its connection is accepted.
    pub handshake_timeout: Duration,
    /// With a password required, how long a session may stay without
    /// logging in after its upgrade (then it is closed with 1008).
    pub login_timeout: Duration,
    /// Close a session when nothing arrives for this long (`None`: never).
    pub idle_timeout: Option<Duration>,
    /// How long to wait for the peer to close after our close frame.
    pub close_timeout: Duration,
    /// TCP keep-alive interval, so that vanished peers free their slot.
    pub keep_alive: Option<Duration>,
    /// Abort the TCP connection when sent data stays unacknowledged this long.
    pub tcp_timeout: Option<Duration>,
    /// Sessions one IP address may hold at once.
    pub max_sessions_per_address: usize,
    /// Handshakes one IP address may have in progress at once.
    pub max_handshakes_per_address: usize,
    /// How old a connection that has not logged in must be before a
    /// newcomer may evict it (see [`admission`]).
    pub reclaim_after: Duration,
    /// Origins accepted besides the vehicle's own (`*`: any); see
    /// [`lluav_core::websocket::policy`].
    pub allowed_origins: &'static [&'static str],
    /// `Host` names accepted besides the adapter's address; see
    /// [`lluav_core::websocket::policy`].
    pub allowed_hosts: &'static [&'static str],
}

impl Config {
    /// Port [`PORT`], 3 s for the handshake, 10 s to log in, 5 min idle,
    /// 2 s to close, keep-alive every 30 s, 60 s TCP timeout, two sessions
    /// and two handshakes per address, eviction after 500 ms, no extra
    /// origins or host names.
    pub const fn new() -> Self {
        Config {
            port: PORT,
            handshake_timeout: Duration::from_secs(3),
            login_timeout: Duration::from_secs(10),
            idle_timeout: Some(Duration::from_secs(300)),
            close_timeout: Duration::from_secs(2),
            keep_alive: Some(Duration::from_secs(30)),
            tcp_timeout: Some(Duration::from_secs(60)),
            max_sessions_per_address: 2,
            max_handshakes_per_address: 2,
            reclaim_after: Duration::from_millis(500),
            allowed_origins: &[],
            allowed_hosts: &[],
        }
    }
}

impl Default for Config {
    fn default() -> Self {
        Config::new()
    }
}
