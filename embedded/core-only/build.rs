//! Puts the board's (or, with feature `qemu`, QEMU mps2-an500's) memory.x
//! where the linker looks for it, and writes the benchmark's 1 KiB mission
//! frame, built exactly as `core/benches/frames/workload.rs` builds it so
//! that the Cortex-M and host instruction counts are of the same frames.

use std::path::PathBuf;
use std::{env, fs};

fn mission_1k() -> String {
    let mut wps: Vec<String> = Vec::new();
    let mut i = 0;
    loop {
        let wp = format!(r#"{{"x":{}.5,"y":-{}.25,"z":-10,"yaw":0.{}}}"#, i, i * 2, i % 10);
        let len: usize = wps.iter().map(|w| w.len() + 1).sum::<usize>() + wp.len();
        if len > 1000 {
            break;
        }
        wps.push(wp);
        i += 1;
    }
    format!(r#"mission 1001:{{"waypoints":[{}]}}"#, wps.join(","))
}

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let memory = if env::var_os("CARGO_FEATURE_QEMU").is_some() {
        "memory-qemu.x"
    } else {
        "memory-h743.x"
    };
    fs::copy(memory, out.join("memory.x")).expect("copy memory.x");
    fs::write(out.join("mission.txt"), mission_1k()).expect("write the mission frame");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-h743.x");
    println!("cargo:rerun-if-changed=memory-qemu.x");
}
