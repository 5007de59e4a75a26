//! What the broker benches share: their flags, latency histograms in ns,
//! and a process's CPU time from `/proc`.

use std::time::Instant;

use hdrhistogram::Histogram;

/// The number after flag `name` on the command line (`--name N`), or
/// `default`.
pub fn flag(name: &str, default: usize) -> usize {
    flag_word(name).and_then(|w| w.parse().ok()).unwrap_or(default)
}

/// The word after flag `name` on the command line (`--name WORD`), if
/// given.
pub fn flag_word(name: &str) -> Option<String> {
    let argv: Vec<String> = std::env::args().collect();
    argv.windows(2)
        .rev()
        .find(|pair| pair[0] == name)
        .map(|pair| pair[1].clone())
}

/// A histogram of nanoseconds, up to a minute.
pub fn histogram() -> Histogram<u64> {
    // Bounds and precision are constants that hdrhistogram accepts.
    Histogram::new_with_bounds(1, 60_000_000_000, 3).expect("valid histogram bounds")
}

/// Records the time since `since`.
pub fn record(h: &mut Histogram<u64>, since: Instant) {
    h.saturating_record(u64::try_from(since.elapsed().as_nanos()).unwrap_or(u64::MAX));
}

/// The quantile `q` of `h`, in µs.
pub fn us(h: &Histogram<u64>, q: f64) -> f64 {
    h.value_at_quantile(q) as f64 / 1000.0
}

/// (utime + stime) in seconds of process `pid` (all its threads, the
/// ones that ended included), in clock ticks of 10 ms.
pub fn cpu_s(pid: u32) -> f64 {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let after_name = stat.rsplit_once(')').map(|(_, rest)| rest).unwrap_or_default();
    let ticks: u64 = after_name
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|f| f.parse::<u64>().ok())
        .sum();
    // SAFETY: sysconf only reads a configuration value.
    let per_s = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    ticks as f64 / if per_s > 0 { per_s as f64 } else { 100.0 }
}
