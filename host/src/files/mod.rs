//! The data directory: where maps, images, bags, videos, logs, missions
//! and the daemon's own state live. A vehicle backend reads mission files
//! and stores camera images and videos through [`Files`] too, so the rules
//! below hold for every backend.
//!
//! Client paths reach only the areas made for them, the subdirectories
//! `maps/`, `images/`, `bags/`, `videos/`, `logs/` and `missions/`; the
//! daemon's own files (the password, parameters, saved state,
//! and whatever else the operator keeps there) are never read, listed or
//! removed for a client. The core already refuses absolute paths, `..` and
//! unsafe names; here every client path is joined to its area and walked
//! component by component without following symlinks, and a symlink whose
//! target is not inside an area is refused.

use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io::{self, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Component, Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use nix::fcntl::OFlag;
use nix::sys::statvfs;

use crate::recent_log::utc_date;

mod error;
mod saved;
pub use error::{Error, Result};
pub(crate) use saved::Saved;

/// Subdirectories of the data directory.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Area {
    /// Saved maps, one file each.
    Maps,
    /// Image directories, one per capture session.
    Images,
    /// Recorded bags, one file each.
    Bags,
    /// Downloaded camera videos.
    Videos,
    /// Saved log messages.
    Logs,
    /// Mission files clients put there (`mission`, `ai1_mission`,
    /// `test_listwp` read them).
    Missions,
}

impl Area {
    const ALL: [Area; 6] = [
        Area::Maps,
        Area::Images,
        Area::Bags,
        Area::Videos,
        Area::Logs,
        Area::Missions,
    ];

    /// The subdirectory's name.
    pub(crate) fn dir_name(self) -> &'static str {
        match self {
            Area::Maps => "maps",
            Area::Images => "images",
            Area::Bags => "bags",
            Area::Videos => "videos",
            Area::Logs => "logs",
            Area::Missions => "missions",
        }
    }
}

/// The data directory of the companion computer.
#[derive(Clone, Debug)]
pub struct Files {
    root: PathBuf,
}

impl Files {
    /// Creates `root` and its subdirectories if needed.
    pub(crate) fn open(root: &Path) -> io::Result<Files> {
        fs::create_dir_all(root)?;
        let root = fs::canonicalize(root)?;
        let data = Files { root };
        for area in Area::ALL {
            let dir = data.area(area);
            fs::create_dir_all(&dir)?;
            // Listing and clearing read these directories directly, so a
            // subdirectory that is a link out of the data directory is an
            // error at start rather than a hole later.
            if data.resolve(area.dir_name()).is_err() {
                return Err(io::Error::new(
                    io::ErrorKind::InvalidInput,
                    format!("{} leaves the data directory", dir.display()),
                ));
            }
        }
        Ok(data)
    }

    /// The directory itself (canonical).
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// A subdirectory.
    pub(crate) fn area(&self, area: Area) -> PathBuf {
        self.root.join(area.dir_name())
    }

    /// Resolves a relative path inside the data directory, refusing
    /// symlinks whose target is not inside an [`Area`]. The path need not
    /// exist; whatever part of it exists is checked.
    fn resolve(&self, rel: &str) -> Result<PathBuf> {
        let mut path = self.root.clone();
        for component in Path::new(rel).components() {
            match component {
                Component::Normal(part) => path.push(part),
                Component::CurDir => {}
                _ => return Err(Error::Escapes(rel.into())),
            }
            match fs::symlink_metadata(&path) {
                Ok(meta) if meta.file_type().is_symlink() => {
                    let target = fs::canonicalize(&path).map_err(|_| Error::Escapes(rel.into()))?;
                    if !Area::ALL.iter().any(|&a| target.starts_with(self.area(a))) {
                        return Err(Error::Escapes(rel.into()));
                    }
                }
                Ok(_) => {}
                // The rest does not exist yet, so nothing further can be a link.
                Err(e) if e.kind() == io::ErrorKind::NotFound => break,
                Err(e) => return Err(Error::about("stat", rel, e)),
            }
        }
        Ok(path)
    }

    /// Resolves a single name inside `area`.
    pub(crate) fn named(&self, area: Area, name: &str) -> Result<PathBuf> {
        if !matches!(
            Path::new(name).components().collect::<Vec<_>>()[..],
            [Component::Normal(_)]
        ) {
            return Err(Error::Escapes(name.into()));
        }
        self.within(area, name)
    }

    /// Resolves a client's relative path inside `area`.
    pub(crate) fn within(&self, area: Area, rel: &str) -> Result<PathBuf> {
        self.resolve(&format!("{}/{rel}", area.dir_name()))
    }

    /// Reads a client's mission file, `missions/<path>` (the client names
    /// it relative to the data directory), at most `limit` bytes, as UTF-8.
    /// Errors never show the file's content.
    pub fn read_mission_file(&self, rel: &str, limit: u64) -> Result<String> {
        let area = Area::Missions.dir_name();
        let inside = rel
            .strip_prefix(area)
            .and_then(|r| r.strip_prefix('/'))
            .ok_or_else(|| Error::NotFound(format!("{rel} is not in {area}/")))?;
        let path = self.within(Area::Missions, inside)?;
        let meta = fs::metadata(&path).map_err(|e| Error::about("stat", rel, e))?;
        if !meta.is_file() {
            return Err(Error::NotFound(format!("{rel} is not a file")));
        }
        if meta.len() > limit {
            return Err(Error::Invalid(format!("{rel} is larger than {limit} bytes")));
        }
        let bytes = fs::read(&path).map_err(|e| Error::about("read", rel, e))?;
        String::from_utf8(bytes).map_err(|_| Error::Invalid(format!("{rel} is not UTF-8")))
    }

    /// Stores a camera image as a new file `name` in the capture directory
    /// of the UTC day of `now_ms` (`images/YYYYMMDD`, created if needed);
    /// returns that directory's name.
    pub fn store_image(&self, now_ms: i64, name: &str, bytes: &[u8]) -> Result<String> {
        let dir_name = capture_dir(now_ms);
        let dir = self.named(Area::Images, &dir_name)?;
        fs::create_dir_all(&dir).map_err(|e| Error::io("create image directory", e))?;
        create_file(&dir.join(name), bytes).map_err(|e| Error::io(format!("write {name}"), e))?;
        Ok(dir_name)
    }

    /// Stores a downloaded camera video as `videos/<name>` (replacing one
    /// of that name); returns its path relative to the data directory.
    pub fn store_video(&self, name: &str, bytes: &[u8]) -> Result<String> {
        let path = self.named(Area::Videos, name)?;
        atomic_write(&path, bytes, 0o644).map_err(|e| Error::io(format!("write {name}"), e))?;
        Ok(format!("{}/{name}", Area::Videos.dir_name()))
    }

    /// Bytes available to unprivileged users on the data directory's
    /// filesystem.
    pub fn free_bytes(&self) -> Result<u64> {
        available_bytes(&self.root).map_err(|e| Error::io("statvfs()", e))
    }
}

/// Bytes available to unprivileged users on the filesystem holding `path`.
// The statvfs counters are 32-bit on some targets.
#[allow(clippy::useless_conversion)]
pub(crate) fn available_bytes(path: &Path) -> io::Result<u64> {
    let st = statvfs::statvfs(path)?;
    Ok(u64::from(st.blocks_available()).saturating_mul(u64::from(st.fragment_size())))
}

/// The directory cameras write into on the UTC day of `now_ms`: the one
/// `clear_images` never deletes.
pub(crate) fn capture_dir(now_ms: i64) -> String {
    let since_epoch = Duration::from_millis(u64::try_from(now_ms).unwrap_or(0));
    utc_date(UNIX_EPOCH + since_epoch)
}

/// Writes `bytes` to `path` so that a crash leaves either the old or the new
/// content: a temp file in the same directory, fsync, rename, fsync of the
/// directory.
pub(crate) fn atomic_write(path: &Path, bytes: &[u8], mode: u32) -> io::Result<()> {
    static SEQ: AtomicU64 = AtomicU64::new(0);
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut tmp_name = OsString::from(".");
    tmp_name.push(path.file_name().unwrap_or_default());
    tmp_name.push(format!(
        ".tmp.{}.{}",
        std::process::id(),
        SEQ.fetch_add(1, Ordering::Relaxed)
    ));
    let tmp = dir.join(tmp_name);
    let result = (|| {
        let mut f = OpenOptions::new()
            .write(true)
            .create_new(true)
            .mode(mode)
            .open(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)?;
        File::open(dir)?.sync_all()
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Writes a new file that must not exist yet (never through a link).
pub(crate) fn create_file(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut f = OpenOptions::new()
        .write(true)
        .create_new(true)
        .custom_flags(OFlag::O_NOFOLLOW.bits())
        .open(path)?;
    f.write_all(bytes)
}

/// A regular file or real directory (never a link) in an area.
#[derive(Clone, Debug)]
pub(crate) struct Entry {
    /// Its name.
    pub(crate) name: String,
    /// Its full path.
    pub(crate) path: PathBuf,
    /// Size in bytes (of all regular files inside, for a directory).
    pub(crate) bytes: u64,
    /// Regular files inside (1 for a file).
    pub(crate) files: u64,
    /// Last modification.
    pub(crate) modified: SystemTime,
}

impl Entry {
    /// Modification time in milliseconds since the Unix epoch.
    pub(crate) fn modified_ms(&self) -> i64 {
        self.modified
            .duration_since(SystemTime::UNIX_EPOCH)
            .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
    }
}

/// What [`entries`] lists.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    /// Regular files.
    Files,
    /// Directories.
    Dirs,
}

/// The entries of `dir` of one kind, oldest first (ties by name). Links and
/// hidden temp files are skipped.
pub(crate) fn entries(dir: &Path, kind: Kind) -> io::Result<Vec<Entry>> {
    let mut out = Vec::new();
    for item in fs::read_dir(dir)? {
        let item = item?;
        let Ok(name) = item.file_name().into_string() else {
            continue;
        };
        let meta = item.metadata()?;
        let wanted = match kind {
            Kind::Files => meta.file_type().is_file(),
            Kind::Dirs => meta.file_type().is_dir(),
        };
        if !wanted || name.starts_with('.') {
            continue;
        }
        let (bytes, files) = match kind {
            Kind::Files => (meta.len(), 1),
            Kind::Dirs => dir_usage(&item.path())?,
        };
        out.push(Entry {
            name,
            path: item.path(),
            bytes,
            files,
            modified: meta.modified()?,
        });
    }
    out.sort_by(|a, b| a.modified.cmp(&b.modified).then_with(|| a.name.cmp(&b.name)));
    Ok(out)
}

fn dir_usage(dir: &Path) -> io::Result<(u64, u64)> {
    let (mut bytes, mut files) = (0, 0);
    for item in fs::read_dir(dir)? {
        let meta = item?.metadata()?;
        if meta.is_file() {
            bytes += meta.len();
            files += 1;
        }
    }
    Ok((bytes, files))
}

/// Removes a regular file or a real directory tree (links inside are
/// removed, never followed).
fn remove_entry(path: &Path) -> io::Result<()> {
    let meta = fs::symlink_metadata(path)?;
    if meta.is_dir() {
        fs::remove_dir_all(path)
    } else {
        fs::remove_file(path)
    }
}

/// Deletes entries of `dir`, oldest first, until `enough()` holds (checked
/// before each deletion) or none are left; `keep` is never deleted.
/// Returns the names removed.
pub(crate) fn clear_oldest(
    dir: &Path,
    kind: Kind,
    keep: Option<&Path>,
    mut enough: impl FnMut() -> io::Result<bool>,
) -> io::Result<Vec<String>> {
    let mut removed = Vec::new();
    for entry in entries(dir, kind)? {
        if keep == Some(entry.path.as_path()) {
            continue;
        }
        if enough()? {
            break;
        }
        remove_entry(&entry.path)?;
        removed.push(entry.name);
    }
    Ok(removed)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::symlink;

    #[test]
    fn statvfs_fails_for_a_missing_path() {
        assert!(available_bytes(Path::new("/")).unwrap() > 0);
        assert!(available_bytes(Path::new("/no/such/dir")).is_err());
    }

    #[test]
    fn symlinks_leaving_the_client_areas_are_refused() {
        let outside = tempfile::tempdir().unwrap();
        fs::write(outside.path().join("secret"), "x").unwrap();
        let dir = tempfile::tempdir().unwrap();
        let data = Files::open(dir.path()).unwrap();
        fs::write(data.root().join("password"), "12345x").unwrap();
        let missions = data.area(Area::Missions);
        symlink(outside.path(), missions.join("out")).unwrap();
        symlink(data.root().join("password"), missions.join("pw")).unwrap();
        symlink(outside.path().join("secret"), data.area(Area::Maps).join("m")).unwrap();
        assert!(matches!(data.named(Area::Maps, "m"), Err(Error::Escapes(_))));
        for path in ["missions/out/secret", "missions/pw"] {
            assert!(
                matches!(data.read_mission_file(path, 10), Err(Error::Escapes(_))),
                "{path}"
            );
        }
    }

    #[test]
    fn mission_files_are_read_from_missions_only() {
        let dir = tempfile::tempdir().unwrap();
        let data = Files::open(dir.path()).unwrap();
        fs::write(data.root().join("params.json"), "{}").unwrap();
        fs::write(data.area(Area::Maps).join("m1"), "{}").unwrap();
        for path in ["params.json", "maps/m1", "missionsx/a", "missions"] {
            let e = data.read_mission_file(path, 10).unwrap_err();
            assert_eq!(
                e.to_string(),
                format!("Invalid arguments: {path} is not in missions/")
            );
        }
    }

    #[test]
    fn a_subdirectory_linked_out_of_the_data_dir_stops_open() {
        let outside = tempfile::tempdir().unwrap();
        let dir = tempfile::tempdir().unwrap();
        symlink(outside.path(), dir.path().join("maps")).unwrap();
        let e = Files::open(dir.path()).unwrap_err();
        assert!(e.to_string().ends_with("maps leaves the data directory"), "{e}");
    }

    #[test]
    fn symlinks_from_one_client_area_into_another_are_followed() {
        let dir = tempfile::tempdir().unwrap();
        let data = Files::open(dir.path()).unwrap();
        fs::write(data.area(Area::Maps).join("real"), "map").unwrap();
        symlink(data.area(Area::Maps), data.area(Area::Missions).join("alias")).unwrap();
        assert_eq!(data.read_mission_file("missions/alias/real", 10).unwrap(), "map");
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temp_files() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("state");
        atomic_write(&file, b"one", 0o600).unwrap();
        atomic_write(&file, b"two", 0o600).unwrap();
        assert_eq!(fs::read(&file).unwrap(), b"two");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn clear_oldest_stops_when_enough_and_keeps_the_kept_entry() {
        let dir = tempfile::tempdir().unwrap();
        for (i, name) in ["a", "b", "c"].iter().enumerate() {
            let p = dir.path().join(name);
            fs::write(&p, "x").unwrap();
            let t = SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(1_000 + i as u64);
            File::options()
                .write(true)
                .open(&p)
                .unwrap()
                .set_modified(t)
                .unwrap();
        }
        let keep = dir.path().join("a");
        let mut budget = 1;
        let removed = clear_oldest(dir.path(), Kind::Files, Some(&keep), || {
            budget -= 1;
            Ok(budget < 0)
        })
        .unwrap();
        assert_eq!(removed, ["b"]);
        let left: Vec<_> = entries(dir.path(), Kind::Files)
            .unwrap()
            .into_iter()
            .map(|e| e.name)
            .collect();
        assert_eq!(left, ["a", "c"]);
    }
}
