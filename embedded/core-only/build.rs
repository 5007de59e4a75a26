//! Puts the board's (or, with feature `qemu`, QEMU mps2-an500's) memory.x
//! where the linker looks for it, and writes the benchmark's 1 KiB mission
//! frame with `core/benches/frames/workload.rs` itself, so
//! that the Cortex-M and host instruction counts are of the same frames.

use std::path::PathBuf;
use std::{env, fs};

#[path = "../../core/benches/frames/workload.rs"]
#[allow(dead_code)] // only the mission frame is needed here
mod workload;

fn main() {
    let out = PathBuf::from(env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let memory = if env::var_os("CARGO_FEATURE_QEMU").is_some() {
        "memory-qemu.x"
    } else {
        "memory-h743.x"
    };
    fs::copy(memory, out.join("memory.x")).expect("copy memory.x");
    fs::write(out.join("mission.txt"), workload::mission_1k()).expect("write the mission frame");
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed=memory-h743.x");
    println!("cargo:rerun-if-changed=memory-qemu.x");
}
