//! Maps: files in the map directory `maps/`. Every map path a client gives
//! (`savemap`, `set_mappath`, `rm_map`) is relative to that directory, so
//! `savemap m1` then `set_mappath m1` names the same map; `list_maps`
//! lists the map files directly in it, newest first (as many as fit). The
//! map in use (kept across a restart) and the keyframe count are the `kfs`
//! object of `hud1` and `get_submap_info`.

use std::fs;

use lluav_core::{Args, Command, CommandId, Fields};

use super::Kept;
use super::error::{Error, Result};
use super::images::write_entries;
use crate::files::{self, Area, Files, Kind, Saved, atomic_write};
use crate::vehicle::Snapshot;

/// Map keyframes are taken every this many metres flown.
const KEYFRAME_SPACING_M: f64 = 2.0;

/// Keyframes of the live map: one at the start, one per spacing flown.
fn keyframes(vehicle: &Snapshot) -> u64 {
    1 + (vehicle.distance_m / KEYFRAME_SPACING_M) as u64
}

/// `savemap`, `set_mappath`, `list_maps`, `rm_map`; the map in use is
/// `kept.map_path`, saved before it changes.
pub(super) fn run(
    cmd: &Command<'_>,
    files: &Files,
    now_ms: i64,
    vehicle: &Snapshot,
    kept: &mut Saved<Kept>,
    out: &mut Fields<'_>,
) -> Result {
    match (cmd.id(), cmd.args()) {
        (CommandId::Savemap, Args::Name(name)) => save(name, files, now_ms, vehicle, out),
        (CommandId::SetMappath, Args::Path(path)) => choose(path, files, kept, out),
        (CommandId::RmMap, Args::Name(name)) => remove(name, files, kept, out),
        (CommandId::ListMaps, _) => {
            let mut maps = files::entries(&files.area(Area::Maps), Kind::Files)
                .map_err(|e| Error::io("list maps", e))?;
            maps.reverse();
            let total = maps.len();
            write_entries(out, "maps", maps, total);
            Ok(())
        }
        (id, _) => Err(Error::NotOwned(id.name())),
    }
}

fn choose(path: &str, files: &Files, kept: &mut Saved<Kept>, out: &mut Fields<'_>) -> Result {
    let full = files.within(Area::Maps, path)?;
    let meta = fs::metadata(&full).map_err(|e| Error::about("stat", path, e))?;
    if !meta.is_file() {
        return Err(Error::not_found(format!("{path} is not a map file")));
    }
    kept.update(|k| k.map_path = Some(path.to_owned()))
        .map_err(|e| Error::io("save the map path", e))?;
    out.str("map_path", path);
    Ok(())
}

fn remove(name: &str, files: &Files, kept: &Saved<Kept>, out: &mut Fields<'_>) -> Result {
    let path = files.named(Area::Maps, name)?;
    let meta = fs::symlink_metadata(&path).map_err(|e| Error::about("stat", name, e))?;
    if meta.is_dir() {
        return Err(Error::not_found(format!("{name} is not a map file")));
    }
    if kept.get().map_path.as_deref() == Some(name) {
        return Err(Error::MapInUse(name.to_owned()));
    }
    fs::remove_file(&path).map_err(|e| Error::about("remove", name, e))?;
    tracing::info!(map = name, "map removed");
    out.str("removed", name);
    Ok(())
}

/// Writes `kfs`: the map in use (`null` for the live map) and its
/// keyframe count. `hud1` and `get_submap_info` share this one shape.
pub(super) fn write_kfs(kept: &Kept, vehicle: &Snapshot, out: &mut Fields<'_>) {
    out.object("kfs", |o| {
        match &kept.map_path {
            Some(map) => o.str("map_id", map),
            None => o.null("map_id"),
        };
        o.u64("count", keyframes(vehicle));
    });
}

/// Saves the live map as `maps/<name>`: its keyframes and origin. A
/// directory of that name is the client's mistake (-2), not a failure of
/// this machine.
fn save(name: &str, files: &Files, now_ms: i64, vehicle: &Snapshot, out: &mut Fields<'_>) -> Result {
    let path = files.named(Area::Maps, name)?;
    if fs::symlink_metadata(&path).is_ok_and(|m| m.is_dir()) {
        return Err(Error::not_found(format!("{name} is a directory, not a map file")));
    }
    let p = vehicle.position;
    let map = serde_json::json!({
        "name": name,
        "keyframes": keyframes(vehicle),
        "origin": {"x": p.x as f32, "y": p.y as f32, "z": p.z as f32},
        "created_ms": now_ms,
    });
    let bytes = serde_json::to_vec_pretty(&map).map_err(|e| Error::io("encode map", e.into()))?;
    atomic_write(&path, &bytes, 0o644).map_err(|e| Error::io(format!("write map {name}"), e))?;
    tracing::info!(map = name, "map saved");
    out.object("map", |o| {
        o.str("name", name).u64("bytes", bytes.len() as u64);
    });
    Ok(())
}
