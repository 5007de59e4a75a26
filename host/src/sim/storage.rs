//! Commands over real files in the data directory: maps, images, bags,
//! camera videos, saved log messages and waypoint files.

use std::fs::{self, OpenOptions};
use std::io::{self, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::time::SystemTime;

use lluav_core::Fields;

use super::error::{SimError, SimResult};
use super::files::{self, Area, Entry, Kind, atomic_write, create_file};
use super::fsm::Ned;
use super::mission::{self, Fence};
use super::{Bag, Simulator, unix_ms};
use crate::recent_log::utc_date;

/// Side of the simulated camera frames, pixels.
const FRAME_SIDE: usize = 8;

/// Appends a bag's buffered samples to its file (never through a link).
pub(super) fn append_samples(bag: &mut Bag) -> io::Result<()> {
    if bag.samples.is_empty() {
        return Ok(());
    }
    let mut f = OpenOptions::new()
        .append(true)
        .custom_flags(libc::O_NOFOLLOW)
        .open(&bag.path)?;
    let mut text = bag.samples.join("\n");
    text.push('\n');
    f.write_all(text.as_bytes())?;
    f.sync_data()?;
    bag.samples.clear();
    Ok(())
}

/// A binary PPM (colour) or PGM (grey) frame: a gradient that differs per
/// frame number, so that every capture is a distinct, valid image.
fn frame(colour: bool, n: u64) -> Vec<u8> {
    let magic = if colour { "P6" } else { "P5" };
    let mut img = format!("{magic}\n{FRAME_SIDE} {FRAME_SIDE}\n255\n").into_bytes();
    for y in 0..FRAME_SIDE {
        for x in 0..FRAME_SIDE {
            let v = ((x * 32 + y * 4) as u64).wrapping_add(n * 17) as u8;
            if colour {
                img.extend_from_slice(&[v, v.wrapping_add(85), v.wrapping_add(170)]);
            } else {
                img.push(v);
            }
        }
    }
    img
}

fn write_entries(out: &mut Fields<'_>, key: &str, entries: &[Entry]) {
    out.array(key, |a| {
        for e in entries {
            a.object(|o| {
                o.str("name", &e.name)
                    .u64("bytes", e.bytes)
                    .u64("files", e.files)
                    .i64("modified_ms", e.modified_ms());
            });
        }
    });
}

fn io_err(what: &str, name: &str) -> impl FnOnce(io::Error) -> SimError {
    let what = format!("{what} {name}");
    move |e| {
        if e.kind() == io::ErrorKind::NotFound {
            SimError::NotFound(name.to_owned())
        } else {
            SimError::io(what, e)
        }
    }
}

impl Simulator {
    pub(super) fn save_map(&mut self, name: &str, out: &mut Fields<'_>) -> SimResult {
        let path = self.data.named(Area::Maps, name)?;
        let pos = self.flight.pos();
        let map = serde_json::json!({
            "name": name,
            "keyframes": 1 + (self.flight.distance_m / 2.0) as u64,
            "origin": {"x": pos.x, "y": pos.y, "z": pos.z},
            "created_ms": unix_ms(),
        });
        let bytes =
            serde_json::to_vec_pretty(&map).map_err(|e| SimError::io("encode map", io::Error::other(e)))?;
        atomic_write(&path, &bytes, 0o644).map_err(|e| SimError::io(format!("write map {name}"), e))?;
        tracing::info!(map = name, "map saved");
        out.object("map", |o| {
            o.str("name", name).u64("bytes", bytes.len() as u64);
        });
        Ok(())
    }

    pub(super) fn set_map_path(&mut self, path: &str, out: &mut Fields<'_>) -> SimResult {
        let full = self.data.resolve(path)?;
        let meta = fs::metadata(&full).map_err(io_err("stat", path))?;
        if !meta.is_file() {
            return Err(SimError::NotFound(format!("map file {path}")));
        }
        self.map_path = Some(path.to_owned());
        out.str("map_path", path);
        Ok(())
    }

    pub(super) fn list_maps(&self, out: &mut Fields<'_>) -> SimResult {
        let maps = files::entries(&self.data.area(Area::Maps), Kind::Files)
            .map_err(|e| SimError::io("list maps", e))?;
        write_entries(out, "maps", &maps);
        Ok(())
    }

    pub(super) fn remove_map(&mut self, name: &str, out: &mut Fields<'_>) -> SimResult {
        let path = self.data.named(Area::Maps, name)?;
        let meta = fs::symlink_metadata(&path).map_err(io_err("stat", name))?;
        if meta.is_dir() {
            return Err(SimError::NotFound(format!("map {name}")));
        }
        fs::remove_file(&path).map_err(io_err("remove", name))?;
        let in_use = format!("{}/{name}", Area::Maps.dir_name());
        if self.map_path.as_deref() == Some(in_use.as_str()) {
            self.map_path = None;
        }
        tracing::info!(map = name, "map removed");
        out.str("removed", name);
        Ok(())
    }

    /// Today's capture directory (created if needed) and a fresh file stem.
    fn capture_target(&mut self) -> SimResult<(String, String)> {
        let dir_name = utc_date(SystemTime::now());
        let dir = self.data.named(Area::Images, &dir_name)?;
        fs::create_dir_all(&dir).map_err(|e| SimError::io("create image directory", e))?;
        self.captures += 1;
        Ok((dir_name, format!("{}_{}", unix_ms(), self.captures)))
    }

    pub(super) fn capture(&mut self, out: &mut Fields<'_>) -> SimResult {
        let (dir, stem) = self.capture_target()?;
        let n = self.captures;
        let names = [format!("{stem}_rgb.ppm"), format!("{stem}_ir.pgm")];
        for (name, colour) in names.iter().zip([true, false]) {
            let path = self.data.area(Area::Images).join(&dir).join(name);
            create_file(&path, &frame(colour, n)).map_err(|e| SimError::io(format!("write {name}"), e))?;
        }
        out.str("dir", &dir).array("files", |a| {
            names.iter().for_each(|f| {
                a.str(f);
            })
        });
        Ok(())
    }

    pub(super) fn snapshot(&mut self, out: &mut Fields<'_>) -> SimResult {
        let (dir, stem) = self.capture_target()?;
        let name = format!("{stem}_snapshot.ppm");
        let path = self.data.area(Area::Images).join(&dir).join(&name);
        create_file(&path, &frame(true, self.captures))
            .map_err(|e| SimError::io(format!("write {name}"), e))?;
        out.str("dir", &dir).str("file", &name);
        Ok(())
    }

    pub(super) fn savebag(&mut self, on: bool, out: &mut Fields<'_>) -> SimResult {
        if on && self.bag.is_none() {
            let name = format!("{}_{}.bag", utc_date(SystemTime::now()), unix_ms());
            let path = self.data.named(Area::Bags, &name)?;
            create_file(&path, b"# lluav simulated bag: sim_time_s x y z yaw fsm\n")
                .map_err(|e| SimError::io(format!("create bag {name}"), e))?;
            tracing::info!(bag = %name, "bag recording started");
            self.bag = Some(Bag {
                name,
                path,
                samples: Vec::new(),
            });
        } else if !on && let Some(mut bag) = self.bag.take() {
            append_samples(&mut bag).map_err(|e| SimError::io(format!("write bag {}", bag.name), e))?;
            tracing::info!(bag = %bag.name, "bag recording stopped");
            out.str("bag", &bag.name);
        }
        if let Some(bag) = &self.bag {
            out.str("bag", &bag.name);
        }
        out.bool("recording", self.bag.is_some());
        Ok(())
    }

    pub(super) fn download_video(&mut self, vid: Option<u32>, out: &mut Fields<'_>) -> SimResult {
        let vid = match vid {
            Some(v) => v,
            None => *self
                .dev
                .siyi
                .videos
                .last()
                .ok_or_else(|| SimError::NotFound("no video on the SIYI card".into()))?,
        };
        if !self.dev.siyi.videos.contains(&vid) {
            return Err(SimError::NotFound(format!("video {vid} on the SIYI card")));
        }
        let name = format!("siyi_{vid}.video");
        let path = self.data.named(Area::Videos, &name)?;
        let body = format!("simulated SIYI video {vid}\n");
        atomic_write(&path, body.as_bytes(), 0o644).map_err(|e| SimError::io(format!("write {name}"), e))?;
        out.u64("vid", vid.into())
            .str("file", &format!("{}/{name}", Area::Videos.dir_name()));
        Ok(())
    }

    /// Deletes the oldest entries of `area` until at least `min_gb` GiB are
    /// free, or all of them when no `min_gb` is given. A bag being recorded
    /// is kept.
    pub(super) fn clear(&mut self, area: Area, min_gb: Option<f32>, out: &mut Fields<'_>) -> SimResult {
        let dir = self.data.area(area);
        let kind = if area == Area::Images {
            Kind::Dirs
        } else {
            Kind::Files
        };
        let root = self.data.root().to_path_buf();
        let want = min_gb.map(|gb| (f64::from(gb) * f64::from(1u32 << 30)) as u64);
        let keep = self.bag.as_ref().map(|b| b.path.clone());
        let removed = files::clear_oldest(&dir, kind, keep.as_deref(), || match want {
            Some(bytes) => Ok(super::system::available_bytes(&root)? >= bytes),
            None => Ok(false),
        })
        .map_err(|e| SimError::io(format!("clear {}", area.dir_name()), e))?;
        tracing::info!(area = area.dir_name(), removed = removed.len(), "cleared");
        let free = super::system::available_bytes(&root).map_err(|e| SimError::io("statvfs()", e))?;
        out.array("removed", |a| {
            removed.iter().for_each(|n| {
                a.str(n);
            })
        })
        .u64("available_MB", free >> 20);
        Ok(())
    }

    /// Lists image directories, newest first, at most `size` of them.
    pub(super) fn list_imagedirs(&self, size: Option<u32>, out: &mut Fields<'_>) -> SimResult {
        let mut dirs = files::entries(&self.data.area(Area::Images), Kind::Dirs)
            .map_err(|e| SimError::io("list image directories", e))?;
        dirs.reverse();
        if let Some(n) = size {
            dirs.truncate(usize::try_from(n).unwrap_or(usize::MAX));
        }
        write_entries(out, "imagedirs", &dirs);
        Ok(())
    }

    pub(super) fn remove_imagedir(&mut self, name: &str, out: &mut Fields<'_>) -> SimResult {
        let path = self.data.named(Area::Images, name)?;
        let meta = fs::symlink_metadata(&path).map_err(io_err("stat", name))?;
        if !meta.is_dir() {
            return Err(SimError::NotFound(format!("image directory {name}")));
        }
        fs::remove_dir_all(&path).map_err(io_err("remove", name))?;
        tracing::info!(dir = name, "image directory removed");
        out.str("removed", name);
        Ok(())
    }

    /// Checks every waypoint of a mission file against the geofence.
    pub(super) fn test_waypoint_file(&self, path: &str, out: &mut Fields<'_>) -> SimResult {
        let text = self.data.read_client_file(path, super::MAX_MISSION_FILE)?;
        let anywhere = Fence {
            home: Ned::default(),
            radius: f64::INFINITY,
            max_alt: f64::INFINITY,
        };
        let waypoints = mission::parse(&text, &anywhere)?;
        let fence = self.fence();
        let verdicts: Vec<_> = waypoints
            .iter()
            .map(|w| (w.wp_id(), fence.check(w.ned())))
            .collect();
        out.bool("reachable", verdicts.iter().all(|(_, v)| v.is_ok()))
            .array("waypoints", |a| {
                for (id, verdict) in &verdicts {
                    a.object(|o| {
                        o.u64("id", (*id).into()).bool("reachable", verdict.is_ok());
                        if let Err(why) = verdict {
                            o.str("reason", why);
                        }
                    });
                }
            });
        Ok(())
    }

    /// Writes every recent log line to a new file under `logs/`; returns
    /// its path relative to the data directory and the line count.
    pub(super) fn save_messages(&self) -> SimResult<(String, usize)> {
        let lines = self.log.recent(usize::MAX);
        let name = format!("msgs_{}.log", unix_ms());
        let path = self.data.named(Area::Logs, &name)?;
        let mut text = lines.join("\n");
        text.push('\n');
        atomic_write(&path, text.as_bytes(), 0o644).map_err(|e| SimError::io(format!("write {name}"), e))?;
        Ok((format!("{}/{name}", Area::Logs.dir_name()), lines.len()))
    }
}
