//! Facts about the real machine: `sysinfo()`, `statvfs()` and the machine
//! id. These are the commands about the computer rather than the vehicle,
//! so the simulator answers them truthfully.

use std::ffi::CString;
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::path::Path;

/// What `sysinfo()` reports, in the units the response uses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SysInfo {
    /// Seconds since boot.
    pub uptime_s: i64,
    /// Total RAM, MiB.
    pub ram_total_mb: u64,
    /// Free RAM, MiB.
    pub ram_free_mb: u64,
    /// 1, 5 and 15 minute load averages.
    pub loads: [f64; 3],
    /// Number of processes.
    pub procs: u16,
}

/// Reads `sysinfo(2)`.
// `c_ulong` and the statvfs counters are 32-bit on some targets, so the
// widening conversions are kept even where they are no-ops on x86_64.
#[allow(clippy::useless_conversion)]
pub fn sysinfo() -> io::Result<SysInfo> {
    // SAFETY: `libc::sysinfo` is a plain C struct; all-zero is a valid value.
    let mut info: libc::sysinfo = unsafe { std::mem::zeroed() };
    // SAFETY: the pointer is to a live, writable `sysinfo` struct.
    if unsafe { libc::sysinfo(&mut info) } != 0 {
        return Err(io::Error::last_os_error());
    }
    let unit = u64::from(info.mem_unit.max(1));
    let mb = |v: libc::c_ulong| u64::from(v).saturating_mul(unit) / (1 << 20);
    // Load averages are fixed-point with 16 fractional bits (SI_LOAD_SHIFT).
    let load = |v: libc::c_ulong| u64::from(v) as f64 / 65536.0;
    Ok(SysInfo {
        uptime_s: info.uptime,
        ram_total_mb: mb(info.totalram),
        ram_free_mb: mb(info.freeram),
        loads: [load(info.loads[0]), load(info.loads[1]), load(info.loads[2])],
        procs: info.procs,
    })
}

/// Bytes available to unprivileged users on the filesystem holding `path`.
#[allow(clippy::useless_conversion)]
pub fn available_bytes(path: &Path) -> io::Result<u64> {
    let c_path = CString::new(path.as_os_str().as_bytes())
        .map_err(|_| io::Error::new(io::ErrorKind::InvalidInput, "path holds a NUL byte"))?;
    // SAFETY: `statvfs` is a plain C struct; all-zero is a valid value.
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: `c_path` is a NUL-terminated string and `st` is writable.
    if unsafe { libc::statvfs(c_path.as_ptr(), &mut st) } != 0 {
        return Err(io::Error::last_os_error());
    }
    Ok(u64::from(st.f_bavail).saturating_mul(u64::from(st.f_frsize)))
}

/// The machine id from `file` (normally `/etc/machine-id`), trimmed.
pub fn machine_id(file: &Path) -> io::Result<String> {
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
    fn statvfs_fails_for_a_missing_path() {
        assert!(available_bytes(Path::new("/")).unwrap() > 0);
        assert!(available_bytes(Path::new("/no/such/dir")).is_err());
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
