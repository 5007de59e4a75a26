//! The HTTP request head of a new connection, read and judged here rather
//! than inside the WebSocket library: bounded in size, parsed with
//! httparse, checked against RFC 6455 (section 4.2.1) and the
//! [`Policy`], and answered by us — `101` and the
//! stream goes on to the WebSocket layer, anything else is answered and
//! closed. A request that is not an upgrade goes to the console and never
//! reaches the protocol.

use std::fmt;
use std::net::IpAddr;

use tokio::io::{AsyncRead, AsyncReadExt};
use tokio_tungstenite::tungstenite::handshake::derive_accept_key;

use super::policy::{Forbidden, Policy};
use crate::console;

/// Largest request head read; a longer one is refused with 431.
pub const MAX_HEAD: usize = 8 * 1024;

/// Most header lines in a head.
const MAX_HEADERS: usize = 48;

/// What a complete, acceptable head asks for.
#[derive(Debug, PartialEq, Eq)]
pub enum Request {
    /// A WebSocket upgrade with this `Sec-WebSocket-Key`, allowed by the policy.
    Upgrade {
        /// The client's key, for `Sec-WebSocket-Accept`.
        key: String,
    },
    /// A plain HTTP request, for the console.
    Http {
        /// `GET`, `HEAD`, ...
        method: String,
        /// The request target as sent.
        target: String,
    },
}

/// Why a request is refused, each with its HTTP status.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// 400: not a valid HTTP/1.1 request or WebSocket upgrade.
    BadRequest(&'static str),
    /// 403: the Origin/Host policy says no.
    Forbidden(Forbidden),
    /// 405: an upgrade with a method other than GET.
    MethodNotAllowed,
    /// 426: a WebSocket version other than 13.
    UpgradeRequired,
    /// 431: the head is longer than [`MAX_HEAD`].
    TooLarge,
    /// 503: no session slot for this connection; the text says which limit.
    Unavailable(String),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::BadRequest(why) => f.write_str(why),
            Refusal::Forbidden(why) => write!(f, "{why}"),
            Refusal::MethodNotAllowed => f.write_str("a WebSocket upgrade must be a GET request"),
            Refusal::UpgradeRequired => f.write_str("only WebSocket version 13 is served"),
            Refusal::TooLarge => write!(f, "the request head is longer than {MAX_HEAD} bytes"),
            Refusal::Unavailable(why) => f.write_str(why),
        }
    }
}

impl Refusal {
    fn status(&self) -> (u16, &'static str) {
        match self {
            Refusal::BadRequest(_) => (400, "Bad Request"),
            Refusal::Forbidden(_) => (403, "Forbidden"),
            Refusal::MethodNotAllowed => (405, "Method Not Allowed"),
            Refusal::UpgradeRequired => (426, "Upgrade Required"),
            Refusal::TooLarge => (431, "Request Header Fields Too Large"),
            Refusal::Unavailable(_) => (503, "Service Unavailable"),
        }
    }

    /// The HTTP status code.
    pub fn code(&self) -> u16 {
        self.status().0
    }

    /// The whole response: status line, headers, a one-line body.
    pub fn to_bytes(&self) -> Vec<u8> {
        let (code, reason) = self.status();
        let extra = match self {
            Refusal::MethodNotAllowed => "Allow: GET\r\n",
            Refusal::UpgradeRequired => "Sec-WebSocket-Version: 13\r\nUpgrade: websocket\r\n",
            Refusal::Unavailable(_) => "Retry-After: 1\r\n",
            _ => "",
        };
        let body = format!("lluavd: {self}\n");
        format!(
            "HTTP/1.1 {code} {reason}\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\n\
             {extra}Connection: close\r\n\r\n{body}",
            body.len()
        )
        .into_bytes()
    }
}

/// The `101 Switching Protocols` answer to `key`.
pub fn switching_protocols(key: &str) -> Vec<u8> {
    format!(
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Accept: {}\r\n\r\n",
        derive_accept_key(key.as_bytes())
    )
    .into_bytes()
}

/// The console's answer to a plain request.
pub fn console_response(enabled: bool, method: &str, target: &str) -> Vec<u8> {
    console::respond(enabled, method, target).to_bytes(method == "HEAD")
}

/// Why no complete head arrived.
#[derive(Debug)]
pub enum HeadError {
    /// The peer closed, or the socket failed, before the head was complete.
    Closed,
    /// The head is malformed or too long.
    Refused(Refusal),
}

/// Reads into `buf` until it holds a complete request head and returns the
/// head's length; bytes after it (a client that did not wait for the
/// `101`) stay in `buf`. The caller bounds the time.
pub async fn read_head<S: AsyncRead + Unpin>(stream: &mut S, buf: &mut Vec<u8>) -> Result<usize, HeadError> {
    loop {
        let searched_from = buf.len().saturating_sub(3);
        buf.reserve(2048);
        match stream.read_buf(buf).await {
            Ok(0) | Err(_) => return Err(HeadError::Closed),
            Ok(_) => {}
        }
        // Parse only once a blank line may have arrived: a client dripping
        // one byte at a time costs a scan of its new bytes, not a parse of
        // the whole head each time.
        let tail = buf.get(searched_from..).unwrap_or_default();
        let blank_line = tail.windows(2).any(|w| w == b"\n\n") || tail.windows(3).any(|w| w == b"\n\r\n");
        if blank_line {
            let mut headers = [httparse::EMPTY_HEADER; MAX_HEADERS];
            match httparse::Request::new(&mut headers).parse(buf) {
                Ok(httparse::Status::Complete(len)) if len <= MAX_HEAD => return Ok(len),
                Ok(httparse::Status::Complete(_)) => return Err(HeadError::Refused(Refusal::TooLarge)),
                Ok(httparse::Status::Partial) => {}
                Err(httparse::Error::TooManyHeaders) => {
                    return Err(HeadError::Refused(Refusal::BadRequest("too many header lines")));
                }
                Err(_) => return Err(HeadError::Refused(Refusal::BadRequest("malformed HTTP request"))),
            }
        }
        if buf.len() > MAX_HEAD {
            return Err(HeadError::Refused(Refusal::TooLarge));
        }
    }
}

/// The headers of one request that matter here.
#[derive(Default)]
struct Headers<'h> {
    host: Option<&'h str>,
    origin: Option<&'h str>,
    upgrade: Option<&'h str>,
    connection: Vec<&'h str>,
    key: Option<&'h str>,
    version: Option<&'h str>,
    body: bool,
}

impl<'h> Headers<'h> {
    fn collect(raw: &[httparse::Header<'h>]) -> Result<Headers<'h>, Refusal> {
        let mut h = Headers::default();
        for header in raw {
            let value = std::str::from_utf8(header.value)
                .map_err(|_| Refusal::BadRequest("a header value is not UTF-8"))?
                .trim();
            let name = header.name;
            let once = |slot: &mut Option<&'h str>, what: &'static str| {
                if slot.replace(value).is_some() {
                    Err(Refusal::BadRequest(what))
                } else {
                    Ok(())
                }
            };
            if name.eq_ignore_ascii_case("host") {
                once(&mut h.host, "more than one Host header")?;
            } else if name.eq_ignore_ascii_case("origin") {
                once(&mut h.origin, "more than one Origin header")?;
            } else if name.eq_ignore_ascii_case("upgrade") {
                once(&mut h.upgrade, "more than one Upgrade header")?;
            } else if name.eq_ignore_ascii_case("connection") {
                h.connection.push(value);
            } else if name.eq_ignore_ascii_case("sec-websocket-key") {
                once(&mut h.key, "more than one Sec-WebSocket-Key header")?;
            } else if name.eq_ignore_ascii_case("sec-websocket-version") {
                once(&mut h.version, "more than one Sec-WebSocket-Version header")?;
            } else if name.eq_ignore_ascii_case("transfer-encoding")
                || (name.eq_ignore_ascii_case("content-length") && value != "0")
            {
                h.body = true;
            }
        }
        Ok(h)
    }

    /// Whether the request asks for a WebSocket: `Upgrade: websocket`
    /// and the `upgrade` token in `Connection`.
    fn wants_websocket(&self) -> bool {
        let upgrade = self
            .upgrade
            .is_some_and(|u| u.split(',').any(|t| t.trim().eq_ignore_ascii_case("websocket")));
        let connection = self
            .connection
            .iter()
            .flat_map(|v| v.split(','))
            .any(|t| t.trim().eq_ignore_ascii_case("upgrade"));
        upgrade && connection
    }
}

/// A `Sec-WebSocket-Key` is 16 bytes in base64: 22 characters and `==`.
fn valid_key(key: &str) -> bool {
    let base64 = |c: &u8| c.is_ascii_alphanumeric() || matches!(c, b'+' | b'/');
    key.len() == 24 && key.ends_with("==") && key.as_bytes().get(..22).is_some_and(|k| k.iter().all(base64))
}

/// Decides what the complete `head` asks for. `local` is the address the
/// connection arrived on, `tls` whether it is `wss://`.
pub fn judge(head: &[u8], policy: &Policy, local: IpAddr, tls: bool) -> Result<Request, Refusal> {
    let mut raw = [httparse::EMPTY_HEADER; MAX_HEADERS];
    let mut request = httparse::Request::new(&mut raw);
    match request.parse(head) {
        Ok(httparse::Status::Complete(_)) => {}
        _ => return Err(Refusal::BadRequest("malformed HTTP request")),
    }
    let (Some(method), Some(target), Some(1)) = (request.method, request.path, request.version) else {
        return Err(Refusal::BadRequest("only HTTP/1.1 is served"));
    };
    let headers = Headers::collect(request.headers)?;
    if !headers.wants_websocket() {
        return Ok(Request::Http {
            method: method.to_owned(),
            target: target.to_owned(),
        });
    }
    if method != "GET" {
        return Err(Refusal::MethodNotAllowed);
    }
    if headers.body {
        return Err(Refusal::BadRequest("a WebSocket upgrade has no body"));
    }
    let host = headers.host.ok_or(Refusal::BadRequest("no Host header"))?;
    if headers.version != Some("13") {
        return Err(Refusal::UpgradeRequired);
    }
    let key = headers
        .key
        .filter(|k| valid_key(k))
        .ok_or(Refusal::BadRequest("missing or malformed Sec-WebSocket-Key"))?;
    policy
        .check(host, headers.origin, local, tls)
        .map_err(Refusal::Forbidden)?;
    Ok(Request::Upgrade { key: key.to_owned() })
}

#[cfg(test)]
mod tests {
    use super::*;

    const LOOPBACK: IpAddr = IpAddr::V4(std::net::Ipv4Addr::LOCALHOST);
    const KEY: &str = "dGhlIHNhbXBsZSBub25jZQ==";

    fn upgrade(extra: &str) -> String {
        format!(
            "GET /chat HTTP/1.1\r\nHost: 127.0.0.1:53001\r\nUpgrade: websocket\r\nConnection: keep-alive, Upgrade\r\n\
             Sec-WebSocket-Key: {KEY}\r\nSec-WebSocket-Version: 13\r\n{extra}\r\n"
        )
    }

    fn judged(head: &str) -> Result<Request, Refusal> {
        judge(head.as_bytes(), &Policy::default(), LOOPBACK, false)
    }

    #[test]
    fn a_valid_upgrade_is_accepted_and_answered_per_rfc_6455() {
        assert_eq!(judged(&upgrade("")), Ok(Request::Upgrade { key: KEY.into() }));
        let answer = String::from_utf8(switching_protocols(KEY)).expect("ASCII");
        // The example of RFC 6455, section 1.3.
        assert!(
            answer.contains("Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n"),
            "{answer}"
        );
        assert!(answer.starts_with("HTTP/1.1 101 ") && answer.ends_with("\r\n\r\n"));
    }

    #[test]
    fn a_plain_request_goes_to_the_console() {
        let head = "GET /index.html HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
        assert_eq!(
            judged(head),
            Ok(Request::Http {
                method: "GET".into(),
                target: "/index.html".into()
            })
        );
        let answer = String::from_utf8(console_response(true, "HEAD", "/")).expect("ASCII");
        assert!(answer.ends_with("\r\n\r\n"), "HEAD has no body: {answer}");
    }

    #[test]
    fn broken_upgrades_are_refused_with_their_status() {
        let cases = [
            (
                upgrade("").replace("Sec-WebSocket-Version: 13", "Sec-WebSocket-Version: 8"),
                426,
            ),
            (upgrade("").replace(KEY, "short=="), 400),
            (upgrade("").replace("GET", "POST"), 405),
            (upgrade("Sec-WebSocket-Key: x\r\n"), 400),
            (upgrade("Content-Length: 5\r\n"), 400),
            (upgrade("").replace("Host: 127.0.0.1:53001\r\n", ""), 400),
            (upgrade("").replace("HTTP/1.1", "HTTP/1.0"), 400),
            (upgrade("Origin: https://evil.example\r\n"), 403),
            (upgrade("").replace("127.0.0.1", "evil.example"), 403),
        ];
        for (head, code) in cases {
            let refused = judged(&head).expect_err("refused");
            assert_eq!(refused.code(), code, "{head}");
            let bytes = String::from_utf8(refused.to_bytes()).expect("ASCII");
            assert!(bytes.starts_with(&format!("HTTP/1.1 {code} ")), "{bytes}");
        }
    }

    #[tokio::test]
    async fn a_head_is_read_whole_and_what_follows_it_is_kept() {
        let mut bytes = upgrade("").into_bytes();
        let len = bytes.len();
        bytes.extend_from_slice(b"\x81\x05");
        let mut stream = &bytes[..];
        let mut buf = Vec::new();
        assert_eq!(read_head(&mut stream, &mut buf).await.ok(), Some(len));
        assert_eq!(buf.get(len..), Some(&b"\x81\x05"[..]));
    }

    #[tokio::test]
    async fn an_endless_head_is_refused_with_431() {
        let bytes = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
        let mut stream = bytes.as_bytes();
        let got = read_head(&mut stream, &mut Vec::new()).await;
        assert!(
            matches!(got, Err(HeadError::Refused(Refusal::TooLarge))),
            "{got:?}"
        );
        let mut truncated = &b"GET / HTTP/1.1\r\nHost: x\r\n"[..];
        let got = read_head(&mut truncated, &mut Vec::new()).await;
        assert!(matches!(got, Err(HeadError::Closed)), "{got:?}");
    }
}
