//! Image directories under `images/`: listed, removed, cleared. Cameras
//! write into the directory of the current UTC day ([`Files::store_image`]);
//! that directory is being written now, so `clear_images` never deletes it
//! (`rm_imagedir` does, when asked by name).

use std::fs;

use lluav_core::{Args, Command, Fields};

use super::error::{Error, Result};
use super::fit::{fitting, json_str_len, write_counts, write_strings};
use crate::files::{self, Area, Entry, Files, Kind, capture_dir};

/// `list_imagedir`, `rm_imagedir`, `clear_images`.
pub(super) fn run(cmd: &Command<'_>, files: &Files, now_ms: i64, out: &mut Fields<'_>) -> Result {
    match cmd.args() {
        &Args::OptCount(size) => list(files, size, out),
        Args::Name(name) => remove(files, name, out),
        &Args::OptAmount(min_gb) => {
            let keep = files.named(Area::Images, &capture_dir(now_ms))?;
            clear(files, Area::Images, min_gb.map(|n| n.value()), Some(&keep), out)
        }
        _ => Err(Error::NotOwned(cmd.id().name())),
    }
}

/// Lists image directories, newest first, at most `size` of them (and as
/// many as fit).
fn list(files: &Files, size: Option<u32>, out: &mut Fields<'_>) -> Result {
    let mut dirs = files::entries(&files.area(Area::Images), Kind::Dirs)
        .map_err(|e| Error::io("list image directories", e))?;
    dirs.reverse();
    let total = dirs.len();
    if let Some(n) = size {
        dirs.truncate(usize::try_from(n).unwrap_or(usize::MAX));
    }
    write_entries(out, "imagedirs", dirs, total);
    Ok(())
}

fn remove(files: &Files, name: &str, out: &mut Fields<'_>) -> Result {
    let path = files.named(Area::Images, name)?;
    let meta = fs::symlink_metadata(&path).map_err(|e| Error::about("stat", name, e))?;
    if !meta.is_dir() {
        return Err(Error::not_found(format!("{name} is not an image directory")));
    }
    fs::remove_dir_all(&path).map_err(|e| Error::about("remove", name, e))?;
    tracing::info!(dir = name, "image directory removed");
    out.str("removed", name);
    Ok(())
}

/// Deletes the oldest entries of `area` until at least `min_gb` GiB are
/// free, or all of them when no `min_gb` is given; `keep` (what is being
/// written now) is never deleted. Answers what went and what is free.
pub(super) fn clear(
    files: &Files,
    area: Area,
    min_gb: Option<f32>,
    keep: Option<&std::path::Path>,
    out: &mut Fields<'_>,
) -> Result {
    let kind = if area == Area::Images {
        Kind::Dirs
    } else {
        Kind::Files
    };
    let want = min_gb.map(|gb| (f64::from(gb) * f64::from(1u32 << 30)) as u64);
    let removed = files::clear_oldest(&files.area(area), kind, keep, || match want {
        Some(bytes) => Ok(files::available_bytes(files.root())? >= bytes),
        None => Ok(false),
    })
    .map_err(|e| Error::io(format!("clear {}", area.dir_name()), e))?;
    tracing::info!(area = area.dir_name(), removed = removed.len(), "cleared");
    let total = removed.len();
    write_strings(out, "removed", removed, total);
    out.u64("available_MB", files.free_bytes()? >> 20);
    Ok(())
}

/// Writes `key` as an array of the entries that fit (name, size, files,
/// modification), then whether any of the `total` there are were left
/// out, and `total`.
pub(super) fn write_entries(out: &mut Fields<'_>, key: &str, entries: Vec<Entry>, total: usize) {
    // `{"name":..,"bytes":..,"files":..,"modified_ms":..}` with every
    // number at its longest.
    let (entries, _) = fitting(entries, |e| json_str_len(&e.name) + 100);
    out.array(key, |a| {
        for e in &entries {
            a.object(|o| {
                o.str("name", &e.name)
                    .u64("bytes", e.bytes)
                    .u64("files", e.files)
                    .i64("modified_ms", e.modified_ms());
            });
        }
    });
    write_counts(out, entries.len(), total);
}
