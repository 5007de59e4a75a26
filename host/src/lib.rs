//! LLUAV on the host (tokio): the `lluavd` daemon, its simulated vehicle and
//! the `lluav` client library.

pub mod recent_log;
pub mod sim;
