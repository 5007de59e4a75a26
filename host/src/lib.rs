//! LLUAV on the host (tokio): the `lluavd` daemon, its simulated vehicle and
//! the `lluav` client library.
//!
//! - [`daemon`]: the vehicle behind lluav-core's server, ticked and flushed;
//! - [`ws`]: the WebSocket layer (framing, limits, shutdown) every
//!   connection goes through;
//! - [`config`]: `lluavd`'s command line and config file;
//! - [`client`]: the typed async client `lluav` is built on;
//! - [`onboard`]: the daemon's backend, a [`companion`] computer and a
//!   vehicle (the simulator, [`sim`]) composed;
//! - [`recent_log`]: the log `showmsg` shows.

#![warn(missing_docs)]

pub mod client;
pub mod companion;
pub mod config;
pub mod daemon;
pub mod mavlink;
pub mod onboard;
pub mod recent_log;
pub mod sim;
pub mod ws;
