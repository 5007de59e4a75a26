//! WebSocket (RFC 6455) without I/O: everything about it both adapters
//! enforce, written once, so that lluavd and the MCU accept, refuse and
//! close alike. The adapters only move the bytes.
//!
//! - [`handshake`]: the upgrade request, judged whole (its HTTP/1.1 form,
//!   the WebSocket headers), each refusal with its HTTP status;
//! - [`policy`]: who may open a session, the `Origin` and `Host` rules of
//!   DESIGN.md's "Security defaults", given the address a connection
//!   arrived on;
//! - frames ([`parse_header`], [`unmask`], [`write_header`], [`Utf8`],
//!   [`Utf8Stream`]): client headers checked before any payload is read,
//!   server headers written in the minimal length form, text checked as
//!   it arrives (kept whole or not);
//! - messages ([`Fragments`], [`close_reply`]): the rules of a message
//!   across its frames, and the answer to a peer's close.
//!
//! The close codes a failure maps to are [`CloseCode`](crate::CloseCode)'s,
//! the same the protocol's close policy ([`Message::text`](crate::Message::text))
//! uses.

mod frame;
pub mod handshake;
mod message;
pub mod policy;

pub use frame::{
    Header, MAX_CLIENT_HEADER, MAX_CONTROL_PAYLOAD, MAX_SERVER_HEADER, Opcode, Utf8, Utf8Stream, Verdict,
    header_len, parse_header, unmask, write_header,
};
pub use message::{Fragments, Interrupt, close_reply};
