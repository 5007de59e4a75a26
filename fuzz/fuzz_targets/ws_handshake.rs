//! Arbitrary bytes as the HTTP upgrade request, into both adapters'
//! connection code: never a panic. The embedded adapter answers each
//! request with the status the core's upgrade check and Origin/Host policy
//! give it (101 for an upgrade they accept).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&piece, request)) = data.split_first() else {
        return;
    };

    let out = lluav_fuzz::embedded(request, usize::from(piece % 64) + 1);
    let status = lluav_fuzz::status(&out);
    assert!(
        out.is_empty() || status.is_some(),
        "unexpected answer {:?}",
        String::from_utf8_lossy(&out)
    );
    if let Some((expected, _)) = lluav_fuzz::expected_status(request) {
        assert_eq!(status, Some(expected), "{:?}", String::from_utf8_lossy(&out));
    }

    let out = lluav_fuzz::host(request, &[]);
    assert!(
        out.is_empty() || out.starts_with(b"HTTP/1.1 "),
        "{:?}",
        String::from_utf8_lossy(&out)
    );
});
