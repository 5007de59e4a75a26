//! Arbitrary bytes as the frame stream after a valid upgrade, into both
//! adapters' connection code (echo configuration, the same message
//! limit): never a panic, memory bounded, and the first close frame each
//! sends carries the code the core's rules give for that stream (frame
//! headers, fragmentation, UTF-8 as it arrives, the close policy, the
//! answer to a peer's close), or neither sends one.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&piece, frames)) = data.split_first() else {
        return;
    };
    let input = [lluav_fuzz::UPGRADE, frames].concat();
    let expected = lluav_fuzz::expected_close(frames);

    for (adapter, out) in [
        ("MCU", lluav_fuzz::embedded(&input, usize::from(piece % 64) + 1)),
        ("lluavd", lluav_fuzz::host(lluav_fuzz::UPGRADE, frames)),
    ] {
        assert!(
            out.starts_with(b"HTTP/1.1 101 "),
            "{adapter} did not accept the valid upgrade"
        );
        let head = out.windows(4).position(|w| w == b"\r\n\r\n").map_or(0, |i| i + 4);
        let closed = lluav_fuzz::first_close_sent(&out[head..]);
        assert_eq!(closed, expected, "{adapter}'s first close code");
    }
});
