//! lluavd's MAVLink link with the input playing the autopilot and its
//! neighbours on a shared, lossy, spoofable link: garbage datagrams,
//! well-formed messages from a few addresses and systems, signed or not,
//! against what lluavd knows of the autopilot and the command and mission
//! protocols. See `lluav_fuzz::mavlink` for the input format and what is
//! checked.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| lluav_fuzz::mavlink::run(data));
