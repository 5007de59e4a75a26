//! Arbitrary bytes as the HTTP upgrade request. The core's upgrade check
//! and Origin/Host policy judge it (never a panic), and both adapters'
//! connection code, configured alike, answer it: each with the status the
//! core's verdict gives (101 for an upgrade it accepts, its rejection's
//! status otherwise), so the MCU and lluavd enforce one policy.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Some((&piece, request)) = data.split_first() else {
        return;
    };
    let expected = lluav_fuzz::expected_status(request);

    let mcu = lluav_fuzz::embedded(request, usize::from(piece % 64) + 1);
    let host = lluav_fuzz::host(request, &[]);
    let answered = (lluav_fuzz::status(&mcu), lluav_fuzz::status(&host));
    assert!(
        mcu.is_empty() || answered.0.is_some(),
        "the MCU answered {:?}",
        String::from_utf8_lossy(&mcu)
    );
    assert!(
        host.is_empty() || answered.1.is_some(),
        "lluavd answered {:?}",
        String::from_utf8_lossy(&host)
    );
    if let Some((mcu_status, host_status)) = expected {
        assert_eq!(
            answered,
            (Some(mcu_status), Some(host_status)),
            "MCU {:?}, lluavd {:?}",
            String::from_utf8_lossy(&mcu),
            String::from_utf8_lossy(&host)
        );
    }
});
