//! SEAM: a stand-in for `crate::console` (the web console, issue 12) with
//! the same shape, until that module lands; then `super::handshake`'s
//! `use super::console_fallback as console;` becomes `use crate::console;`
//! and this file goes away.
//!
//! It answers every plain HTTP request the way a server without a console
//! must: `404 Not Found` for `GET`/`HEAD`, `405 Method Not Allowed` for
//! anything else. Either way the request never reaches the protocol.

/// A complete HTTP response to a request that is not a WebSocket upgrade.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Response {
    status: u16,
    reason: &'static str,
    allow: bool,
    body: &'static str,
}

/// The answer to `method target` (`enabled`: whether the console is served).
pub fn respond(_enabled: bool, method: &str, _target: &str) -> Response {
    if matches!(method, "GET" | "HEAD") {
        Response {
            status: 404,
            reason: "Not Found",
            allow: false,
            body: "lluavd serves the LLUAV protocol over WebSocket here; nothing else.\n",
        }
    } else {
        Response {
            status: 405,
            reason: "Method Not Allowed",
            allow: true,
            body: "Only GET and HEAD are served here.\n",
        }
    }
}

impl Response {
    /// The bytes on the wire; `head_only` for a `HEAD` request.
    pub fn to_bytes(&self, head_only: bool) -> Vec<u8> {
        let allow = if self.allow { "Allow: GET, HEAD\r\n" } else { "" };
        let mut bytes = format!(
            "HTTP/1.1 {} {}\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\n\
             {allow}Connection: close\r\n\r\n",
            self.status,
            self.reason,
            self.body.len()
        )
        .into_bytes();
        if !head_only {
            bytes.extend_from_slice(self.body.as_bytes());
        }
        bytes
    }
}
