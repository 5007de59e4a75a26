//! The simulated cameras and the SIYI gimbal: `capture` and `snapshot`
//! write real image files (through the companion's [`Files`]), `record`
//! toggles video onto the SIYI card, `siyi_downvideo` copies a video into
//! the data directory.

use lluav_core::{Args, Command, CommandId as C, Fields};

use super::error::{SimError, SimResult};
use crate::files::Files;

/// Most videos the simulated SIYI card holds: recording on a full card
/// replaces the oldest, as a camera in loop recording does (and the
/// `siyi` answer, which lists them, stays small).
const MAX_VIDEOS: usize = 256;

/// Side of the simulated camera frames, pixels.
const FRAME_SIDE: usize = 8;

/// The cameras and the SIYI camera/gimbal.
#[derive(Clone, Debug)]
pub(crate) struct Camera {
    /// Frames captured since start (each gets a distinct image).
    captures: u64,
    recording: bool,
    /// Ids of the videos on the SIYI card, oldest first.
    videos: Vec<u32>,
    next_vid: u32,
    centered: bool,
    /// HDMI output (`siyi_init` closes it).
    hdmi: bool,
    reboots: u32,
    syncs: u32,
}

impl Default for Camera {
    fn default() -> Self {
        Camera {
            captures: 0,
            recording: false,
            videos: Vec::new(),
            next_vid: 0,
            centered: false,
            hdmi: true,
            reboots: 0,
            syncs: 0,
        }
    }
}

impl Camera {
    /// The Camera & Recording commands a vehicle owns.
    pub(crate) fn run(
        &mut self,
        cmd: &Command<'_>,
        now_ms: i64,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> SimResult {
        match (cmd.id(), cmd.args()) {
            (C::Capture, _) => return self.capture(now_ms, files, out),
            (C::Snapshot, _) => {
                let name = self.next_name(now_ms, "snapshot.ppm");
                let dir = files.store_image(now_ms, &name, &frame(true, self.captures))?;
                out.str("dir", &dir).str("file", &name);
                return Ok(());
            }
            (C::Record, _) => {
                self.toggle_record(out);
                return Ok(());
            }
            (C::SiyiDownvideo, &Args::OptCount(vid)) => return self.download(vid, files, out),
            (C::SiyiReboot, _) => (self.reboots, self.recording) = (self.reboots + 1, false),
            (C::SiyiFormat, _) => {
                out.u64("erased", self.videos.len() as u64);
                self.videos.clear();
                self.recording = false;
            }
            (C::SiyiCenter, _) => self.centered = true,
            (C::SiyiInit, _) => self.hdmi = false,
            (C::SiyiSync, _) => self.syncs += 1,
            (id, _) => return Err(SimError::NotOwned(id.name())),
        }
        self.write(out);
        Ok(())
    }

    fn next_name(&mut self, now_ms: i64, suffix: &str) -> String {
        self.captures += 1;
        format!("{now_ms}_{}_{suffix}", self.captures)
    }

    /// An RGB and an infrared frame, into today's capture directory.
    fn capture(&mut self, now_ms: i64, files: &Files, out: &mut Fields<'_>) -> SimResult {
        let names = [
            self.next_name(now_ms, "rgb.ppm"),
            format!("{now_ms}_{}_ir.pgm", self.captures),
        ];
        let mut dir = String::new();
        for (name, colour) in names.iter().zip([true, false]) {
            dir = files.store_image(now_ms, name, &frame(colour, self.captures))?;
        }
        out.str("dir", &dir).array("files", |a| {
            names.iter().for_each(|f| {
                a.str(f);
            })
        });
        Ok(())
    }

    /// Toggles recording; stopping stores a new video on the card.
    fn toggle_record(&mut self, out: &mut Fields<'_>) {
        self.recording = !self.recording;
        out.bool("recording", self.recording);
        if !self.recording {
            self.next_vid += 1;
            if self.videos.len() >= MAX_VIDEOS {
                self.videos.remove(0);
            }
            self.videos.push(self.next_vid);
            out.u64("vid", self.next_vid.into());
        }
    }

    fn download(&mut self, vid: Option<u32>, files: &Files, out: &mut Fields<'_>) -> SimResult {
        let vid = match vid {
            Some(v) if self.videos.contains(&v) => v,
            Some(v) => return Err(SimError::NotFound(format!("no video {v} on the SIYI card"))),
            None => *self.videos.last().ok_or(SimError::NoVideo)?,
        };
        let body = format!("simulated SIYI video {vid}\n");
        let file = files.store_video(&format!("siyi_{vid}.video"), body.as_bytes())?;
        out.u64("vid", vid.into()).str("file", &file);
        Ok(())
    }

    /// Writes `siyi`.
    fn write(&self, out: &mut Fields<'_>) {
        out.object("siyi", |o| {
            o.bool("recording", self.recording)
                .array("videos", |a| {
                    self.videos.iter().for_each(|&v| {
                        a.u64(v.into());
                    })
                })
                .bool("centered", self.centered)
                .bool("hdmi", self.hdmi)
                .u64("reboots", self.reboots.into())
                .u64("syncs", self.syncs.into());
        });
    }
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
