//! The HTTP upgrade request, parsed and validated before any answer.
//!
//! Parsing never panics on input and never allocates: a request is
//! accepted only when it is `GET <path> HTTP/1.1` with printable ASCII
//! headers of at most [`MAX_HEADER_VALUE`] bytes, one `Host`, at most one
//! `Origin`, `Upgrade: websocket`, `Connection: upgrade`, version 13 and a
//! `Sec-WebSocket-Key` that is exactly a base64-encoded 16-byte nonce.
//! Offered subprotocols are read as an HTTP list of names of at most
//! [`MAX_PROTOCOL_LEN`] bytes; none is selected (DESIGN.md requires none).
//! Whether the `Host` and `Origin` are acceptable is [`crate::policy`]'s
//! question. Everything rejected is answered with the status of its
//! [`Rejection`] and the connection is closed.

/// The longest header value we accept; longer ones are rejected, not cut.
pub const MAX_HEADER_VALUE: usize = 256;

/// The length of a valid `Sec-WebSocket-Key`: 16 bytes in base64.
pub const KEY_LEN: usize = 24;

/// The longest subprotocol name we accept.
pub const MAX_PROTOCOL_LEN: usize = 24;

/// The longest request head we read (its bytes are held in the
/// connection's message buffer until answered).
pub const MAX_REQUEST_HEAD: usize = 1024;

/// The answer to a malformed upgrade request.
pub const BAD_REQUEST: &[u8] = b"HTTP/1.1 400 Bad Request\r\nConnection: close\r\nContent-Length: 0\r\n\r\n";

/// The answer to a request whose `Host` or `Origin` the policy refuses.
pub const FORBIDDEN: &[u8] = b"HTTP/1.1 403 Forbidden\r\nConnection: close\r\nContent-Length: 0\r\n\r\n";

/// The answer to a request from an address that holds all the sessions
/// one address may hold.
pub const TOO_MANY_REQUESTS: &[u8] =
    b"HTTP/1.1 429 Too Many Requests\r\nConnection: close\r\nContent-Length: 0\r\n\r\n";

/// A valid WebSocket upgrade request: what the answer and the policy need.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Request<'a> {
    /// The `Sec-WebSocket-Key`, validated: 24 characters of base64 encoding 16 bytes.
    pub key: &'a [u8; KEY_LEN],
    /// The `Host` header's value (`name` or `name:port`).
    pub host: &'a str,
    /// The `Origin` header's value, if any (browsers send one).
    pub origin: Option<&'a str>,
}

/// Why an upgrade request was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rejection {
    /// The request head did not end within [`MAX_REQUEST_HEAD`] bytes.
    TooLarge,
    /// The peer closed the connection before the head was complete.
    Incomplete,
    /// Bytes outside printable ASCII, or lines not ended by CRLF.
    NotAscii,
    /// Not `GET <path> HTTP/1.1`.
    BadRequestLine,
    /// A header line without a colon, with an empty or invalid name, or folded.
    BadHeader,
    /// A header value longer than [`MAX_HEADER_VALUE`].
    HeaderTooLong,
    /// No `Host` header, or more than one.
    MissingHost,
    /// More than one `Origin` header.
    BadOrigin,
    /// `Upgrade: websocket` or `Connection: upgrade` missing.
    NotUpgrade,
    /// `Sec-WebSocket-Version` missing or not 13.
    BadVersion,
    /// `Sec-WebSocket-Key` missing, repeated, or not a base64 16-byte nonce.
    BadKey,
    /// A `Sec-WebSocket-Protocol` entry empty or longer than [`MAX_PROTOCOL_LEN`].
    BadProtocol,
    /// The `Host` names neither this adapter's address nor an allowed name
    /// (DNS rebinding).
    ForeignHost,
    /// The `Origin` is a page of another site (cross-site WebSocket hijacking).
    ForeignOrigin,
    /// The peer's address already holds as many sessions as one address may.
    TooManySessions,
}

impl Rejection {
    /// The HTTP answer to this rejection.
    pub fn answer(self) -> &'static [u8] {
        match self {
            Rejection::ForeignHost | Rejection::ForeignOrigin => FORBIDDEN,
            Rejection::TooManySessions => TOO_MANY_REQUESTS,
            _ => BAD_REQUEST,
        }
    }
}

/// Where the request head ends in `buf` (the index after its blank line),
/// if it has ended.
pub fn head_end(buf: &[u8]) -> Option<usize> {
    buf.windows(4).position(|w| w == b"\r\n\r\n").map(|i| i + 4)
}

/// The headers a WebSocket upgrade needs, as they are read.
#[derive(Default)]
struct Seen<'a> {
    host: Option<&'a str>,
    hosts: usize,
    origin: Option<&'a str>,
    origins: usize,
    upgrade: bool,
    connection: bool,
    version: bool,
    key: Option<&'a [u8; KEY_LEN]>,
}

/// Validates a complete request head (up to and including its blank line).
pub fn parse(head: &[u8]) -> Result<Request<'_>, Rejection> {
    if !head
        .iter()
        .all(|&b| b == b'\r' || b == b'\n' || b == b'\t' || (b' '..=b'~').contains(&b))
    {
        return Err(Rejection::NotAscii);
    }
    let body = head.strip_suffix(b"\r\n\r\n").ok_or(Rejection::NotAscii)?;
    let mut lines = body.split(|&b| b == b'\n').peekable();
    let mut first = true;
    let mut seen = Seen::default();
    while let Some(raw) = lines.next() {
        // Every line but the last one of `body` ended in CRLF; no CR may
        // appear anywhere else.
        let line = match lines.peek() {
            Some(_) => raw.strip_suffix(b"\r").ok_or(Rejection::NotAscii)?,
            None => raw,
        };
        if line.contains(&b'\r') {
            return Err(Rejection::NotAscii);
        }
        let line = core::str::from_utf8(line).map_err(|_| Rejection::NotAscii)?;
        if first {
            request_line(line)?;
            first = false;
        } else {
            seen.header(line)?;
        }
    }
    seen.finish()
}

impl<'a> Seen<'a> {
    fn header(&mut self, line: &'a str) -> Result<(), Rejection> {
        let (name, value) = header(line)?;
        let is = |n: &str| name.eq_ignore_ascii_case(n);
        if is("host") {
            self.host = Some(value);
            self.hosts += 1;
        } else if is("origin") {
            self.origin = Some(value);
            self.origins += 1;
        } else if is("upgrade") {
            self.upgrade |= has_token(value, "websocket");
        } else if is("connection") {
            self.connection |= has_token(value, "upgrade");
        } else if is("sec-websocket-version") {
            if value != "13" {
                return Err(Rejection::BadVersion);
            }
            self.version = true;
        } else if is("sec-websocket-key") {
            let key = value.as_bytes().try_into().map_err(|_| Rejection::BadKey)?;
            if self.key.is_some() || !valid_key(key) {
                return Err(Rejection::BadKey);
            }
            self.key = Some(key);
        } else if is("sec-websocket-protocol")
            && !pieces(value, b',')
                .map(str::trim_ascii)
                .all(|p| !p.is_empty() && p.len() <= MAX_PROTOCOL_LEN)
        {
            return Err(Rejection::BadProtocol);
        }
        Ok(())
    }

    fn finish(self) -> Result<Request<'a>, Rejection> {
        let host = match (self.host, self.hosts) {
            (Some(host), 1) if !host.is_empty() => host,
            _ => return Err(Rejection::MissingHost),
        };
        if self.origins > 1 {
            return Err(Rejection::BadOrigin);
        }
        if !(self.upgrade && self.connection) {
            return Err(Rejection::NotUpgrade);
        }
        if !self.version {
            return Err(Rejection::BadVersion);
        }
        let key = self.key.ok_or(Rejection::BadKey)?;
        Ok(Request {
            key,
            host,
            origin: self.origin,
        })
    }
}

fn request_line(line: &str) -> Result<(), Rejection> {
    let mut parts = pieces(line, b' ');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("GET"), Some(target), Some("HTTP/1.1"), None) if target.as_bytes().first() == Some(&b'/') => {
            Ok(())
        }
        _ => Err(Rejection::BadRequestLine),
    }
}

fn header(line: &str) -> Result<(&str, &str), Rejection> {
    let (name, value) = cut(line, b':').ok_or(Rejection::BadHeader)?;
    let token = |b: u8| b.is_ascii_alphanumeric() || b"!#$%&'*+-.^_`|~".contains(&b);
    if name.is_empty() || !name.bytes().all(token) {
        return Err(Rejection::BadHeader);
    }
    // Only spaces and tabs can be ASCII whitespace here: the head is
    // printable ASCII and tabs, and the line has lost its CRLF.
    let value = value.trim_ascii();
    if value.len() > MAX_HEADER_VALUE {
        return Err(Rejection::HeaderTooLong);
    }
    Ok((name, value))
}

fn has_token(value: &str, token: &str) -> bool {
    pieces(value, b',').any(|t| t.trim_ascii().eq_ignore_ascii_case(token))
}

/// `text` cut at the first `sep` (an ASCII byte): what comes before it and
/// after it.
///
/// Byte-wise, and exact for any UTF-8 text (an ASCII byte never occurs
/// inside a multi-byte character): `str`'s `char` searchers, which decode
/// UTF-8, would only cost flash.
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
/// two bits that complete the 16th byte.
fn valid_key(key: &[u8; KEY_LEN]) -> bool {
    let sextet = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    let (digits, pad) = key.split_at(22);
    pad == b"=="
        && digits.iter().all(|&c| sextet(c).is_some())
        && sextet(key[21]).is_some_and(|s| s & 0x0f == 0)
}

#[cfg(test)]
mod tests {
    use super::*;

    const GOOD: &str = "GET /chat HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: keep-alive, Upgrade\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n";

    fn with(extra: &str) -> std::string::String {
        GOOD.replace("\r\n\r\n", &std::format!("\r\n{extra}\r\n\r\n"))
    }

    extern crate std;

    #[test]
    fn accepts_the_rfc_example_key() {
        assert_eq!(
            parse(GOOD.as_bytes()),
            Ok(Request {
                key: b"dGhlIHNhbXBsZSBub25jZQ==",
                host: "x",
                origin: None,
            })
        );
    }

    #[test]
    fn rejects_a_key_longer_than_24_bytes() {
        let req = GOOD.replace("dGhlIHNhbXBsZSBub25jZQ==", "dGhlIHNhbXBsZSBub25jZQ==AAAA");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadKey));
    }

    #[test]
    fn rejects_a_key_whose_last_character_carries_stray_bits() {
        let req = GOOD.replace("dGhlIHNhbXBsZSBub25jZQ==", "dGhlIHNhbXBsZSBub25jZR==");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadKey));
    }

    #[test]
    fn rejects_a_repeated_key() {
        assert_eq!(
            parse(with("Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==").as_bytes()),
            Err(Rejection::BadKey)
        );
    }

    #[test]
    fn rejects_a_protocol_longer_than_24_bytes() {
        let req = with("Sec-WebSocket-Protocol: chat, a-protocol-name-of-25-bytes");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadProtocol));
    }

    #[test]
    fn reads_the_origin_and_refuses_two() {
        let req = with("Origin: http://x");
        assert_eq!(parse(req.as_bytes()).map(|r| r.origin), Ok(Some("http://x")));
        let req = with("Origin: http://x\r\nOrigin: http://y");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadOrigin));
    }

    #[test]
    fn refuses_two_hosts_and_an_empty_one() {
        assert_eq!(parse(with("Host: y").as_bytes()), Err(Rejection::MissingHost));
        let req = GOOD.replace("Host: x", "Host: ");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::MissingHost));
    }

    #[test]
    fn refuses_a_bare_cr_or_lf_inside_the_head() {
        let req = GOOD.replace("Upgrade: websocket\r\n", "Upgrade: websocket\n");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::NotAscii));
        let req = GOOD.replace("Host: x", "Host: x\ry");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::NotAscii));
    }

    #[test]
    fn accepts_short_protocols_without_selecting_one() {
        assert!(parse(with("Sec-WebSocket-Protocol: chat, lluav").as_bytes()).is_ok());
    }

    #[test]
    fn rejects_header_values_over_the_limit() {
        let long = "a".repeat(MAX_HEADER_VALUE + 1);
        assert_eq!(
            parse(with(&std::format!("X-Long: {long}")).as_bytes()),
            Err(Rejection::HeaderTooLong)
        );
    }

    #[test]
    fn rejects_requests_that_are_not_upgrades() {
        let req = GOOD.replace("Upgrade: websocket\r\n", "");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::NotUpgrade));
        let req = GOOD.replace("GET", "POST");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadRequestLine));
        let req = GOOD.replace("Version: 13", "Version: 8");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadVersion));
        let req = GOOD.replace("Host: x\r\n", "");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::MissingHost));
    }

    #[test]
    fn rejects_folded_and_nameless_headers() {
        assert_eq!(parse(with(" folded").as_bytes()), Err(Rejection::BadHeader));
        assert_eq!(parse(with(": value").as_bytes()), Err(Rejection::BadHeader));
    }

    #[test]
    fn rejects_bytes_outside_ascii() {
        assert_eq!(
            parse(with("X-Name: caf\u{e9}").as_bytes()),
            Err(Rejection::NotAscii)
        );
    }

    #[test]
    fn finds_the_end_of_the_head() {
        assert_eq!(head_end(b"GET / HTTP/1.1\r\n\r\nrest"), Some(18));
        assert_eq!(head_end(b"GET / HTTP/1.1\r\n"), None);
    }
}
