//! Arbitrary bytes as the HTTP upgrade request, into both adapters'
//! connection code: never a panic. The embedded adapter answers `101`,
//! `400` (malformed) or `403` (Host or Origin refused by its policy) and
//! nothing else, and accepts only requests its validator accepts.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lluav_embedded::handshake;

fuzz_target!(|data: &[u8]| {
    let Some((&piece, request)) = data.split_first() else {
        return;
    };

    let out = lluav_fuzz::embedded(request, usize::from(piece % 64) + 1);
    let accepted = out.starts_with(b"HTTP/1.1 101 ");
    assert!(
        out.is_empty() || accepted || out == handshake::BAD_REQUEST || out == handshake::FORBIDDEN,
        "unexpected answer {:?}",
        String::from_utf8_lossy(&out)
    );
    if accepted {
        let end = handshake::head_end(request).expect("a complete head was accepted");
        assert!(
            handshake::parse(&request[..end]).is_ok(),
            "accepted what the validator rejects"
        );
    }

    let out = lluav_fuzz::host(request, &[]);
    assert!(
        out.is_empty() || out.starts_with(b"HTTP/1.1 "),
        "{:?}",
        String::from_utf8_lossy(&out)
    );
});
