//! LLUAV on the host (tokio): the `lluavd` daemon and the `lluav` client.
//!
//! This crate is a placeholder member of the workspace: the daemon and the
//! client are tracked by their own issue.

pub use lluav_core as core_protocol;
