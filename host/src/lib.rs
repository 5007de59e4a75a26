//! LLUAV on the host (tokio): the `lluavd` daemon, its simulated vehicle and
//! the `lluav` client library.
//!
//! - [`daemon`]: the vehicle behind lluav-core's server, ticked and flushed;
//! - [`ws`]: the WebSocket layer (framing, limits, shutdown) every
//!   connection goes through;
//! - [`config`]: `lluavd`'s command line and config file;
//! - [`client`]: the typed async client `lluav` is built on;
//! - [`sim`] and [`recent_log`]: the simulated vehicle and the log it shows.

#![warn(missing_docs)]

pub mod client;
pub mod config;
pub mod daemon;
pub mod recent_log;
pub mod sim;
pub mod ws;
