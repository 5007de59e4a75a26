//! Responses: one JSON object per request, written into a caller-provided
//! fixed-capacity buffer.
//!
//! A response is either whole or replaced: when the backend's fields do not
//! fit, the client gets `{"ret":-1,...,"msg":"Response too large"}`, never a
//! truncated or invalid object. Overflow is sticky: once a write does not
//! fit, every later write is a no-op and the response is replaced.
//!
//! Three parts: the JSON writer under everything (`json.rs`: bytes,
//! escaped strings, numbers, nesting), the builders a backend writes with
//! ([`Fields`], [`Items`]), and the envelope (`envelope.rs`:
//! `{"ret":..,"cmd":..,"ts":..`, and whole error replies).

mod envelope;
mod fields;
mod json;

pub use envelope::{MIN_RESPONSE_CAPACITY, is_success};
pub(crate) use envelope::{finish, retry_after, write_error};
pub use fields::{Fields, Items};
