//! Arbitrary bytes as the frame stream after a valid upgrade, into both
//! adapters' connection code (echo configuration): never a panic, and
//! memory bounded by the adapters' fixed limits.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&piece, frames)) = data.split_first() else {
        return;
    };
    let input = [lluav_fuzz::UPGRADE, frames].concat();

    let out = lluav_fuzz::embedded(&input, usize::from(piece % 64) + 1);
    assert!(
        out.starts_with(b"HTTP/1.1 101 "),
        "the valid upgrade was not accepted"
    );

    let out = lluav_fuzz::host(lluav_fuzz::UPGRADE, frames);
    assert!(
        out.starts_with(b"HTTP/1.1 101 "),
        "the valid upgrade was not accepted"
    );
});
