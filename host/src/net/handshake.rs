//! The HTTP request head of a new connection: read here, bounded in
//! size, judged by the core ([`lluav_core::websocket::handshake`]: RFC
//! 6455's upgrade check and the Origin/Host policy, the MCU's too), and
//! answered — `101` and the stream goes on to the WebSocket layer, a plain
//! HTTP request goes to the [`Http`](super::Http) handler the daemon
//! passed in (the console), anything else gets its status and is closed.

use std::fmt;

use lluav_core::websocket::handshake::{KEY_LEN, Rejection, head_end};
use lluav_core::websocket::policy::Forbidden;
use tokio::io::{AsyncRead, AsyncReadExt};
use tokio_tungstenite::tungstenite::handshake::derive_accept_key;

/// Largest request head read; a longer one is refused with 431.
pub const MAX_HEAD: usize = 8 * 1024;

/// Why a request is refused, each with its HTTP status.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The core's upgrade check or Origin/Host policy says no (400, 403,
    /// 405, 426, 431).
    Request(Rejection),
    /// 503: no session slot for this connection; the text says which limit.
    Unavailable(String),
}

impl fmt::Display for Refusal {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Refusal::Request(Rejection::Forbidden(Forbidden::Origin)) => {
                f.write_str("this Origin may not open sessions (lluavd --allow-origin)")
            }
            Refusal::Request(Rejection::Forbidden(Forbidden::Host)) => {
                f.write_str("this Host name is not served here (lluavd --allow-host)")
            }
            Refusal::Request(Rejection::TooLarge) => {
                write!(f, "the request head is longer than {MAX_HEAD} bytes")
            }
            Refusal::Request(why) => f.write_str(why.reason()),
            Refusal::Unavailable(why) => f.write_str(why),
        }
    }
}

impl Refusal {
    fn status(&self) -> (u16, &'static str) {
        match self {
            Refusal::Request(why) => why.status(),
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
            Refusal::Request(Rejection::MethodNotAllowed) => "Allow: GET\r\n",
            Refusal::Request(Rejection::UpgradeRequired) => {
                "Sec-WebSocket-Version: 13\r\nUpgrade: websocket\r\n"
            }
            Refusal::Unavailable(_) => "Retry-After: 1\r\n",
            Refusal::Request(_) => "",
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
pub fn switching_protocols(key: &[u8; KEY_LEN]) -> Vec<u8> {
    format!(
        "HTTP/1.1 101 Switching Protocols\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Accept: {}\r\n\r\n",
        derive_accept_key(key)
    )
    .into_bytes()
}

/// The answer to a plain HTTP request when the daemon passed no handler.
pub fn not_found() -> Vec<u8> {
    b"HTTP/1.1 404 Not Found\r\nContent-Length: 0\r\nConnection: close\r\n\r\n".to_vec()
}

/// Why no complete head arrived.
#[derive(Debug)]
pub enum HeadError {
    /// The peer closed, or the socket failed, before the head was complete.
    Closed,
    /// The head is longer than [`MAX_HEAD`].
    TooLarge,
}

/// Reads into `buf` until it holds a complete request head and returns the
/// head's length; bytes after it (a client that did not wait for the
/// `101`) stay in `buf`. The caller bounds the time.
pub async fn read_head<S: AsyncRead + Unpin>(stream: &mut S, buf: &mut Vec<u8>) -> Result<usize, HeadError> {
    loop {
        // A client dripping one byte at a time costs a scan of its new
        // bytes (and the three before them), not of the whole head.
        let searched_from = buf.len().saturating_sub(3);
        buf.reserve(2048);
        match stream.read_buf(buf).await {
            Ok(0) | Err(_) => return Err(HeadError::Closed),
            Ok(_) => {}
        }
        if let Some(end) = head_end(buf.get(searched_from..).unwrap_or_default()) {
            let len = searched_from + end;
            return if len <= MAX_HEAD {
                Ok(len)
            } else {
                Err(HeadError::TooLarge)
            };
        }
        if buf.len() > MAX_HEAD {
            return Err(HeadError::TooLarge);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: &[u8; KEY_LEN] = b"dGhlIHNhbXBsZSBub25jZQ==";

    fn upgrade() -> String {
        "GET /chat HTTP/1.1\r\nHost: 127.0.0.1:53001\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
         Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
            .to_owned()
    }

    #[test]
    fn the_101_answer_carries_the_rfc_accept_value() {
        let answer = String::from_utf8(switching_protocols(KEY)).expect("ASCII");
        // The example of RFC 6455, section 1.3.
        assert!(
            answer.contains("Sec-WebSocket-Accept: s3pPLMBiTxaQ9kYGzzhZRbK+xOo=\r\n"),
            "{answer}"
        );
        assert!(answer.starts_with("HTTP/1.1 101 ") && answer.ends_with("\r\n\r\n"));
    }

    #[test]
    fn refusals_are_answered_with_their_status_headers_and_reason() {
        let cases = [
            (
                Refusal::Request(Rejection::MethodNotAllowed),
                "405 ",
                "Allow: GET",
            ),
            (
                Refusal::Request(Rejection::UpgradeRequired),
                "426 ",
                "Sec-WebSocket-Version: 13",
            ),
            (
                Refusal::Request(Rejection::TooLarge),
                "431 ",
                "longer than 8192 bytes",
            ),
            (
                Refusal::Request(Rejection::Forbidden(Forbidden::Origin)),
                "403 ",
                "--allow-origin",
            ),
            (Refusal::Unavailable("full".into()), "503 ", "Retry-After: 1"),
        ];
        for (refusal, status, text) in cases {
            let bytes = String::from_utf8(refusal.to_bytes()).expect("ASCII");
            assert!(bytes.starts_with(&format!("HTTP/1.1 {status}")), "{bytes}");
            assert!(bytes.contains(text), "{bytes}");
            let (head, body) = bytes.split_once("\r\n\r\n").expect("a head");
            assert!(
                head.contains(&format!("Content-Length: {}", body.len())),
                "{bytes}"
            );
        }
    }

    #[tokio::test]
    async fn a_head_is_read_whole_and_what_follows_it_is_kept() {
        let mut bytes = upgrade().into_bytes();
        let len = bytes.len();
        bytes.extend_from_slice(b"\x81\x05");
        let mut stream = &bytes[..];
        let mut buf = Vec::new();
        assert_eq!(read_head(&mut stream, &mut buf).await.ok(), Some(len));
        assert_eq!(buf.get(len..), Some(&b"\x81\x05"[..]));
    }

    #[tokio::test]
    async fn an_endless_head_is_refused_as_too_large() {
        let bytes = format!("GET / HTTP/1.1\r\nX: {}\r\n\r\n", "a".repeat(MAX_HEAD));
        let mut stream = bytes.as_bytes();
        let got = read_head(&mut stream, &mut Vec::new()).await;
        assert!(matches!(got, Err(HeadError::TooLarge)), "{got:?}");
        let mut truncated = &b"GET / HTTP/1.1\r\nHost: x\r\n"[..];
        let got = read_head(&mut truncated, &mut Vec::new()).await;
        assert!(matches!(got, Err(HeadError::Closed)), "{got:?}");
    }
}
