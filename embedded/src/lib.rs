//! LLUAV on embassy: the companion-microcontroller adapter.
//!
//! This crate is a placeholder member of the workspace: the embassy-net /
//! embedded-websocket adapter is tracked by its own issue. It re-exports the
//! core so that firmware can already depend on one crate.
#![no_std]

pub use lluav_core as core_protocol;
