//! LLUAV on the host (tokio): the `lluavd` daemon, its simulated vehicle and
//! the `lluav` client library.
//!
//! - [`daemon`]: the companion computer and a vehicle composed behind
//!   lluav-core's server, ticked and flushed;
//! - [`net`]: the network layer every connection goes through (accept,
//!   TLS, the HTTP upgrade and its Origin/Host policy, per-address limits,
//!   framing, shutdown);
//! - [`config`]: `lluavd`'s command line and config file;
//! - [`console`]: the browser console, answered to plain HTTP requests;
//! - [`client`]: the typed async client `lluav` is built on;
//! - [`onboard`]: the daemon's backend, a [`companion`] computer and a
//!   vehicle composed;
//! - [`vehicle`]: what every vehicle is to the rest (the [`vehicle::Vehicle`]
//!   trait, positions, the mission JSON), implemented by the simulator
//!   ([`sim`]) and by an autopilot over MAVLink ([`mavlink`]);
//! - [`files`]: the data directory, the only place client paths reach;
//! - [`recent_log`]: the log `showmsg` shows;
//! - [`notify`], [`journal`], [`check_config`]: running as a systemd
//!   service (readiness, watchdog and status; log lines for the journal;
//!   `--check-config`);
//! - [`uplink`]: the protocol through an MQTT broker (vehicles behind NAT,
//!   fleets), and the operator's side of it;
//! - [`events`]: what happened, told as it happens (the `/events` stream,
//!   the uplink's `events` topic);
//! - [`terminal`]: text from the network made safe to print.

#![warn(missing_docs)]

pub mod alarm;
pub mod check_config;
pub mod client;
pub mod companion;
pub mod config;
pub mod console;
pub mod daemon;
pub mod events;
pub mod files;
pub mod journal;
pub mod json;
pub mod malloc;
pub mod mavlink;
pub mod net;
pub mod notify;
pub mod onboard;
pub mod recent_log;
pub mod sim;
pub mod terminal;
pub mod uplink;
pub mod vehicle;
