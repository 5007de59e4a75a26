//! Bags: recordings of the vehicle's pose under `bags/`, sampled at every
//! tick and appended to the file when recording stops or the daemon
//! flushes. `clear_bags` never deletes the bag being recorded.

use std::fs::OpenOptions;
use std::io::{self, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::PathBuf;

use lluav_core::{Args, Command, Fields};
use nix::fcntl::OFlag;

use super::error::{Error, Result};
use super::images;
use crate::files::{Area, Files, capture_dir, create_file};
use crate::vehicle::Snapshot;

/// Most pose samples a bag buffers before they are written out.
const BAG_BUFFER: usize = 10_000;

/// A bag being recorded.
#[derive(Debug)]
struct Bag {
    name: String,
    path: PathBuf,
    samples: Vec<String>,
}

/// The bag being recorded, if any.
#[derive(Debug, Default)]
pub(super) struct Bags {
    recording: Option<Bag>,
}

impl Bags {
    /// `savebag 0|1` and `clear_bags [min_gb]`.
    pub(super) fn run(
        &mut self,
        cmd: &Command<'_>,
        files: &Files,
        now_ms: i64,
        out: &mut Fields<'_>,
    ) -> Result {
        match *cmd.args() {
            Args::Flag(true) => self.start(files, now_ms, out),
            Args::Flag(false) => self.stop(out),
            Args::OptAmount(min_gb) => {
                let keep = self.recording.as_ref().map(|b| b.path.clone());
                images::clear(files, Area::Bags, min_gb.map(|n| n.value()), keep.as_deref(), out)
            }
            _ => Err(Error::NotOwned(cmd.id().name())),
        }
    }

    fn start(&mut self, files: &Files, now_ms: i64, out: &mut Fields<'_>) -> Result {
        if self.recording.is_none() {
            let name = format!("{}_{now_ms}.bag", capture_dir(now_ms));
            let path = files.named(Area::Bags, &name)?;
            create_file(&path, b"# lluav bag: vehicle_time_s x y z yaw fsm\n")
                .map_err(|e| Error::io(format!("create bag {name}"), e))?;
            tracing::info!(bag = %name, "bag recording started");
            self.recording = Some(Bag {
                name,
                path,
                samples: Vec::new(),
            });
        }
        if let Some(bag) = &self.recording {
            out.str("bag", &bag.name);
        }
        out.bool("recording", true);
        Ok(())
    }

    fn stop(&mut self, out: &mut Fields<'_>) -> Result {
        if let Some(mut bag) = self.recording.take() {
            append(&mut bag).map_err(|e| Error::io(format!("write bag {}", bag.name), e))?;
            tracing::info!(bag = %bag.name, "bag recording stopped");
            out.str("bag", &bag.name);
        }
        out.bool("recording", false);
        Ok(())
    }

    pub(super) fn recording(&self) -> bool {
        self.recording.is_some()
    }

    /// Buffers one pose sample of the recording bag.
    pub(super) fn sample(&mut self, vehicle: &Snapshot) {
        if let Some(bag) = self.recording.as_mut()
            && bag.samples.len() < BAG_BUFFER
        {
            let p = vehicle.position;
            bag.samples.push(format!(
                "{:.3} {:.3} {:.3} {:.3} {:.3} {}",
                vehicle.time_s, p.x, p.y, p.z, vehicle.yaw, vehicle.fsm
            ));
        }
    }

    /// Appends the recording bag's buffered samples to its file.
    pub(super) fn flush(&mut self) -> io::Result<()> {
        match self.recording.as_mut() {
            Some(bag) => append(bag),
            None => Ok(()),
        }
    }

    /// Writes `rosrecord`.
    pub(super) fn write_statics(&self, out: &mut Fields<'_>) {
        out.object("rosrecord", |o| {
            o.bool("recording", self.recording.is_some());
            match &self.recording {
                Some(b) => o.str("bag", &b.name).u64("buffered", b.samples.len() as u64),
                None => o.null("bag"),
            };
        });
    }
}

/// Appends a bag's buffered samples to its file (never through a link).
fn append(bag: &mut Bag) -> io::Result<()> {
    if bag.samples.is_empty() {
        return Ok(());
    }
    let mut f = OpenOptions::new()
        .append(true)
        .custom_flags(OFlag::O_NOFOLLOW.bits())
        .open(&bag.path)?;
    let mut text = bag.samples.join("\n");
    text.push('\n');
    f.write_all(text.as_bytes())?;
    f.sync_data()?;
    bag.samples.clear();
    Ok(())
}
