//! The LLUAV WebSocket command protocol, without I/O, allocation or panics.
//!
//! A client sends `cmd args` text frames (`set_sp_ned 1.0:2.0:-3.0:0.5`,
//! `mw_exec 1001:1,2,3,5`, `mission 1001:{"waypoints":[...]}`) and gets
//! exactly one JSON object back per frame (`{"ret":0,"cmd":23,"ts":...}`).
//! This crate is everything about that protocol that does not touch a
//! socket, a clock or a file:
//!
//! - [`table`]: the one command table (ids, names, grammar, gates, usage);
//! - [`parse()`] / [`Command::encode`]: frame ↔ typed [`Command`], mirror
//!   images of each other, borrowing from the frame;
//! - [`gate`] and [`session`]: login, admin, armed and lock gates;
//! - [`authority`]: who flies (one session in control) and the failsafes
//!   no motion command cancels, gated before the backend;
//! - [`response`]: JSON responses in caller-provided fixed buffers;
//! - [`Backend`] and [`Clock`]: what an adapter supplies;
//! - [`throttle`]: password guessing limited per client and across all;
//! - [`websocket`]: WebSocket as both adapters enforce it: the upgrade
//!   request and the Origin/Host policy, frames (headers, unmasking, UTF-8
//!   checked as a text message arrives), fragmentation and closing;
//! - [`Server::handle`]: the one entry point an adapter calls per message.
//!
//! ```
//! use lluav_core::{Auth, Backend, Command, Context, Failure, Fields, Message, Outcome, Server, Step};
//!
//! struct Parked;
//! impl Backend for Parked {
//!     fn armed(&self) -> bool { false }
//!     fn execute(&mut self, _: &Command<'_>, _: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
//!         out.str("note", "parked");
//!         Ok(Step::Done)
//!     }
//! }
//!
//! let mut server = Server::new(Parked, || 1_714_233_600_000, Auth::new(Some("secret")).unwrap());
//! let mut session = server.open(Some(core::net::IpAddr::from([192, 168, 1, 20]).into()));
//! let mut out = [0u8; 512];
//! assert_eq!(
//!     server.handle(&mut session, Message::Text(b"state"), &mut out),
//!     Outcome::Reply(r#"{"ret":-1,"cmd":2,"ts":1714233600000,"msg":"Login first!"}"#),
//! );
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

pub mod authority;
pub mod backend;
pub mod command;
mod encode;
pub mod error;
pub mod gate;
pub mod number;
pub mod parse;
mod password;
pub mod response;
pub mod server;
pub mod session;
pub mod table;
pub mod throttle;
pub mod websocket;

pub use authority::{Action, Control, Failsafe, Label, Pilot, Via};
pub use backend::{Backend, Clock, Context, DEFAULT_CONTROL_TIMEOUT_MS, Step, Ticket};
pub use command::{Args, Command, LandPoint, MAX_HEIGHTS, MAX_WAYPOINT_IDS, Payload, Point, Pose};
pub use error::{ArgError, Bound, Failure, ParseError, Refusal, Ret};
pub use number::Number;
pub use parse::parse;
pub use response::{Fields, Items, MIN_RESPONSE_CAPACITY};
pub use server::{CloseCode, Message, Outcome, Server};
pub use session::{Auth, AuthError, LoginOutcome, Peer, Role, Session, SessionId};
pub use table::{Class, CommandId, Effect, Flags, Grammar, Section, Spec, TABLE};
