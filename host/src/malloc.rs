//! The C allocator's arenas, kept few (DESIGN.md, "Uplink": the uplink's
//! memory stays within its bound with any number of client ids).
//!
//! glibc gives each thread that allocates while another holds an arena's
//! lock an arena of its own, up to 8 per core. Every arena keeps the pages
//! of its own high-water mark: freed chunks in the middle of an arena stay
//! resident. tokio's worker and blocking threads take turns running the
//! uplink's requests, so the answers it keeps for their 10 minutes (and
//! the ids' records) are allocated and freed in one arena after another,
//! and each arena grows to hold a good part of them. The bench's 100,000
//! client ids (BENCHMARKS.md, "Uplink") measured +33 MiB of VmRSS over
//! six arenas against about 15 MiB of live heap; with two arenas, +18 MiB.

/// Arenas at most, whatever the threads: two, so that the two workers of
/// a two-core companion computer rarely wait for each other's lock.
pub const ARENAS: i32 = 2;

/// Limits glibc's malloc to [`ARENAS`] arenas. Call it first thing in
/// `main`, before any thread starts. Elsewhere than glibc, nothing.
pub fn limit_arenas() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only sets a parameter of the allocator; it is called
    // before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, ARENAS);
    }
}
