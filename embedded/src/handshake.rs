//! The HTTP upgrade request, parsed and validated by us before anything
//! reaches embedded-websocket.
//!
//! embedded-websocket 0.9.5 stores `Sec-WebSocket-Key` and every
//! `Sec-WebSocket-Protocol` value in a 24-byte string with an `unwrap`, so a
//! longer value from any client would halt the board. This module never
//! panics on input: it accepts a request only when the key is exactly a
//! base64-encoded 16-byte nonce (24 characters) and every offered protocol
//! fits 24 bytes, and rejects everything else with a typed error that the
//! adapter answers with `400 Bad Request`.

/// The longest header value we accept; longer ones are rejected, not cut.
pub const MAX_HEADER_VALUE: usize = 256;

/// The length of a valid `Sec-WebSocket-Key`: 16 bytes in base64.
pub const KEY_LEN: usize = 24;

/// The longest subprotocol name we accept (the capacity of
/// `embedded_websocket::WebSocketSubProtocol`).
pub const MAX_PROTOCOL_LEN: usize = 24;

/// The answer to every rejected upgrade request.
pub const BAD_REQUEST: &[u8] = b"HTTP/1.1 400 Bad Request\r\nConnection: close\r\nContent-Length: 0\r\n\r\n";

/// A valid WebSocket upgrade request: what the response needs from it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Upgrade<'a> {
    /// The `Sec-WebSocket-Key`, validated: 24 characters of base64 encoding 16 bytes.
    pub key: &'a str,
}

/// Why an upgrade request was rejected.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Rejection {
    /// The request head did not end within the receive buffer.
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
    /// No `Host` header.
    MissingHost,
    /// `Upgrade: websocket` or `Connection: upgrade` missing.
    NotUpgrade,
    /// `Sec-WebSocket-Version` missing or not 13.
    BadVersion,
    /// `Sec-WebSocket-Key` missing, repeated, or not a base64 16-byte nonce.
    BadKey,
    /// A `Sec-WebSocket-Protocol` entry empty or longer than [`MAX_PROTOCOL_LEN`].
    BadProtocol,
}

/// Where the request head ends in `buf` (the index after its blank line),
/// if it has ended.
pub fn head_end(buf: &[u8]) -> Option<usize> {
    buf.windows(4).position(|w| w == b"\r\n\r\n").map(|i| i + 4)
}

/// Validates a complete request head (up to and including its blank line).
pub fn parse(head: &[u8]) -> Result<Upgrade<'_>, Rejection> {
    let text = core::str::from_utf8(head).map_err(|_| Rejection::NotAscii)?;
    if !text
        .bytes()
        .all(|b| b == b'\r' || b == b'\n' || b == b'\t' || (b' '..=b'~').contains(&b))
    {
        return Err(Rejection::NotAscii);
    }
    let body = text.strip_suffix("\r\n\r\n").ok_or(Rejection::NotAscii)?;
    let mut lines = body.split("\r\n");
    request_line(lines.next().unwrap_or(""))?;

    let mut host = false;
    let mut upgrade = false;
    let mut connection = false;
    let mut version = false;
    let mut key = None;
    for line in lines {
        if line.contains('\n') || line.contains('\r') {
            return Err(Rejection::NotAscii);
        }
        let (name, value) = header(line)?;
        if name.eq_ignore_ascii_case("host") {
            host = true;
        } else if name.eq_ignore_ascii_case("upgrade") {
            upgrade |= has_token(value, "websocket");
        } else if name.eq_ignore_ascii_case("connection") {
            connection |= has_token(value, "upgrade");
        } else if name.eq_ignore_ascii_case("sec-websocket-version") {
            if value != "13" {
                return Err(Rejection::BadVersion);
            }
            version = true;
        } else if name.eq_ignore_ascii_case("sec-websocket-key") {
            if key.is_some() || !valid_key(value) {
                return Err(Rejection::BadKey);
            }
            key = Some(value);
        } else if name.eq_ignore_ascii_case("sec-websocket-protocol") {
            // Entries as HTTP lists are read (comma, optional spaces), and
            // also as embedded-websocket's reader cuts them (at ", " only):
            // "a…a,b…b" is two short entries to the first reading but one
            // long one to the second, which would hit its 24-byte unwrap.
            let ok = value
                .split(',')
                .map(|p| p.trim_matches([' ', '\t']))
                .all(|p| !p.is_empty() && p.len() <= MAX_PROTOCOL_LEN)
                && value.split(", ").all(|p| p.len() <= MAX_PROTOCOL_LEN);
            if !ok {
                return Err(Rejection::BadProtocol);
            }
        }
    }
    if !host {
        return Err(Rejection::MissingHost);
    }
    if !(upgrade && connection) {
        return Err(Rejection::NotUpgrade);
    }
    if !version {
        return Err(Rejection::BadVersion);
    }
    key.map(|key| Upgrade { key }).ok_or(Rejection::BadKey)
}

fn request_line(line: &str) -> Result<(), Rejection> {
    let mut parts = line.split(' ');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("GET"), Some(target), Some("HTTP/1.1"), None) if target.starts_with('/') => Ok(()),
        _ => Err(Rejection::BadRequestLine),
    }
}

fn header(line: &str) -> Result<(&str, &str), Rejection> {
    let (name, value) = line.split_once(':').ok_or(Rejection::BadHeader)?;
    let token = |b: u8| b.is_ascii_alphanumeric() || b"!#$%&'*+-.^_`|~".contains(&b);
    if name.is_empty() || !name.bytes().all(token) {
        return Err(Rejection::BadHeader);
    }
    let value = value.trim_matches([' ', '\t']);
    if value.len() > MAX_HEADER_VALUE {
        return Err(Rejection::HeaderTooLong);
    }
    Ok((name, value))
}

fn has_token(value: &str, token: &str) -> bool {
    value
        .split(',')
        .any(|t| t.trim_matches([' ', '\t']).eq_ignore_ascii_case(token))
}

/// 22 base64 characters and `==`, the last character carrying only the
/// two bits that complete the 16th byte.
fn valid_key(key: &str) -> bool {
    let b = key.as_bytes();
    let sextet = |c: u8| match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'a'..=b'z' => Some(c - b'a' + 26),
        b'0'..=b'9' => Some(c - b'0' + 52),
        b'+' => Some(62),
        b'/' => Some(63),
        _ => None,
    };
    b.len() == KEY_LEN
        && b[22..] == *b"=="
        && b[..22].iter().all(|&c| sextet(c).is_some())
        && sextet(b[21]).is_some_and(|s| s & 0x0f == 0)
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
            Ok(Upgrade {
                key: "dGhlIHNhbXBsZSBub25jZQ=="
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
    fn rejects_protocols_that_embedded_websocket_would_read_as_one_long_entry() {
        let req = with("Sec-WebSocket-Protocol: aaaaaaaaaaaaaaaaaaaa,bbbbbbbbbb");
        assert_eq!(parse(req.as_bytes()), Err(Rejection::BadProtocol));
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
