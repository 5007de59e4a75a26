//! Facts about the real machine: `sysinfo(2)` and the machine id,
//! through nix's safe wrappers.

use std::io;
use std::path::Path;

use nix::sys::sysinfo;

/// What `sysinfo()` reports, in the units the response uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct SysInfo {
    /// Seconds since boot.
    pub(crate) uptime_s: u64,
    /// Total RAM, MiB.
    pub(crate) ram_total_mb: u64,
    /// Free RAM, MiB.
    pub(crate) ram_free_mb: u64,
    /// 1, 5 and 15 minute load averages.
    pub(crate) loads: [f64; 3],
    /// Number of processes.
    pub(crate) procs: u16,
}

/// Reads `sysinfo(2)`.
pub(crate) fn sysinfo() -> io::Result<SysInfo> {
    let info = sysinfo::sysinfo()?;
    let (one, five, fifteen) = info.load_average();
    Ok(SysInfo {
        uptime_s: info.uptime().as_secs(),
        ram_total_mb: info.ram_total() >> 20,
        ram_free_mb: info.ram_unused() >> 20,
        loads: [one, five, fifteen],
        procs: info.process_count(),
    })
}

/// The machine id from `file` (normally `/etc/machine-id`), trimmed.
pub(crate) fn machine_id(file: &Path) -> io::Result<String> {
    let id = std::fs::read_to_string(file)?.trim().to_owned();
    if id.is_empty() {
        return Err(io::Error::new(io::ErrorKind::InvalidData, "empty machine id"));
    }
    Ok(id)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sysinfo_reports_a_running_machine() {
        let info = sysinfo().unwrap();
        assert!(info.uptime_s > 0);
        assert!(info.ram_total_mb > 0 && info.ram_free_mb <= info.ram_total_mb);
        assert!(info.procs > 0);
    }

    #[test]
    fn machine_id_is_trimmed_and_must_exist() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("machine-id");
        std::fs::write(&file, "abc123\n").unwrap();
        assert_eq!(machine_id(&file).unwrap(), "abc123");
        assert!(machine_id(&dir.path().join("missing")).is_err());
    }
}
