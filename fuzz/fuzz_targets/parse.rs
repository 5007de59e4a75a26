//! Arbitrary bytes into the parser: never a panic, and whatever parses
//! encodes back to text that parses to the same command.
#![no_main]

use libfuzzer_sys::fuzz_target;
use lluav_core::{Command, parse};

fuzz_target!(|data: &[u8]| {
    let text = String::from_utf8_lossy(data);
    if let Ok(cmd) = parse(&text) {
        let encoded = cmd.to_string();
        assert_eq!(
            parse(&encoded),
            Ok(cmd.clone()),
            "{text:?} encoded as {encoded:?}"
        );
        assert_eq!(Command::new(cmd.id(), cmd.args().clone()), Ok(cmd));
    }
});
