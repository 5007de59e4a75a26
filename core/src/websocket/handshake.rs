//! The opening handshake's request (RFC 6455, section 4.2.1), judged
//! without I/O: the one upgrade check both adapters answer with.
//!
//! [`parse`] reads a complete request head, up to and including its blank
//! line ([`head_end`]), and says what it asks for: a WebSocket
//! [`Upgrade`], a plain HTTP request (lluavd serves its console to those),
//! or why it is refused, each [`Rejection`] with its HTTP status.
//! [`judge`] adds the Origin/Host [`Policy`]. Parsing never panics, never
//! allocates and borrows everything from the head; how long a head may be
//! is the adapter's limit ([`Rejection::TooLarge`]).
//!
//! What a head must be: UTF-8 with every line ended by CRLF and no other
//! control character than tabs; a request line `method target HTTP/1.1`;
//! header lines `name: value` with no whitespace in the name (so no folded
//! lines).
//! `Host`, `Origin`, `Sec-WebSocket-Key` and `Sec-WebSocket-Version` may
//! appear once each; `Upgrade` and `Connection` are token lists and may
//! repeat. An upgrade is a `GET` without a body, with a `Host`, version 13
//! and a key that is a base64-encoded 16-byte nonce. Subprotocols offered
//! are ignored (none is selected: DESIGN.md requires none), and so is
//! every other header.

use super::policy::{Forbidden, Policy};

/// The length of a valid `Sec-WebSocket-Key`: 16 bytes in base64.
pub const KEY_LEN: usize = 24;

/// What an acceptable request head asks for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Request<'a> {
    /// A WebSocket upgrade.
    Upgrade(Upgrade<'a>),
    /// Any other HTTP request: not this module's to answer.
    Plain {
        /// `GET`, `HEAD`, ...
        method: &'a str,
        /// The request target as sent.
        target: &'a str,
    },
}

/// A valid WebSocket upgrade request: what the answer and the policy need.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Upgrade<'a> {
    /// The request target as sent (`/`, `/events`): which endpoint the
    /// client asks for is the adapter's business.
    pub target: &'a str,
    /// The `Sec-WebSocket-Key`: 24 characters of base64 encoding 16 bytes.
    pub key: &'a [u8; KEY_LEN],
    /// The `Host` header's value (`name` or `name:port`), never empty.
    pub host: &'a str,
    /// The `Origin` header's value, if any (browsers send one).
    pub origin: Option<&'a str>,
}

/// Why a request head is refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rejection {
    /// 400: not a well-formed HTTP/1.1 request or WebSocket upgrade.
    Malformed(Malformed),
    /// 405: an upgrade with another method than `GET`.
    MethodNotAllowed,
    /// 426: an upgrade without `Sec-WebSocket-Version: 13`.
    UpgradeRequired,
    /// 431: the head is longer than the adapter reads.
    TooLarge,
    /// 403: the [`Policy`] refuses the `Origin` or the `Host`.
    Forbidden(Forbidden),
}

/// What is wrong with a malformed request.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Malformed {
    /// Not UTF-8, a control character, or a line not ended by CRLF.
    Bytes,
    /// Not `method target HTTP/1.1`.
    RequestLine,
    /// A header line without a colon, or with whitespace in its name (a
    /// folded line starts with a space).
    HeaderLine,
    /// `Host`, `Origin`, `Sec-WebSocket-Key` or `Sec-WebSocket-Version`
    /// more than once.
    Repeated,
    /// An upgrade without a `Host`, or with an empty one.
    Host,
    /// An upgrade without a `Sec-WebSocket-Key` that is a base64 16-byte nonce.
    Key,
    /// An upgrade with a body.
    Body,
}

impl Rejection {
    /// The HTTP status code and its reason phrase.
    pub fn status(self) -> (u16, &'static str) {
        match self {
            Rejection::Malformed(_) => (400, "Bad Request"),
            Rejection::Forbidden(_) => (403, "Forbidden"),
            Rejection::MethodNotAllowed => (405, "Method Not Allowed"),
            Rejection::UpgradeRequired => (426, "Upgrade Required"),
            Rejection::TooLarge => (431, "Request Header Fields Too Large"),
        }
    }

    /// Why, in a sentence for a log line or an answer's body.
    pub fn reason(self) -> &'static str {
        match self {
            Rejection::Malformed(why) => match why {
                Malformed::Bytes => {
                    "malformed request head (not UTF-8, a control character, or a line without CRLF)"
                }
                Malformed::RequestLine => "not an HTTP/1.1 request line",
                Malformed::HeaderLine => "a malformed header line",
                Malformed::Repeated => "a header that may appear once appears twice",
                Malformed::Host => "no Host header",
                Malformed::Key => "missing or malformed Sec-WebSocket-Key",
                Malformed::Body => "a WebSocket upgrade has no body",
            },
            Rejection::MethodNotAllowed => "a WebSocket upgrade must be a GET request",
            Rejection::UpgradeRequired => "only WebSocket version 13 is served",
            Rejection::TooLarge => "the request head is too long",
            Rejection::Forbidden(Forbidden::Origin) => "this Origin may not open sessions",
            Rejection::Forbidden(Forbidden::Host) => "this Host name is not served here",
        }
    }
}

impl From<Malformed> for Rejection {
    fn from(why: Malformed) -> Self {
        Rejection::Malformed(why)
    }
}

/// Where the request head ends in `buf` (the index after its blank line),
/// if it has ended.
pub fn head_end(buf: &[u8]) -> Option<usize> {
    buf.windows(4).position(|w| w == b"\r\n\r\n").map(|i| i + 4)
}

/// [`parse`], then the `policy` on an upgrade's `Host` and `Origin`.
pub fn judge<'h, S: AsRef<str>>(head: &'h [u8], policy: &Policy<'_, S>) -> Result<Request<'h>, Rejection> {
    let request = parse(head)?;
    if let Request::Upgrade(upgrade) = request {
        policy
            .check(upgrade.host, upgrade.origin)
            .map_err(Rejection::Forbidden)?;
    }
    Ok(request)
}

/// Reads a complete request head (up to and including its blank line).
pub fn parse(head: &[u8]) -> Result<Request<'_>, Rejection> {
    // CR and LF come only as the CRLF ending each line.
    let crlf = head.first() != Some(&b'\n')
        && head
            .windows(2)
            .all(|w| matches!(w, [a, b] if (*a == b'\r') == (*b == b'\n')));
    let body = head
        .strip_suffix(b"\r\n\r\n")
        .filter(|_| crlf)
        .ok_or(Malformed::Bytes)?;
    let body = core::str::from_utf8(body).map_err(|_| Malformed::Bytes)?;
    if body
        .bytes()
        .any(|b| (b < b' ' && !matches!(b, b'\t' | b'\r' | b'\n')) || b == 0x7f)
    {
        return Err(Malformed::Bytes.into());
    }
    // Split at each CR, a line is what follows its LF.
    let mut lines = pieces(body, b'\r').map(|line| match line.as_bytes().first() {
        Some(b'\n') => line.get(1..).unwrap_or_default(),
        _ => line,
    });
    let (method, target) = request_line(lines.next().unwrap_or_default())?;
    let mut seen = Seen::default();
    for line in lines {
        seen.header(line)?;
    }
    seen.finish(method, target)
}

fn request_line(line: &str) -> Result<(&str, &str), Malformed> {
    let mut parts = pieces(line, b' ');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some(method), Some(target), Some("HTTP/1.1"), None) if unspaced(method) && !target.is_empty() => {
            Ok((method, target))
        }
        _ => Err(Malformed::RequestLine),
    }
}

/// The headers an upgrade needs, as they are read.
#[derive(Default)]
struct Seen<'a> {
    host: Option<&'a str>,
    origin: Option<&'a str>,
    key: Option<&'a str>,
    version: Option<&'a str>,
    upgrade: bool,
    connection: bool,
    body: bool,
}

impl<'a> Seen<'a> {
    fn header(&mut self, line: &'a str) -> Result<(), Malformed> {
        let (name, value) = cut(line, b':').ok_or(Malformed::HeaderLine)?;
        if !unspaced(name) {
            return Err(Malformed::HeaderLine);
        }
        // Spaces and tabs are the only whitespace left in a line.
        let value = value.trim_ascii();
        let is = |n: &str| same_ignoring_case(name, n);
        let once = |slot: &mut Option<&'a str>| match slot.replace(value) {
            Some(_) => Err(Malformed::Repeated),
            None => Ok(()),
        };
        if is("host") {
            once(&mut self.host)?;
        } else if is("origin") {
            once(&mut self.origin)?;
        } else if is("sec-websocket-key") {
            once(&mut self.key)?;
        } else if is("sec-websocket-version") {
            once(&mut self.version)?;
        } else if is("upgrade") {
            self.upgrade |= has_token(value, "websocket");
        } else if is("connection") {
            self.connection |= has_token(value, "upgrade");
        } else if is("transfer-encoding") || (is("content-length") && value != "0") {
            self.body = true;
        }
        Ok(())
    }

    /// What the request asks for, in the order of DESIGN.md's statuses.
    fn finish(self, method: &'a str, target: &'a str) -> Result<Request<'a>, Rejection> {
        if !(self.upgrade && self.connection) {
            return Ok(Request::Plain { method, target });
        }
        if method != "GET" {
            return Err(Rejection::MethodNotAllowed);
        }
        if self.body {
            return Err(Malformed::Body.into());
        }
        let host = self.host.filter(|h| !h.is_empty()).ok_or(Malformed::Host)?;
        if self.version != Some("13") {
            return Err(Rejection::UpgradeRequired);
        }
        let key = self
            .key
            .and_then(|k| k.as_bytes().try_into().ok())
            .filter(valid_key)
            .ok_or(Malformed::Key)?;
        Ok(Request::Upgrade(Upgrade {
            target,
            key,
            host,
            origin: self.origin,
        }))
    }
}

/// A method or a header name: not empty, no whitespace (so no space
/// before a header's colon, and no folded line). Which characters a token
/// may hold is not checked: no name this module reads holds others, and
/// every other header is ignored.
fn unspaced(s: &str) -> bool {
    !s.is_empty() && !s.bytes().any(|b| b == b' ' || b == b'\t')
}

fn has_token(value: &str, token: &str) -> bool {
    pieces(value, b',').any(|t| same_ignoring_case(t.trim_ascii(), token))
}

/// Whether `a` and `b` are the same ignoring ASCII case (names, schemes
/// and hosts). A plain loop: `str::eq_ignore_ascii_case`'s word-at-a-time
/// form costs an MCU more flash than these short names are worth.
pub(crate) fn same_ignoring_case(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).all(|(x, y)| x.eq_ignore_ascii_case(&y))
}

/// `text` cut at the first `sep` (an ASCII byte): what comes before it and
/// after it.
///
/// Byte-wise, and exact for any UTF-8 text (an ASCII byte never occurs
/// inside a multi-byte character): `str`'s `char` searchers, which decode
/// UTF-8, would only cost an MCU's flash.
pub(crate) fn cut(text: &str, sep: u8) -> Option<(&str, &str)> {
    let at = text.bytes().position(|b| b == sep)?;
    Some((text.get(..at)?, text.get(at + 1..)?))
}

/// The pieces of `text` between the `sep` bytes (see [`cut`]).
pub(crate) fn pieces(text: &str, sep: u8) -> impl Iterator<Item = &str> {
    text.as_bytes()
        .split(move |&b| b == sep)
        .map(|piece| core::str::from_utf8(piece).unwrap_or_default())
}

/// 22 base64 characters and `==`, the last character carrying only the
/// two bits that complete the 16th byte (its other four bits clear: `A`,
/// `Q`, `g` or `w`).
fn valid_key(key: &&[u8; KEY_LEN]) -> bool {
    let (digits, pad) = key.split_at(22);
    pad == b"=="
        && digits
            .iter()
            .all(|&c| c.is_ascii_alphanumeric() || c == b'+' || c == b'/')
        && matches!(digits.last(), Some(b'A' | b'Q' | b'g' | b'w'))
}
