//! Arbitrary bytes as the HTTP upgrade request, into both adapters'
//! connection code: never a panic. The embedded adapter answers `101` or
//! `400` and nothing else; and whatever its validator accepts is safe for
//! embedded-websocket 0.9.5's own header reader, whose 24-byte `unwrap`s on
//! `Sec-WebSocket-Key` and `Sec-WebSocket-Protocol` would halt a board.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lluav_embedded::handshake;

fuzz_target!(|data: &[u8]| {
    let Some((&piece, request)) = data.split_first() else {
        return;
    };

    let out = lluav_fuzz::embedded(request, usize::from(piece % 64) + 1);
    assert!(
        out.is_empty() || out.starts_with(b"HTTP/1.1 101 ") || out == handshake::BAD_REQUEST,
        "unexpected answer {:?}",
        String::from_utf8_lossy(&out)
    );

    if let Some(end) = handshake::head_end(request)
        && handshake::parse(&request[..end]).is_ok()
    {
        let mut headers = [httparse::EMPTY_HEADER; 64];
        let mut req = httparse::Request::new(&mut headers);
        if let Ok(httparse::Status::Complete(_)) = req.parse(&request[..end]) {
            let _ = embedded_websocket::read_http_header(req.headers.iter().map(|h| (h.name, h.value)));
        }
    }

    let out = lluav_fuzz::host(request, &[]);
    assert!(
        out.is_empty() || out.starts_with(b"HTTP/1.1 "),
        "{:?}",
        String::from_utf8_lossy(&out)
    );
});
