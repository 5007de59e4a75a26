//! The vehicle seam: what every vehicle (the simulator, an autopilot over
//! MAVLink) is to the rest of lluavd, and what the vehicles share.
//!
//! - [`Vehicle`]: the flying half of the daemon's backend. It answers the
//!   commands [`crate::onboard`] routes to the vehicle, or hands back a
//!   [`Wait`] that ends with the [`Reply`] when it waits for something
//!   outside; it is advanced in time, flushed and stopped at exit.
//! - [`Ned`] and [`Snapshot`]: positions, and what the companion computer
//!   needs to know of the vehicle.
//! - `Refusal` (crate-internal): an error that knows its `ret`.
//! - [`mission`]: DESIGN.md's mission JSON, read the same way by every
//!   vehicle.
//!
//! This module sits at the bottom of the vehicle side: it depends on
//! lluav-core and the data directory ([`crate::files`]) only.

pub mod envelope;
pub mod mission;

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::time::Duration;

use lluav_core::{Command, Context, Failsafe, Failure, Fields, Ret, SessionId};

use crate::files::{self, Files};

/// How often a vehicle that is doing something is advanced.
pub const TICK: Duration = Duration::from_millis(50);

/// A point or vector in NED metres (x north, y east, z down).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ned {
    /// North.
    pub x: f64,
    /// East.
    pub y: f64,
    /// Down.
    pub z: f64,
}

impl Ned {
    /// A point.
    pub fn new(x: f64, y: f64, z: f64) -> Ned {
        Ned { x, y, z }
    }

    /// Writes `x`, `y`, `z` members as `f32`: coordinates are `f32` on the
    /// wire (DESIGN.md, "Numbers in responses").
    pub fn write(self, o: &mut Fields<'_>) {
        o.f32("x", self.x as f32)
            .f32("y", self.y as f32)
            .f32("z", self.z as f32);
    }
}

/// What the companion computer needs to know of the vehicle: for bags,
/// maps and version reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Snapshot {
    /// The backend's name in `ver` (`simulator`, `mavlink`).
    pub backend: &'static str,
    /// The vehicle's own clock, seconds (simulated time, autopilot boot
    /// time, ...), for bag samples.
    pub time_s: f64,
    /// Position, NED metres.
    pub position: Ned,
    /// Heading, radians.
    pub yaw: f64,
    /// The state machine's state, as in `state.fsm`.
    pub fsm: &'static str,
    /// Distance flown since start, metres (map keyframes are spaced by it).
    pub distance_m: f64,
}

/// A finished command's answer: writes its response fields, or answers
/// its failure (as [`lluav_core::Backend::execute`] would).
pub type Reply = Box<dyn FnOnce(&mut Fields<'_>) -> Result<(), Failure> + Send>;

/// A command waiting for something outside the vehicle (an autopilot's
/// acknowledgement): awaited with the vehicle unlocked, so other sessions
/// are served meanwhile, it ends with the command's [`Reply`].
pub type Wait = Pin<Box<dyn Future<Output = Reply> + Send>>;

/// How far a vehicle got with a command.
pub enum Progress {
    /// Finished: the response fields are written.
    Done,
    /// Waiting; nothing is written yet.
    Waiting(Wait),
}

impl std::fmt::Debug for Progress {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Progress::Done => "Done",
            Progress::Waiting(_) => "Waiting",
        })
    }
}

/// A vehicle: the flying half of the daemon's backend.
///
/// It answers the commands [`crate::onboard`] gives the vehicle, with the
/// contract of [`lluav_core::Backend::execute`]; `files` is the companion
/// computer's data directory, for mission files and camera output.
pub trait Vehicle: Send + 'static {
    /// Whether the motors are armed right now (the armed gate).
    fn armed(&self) -> bool;

    /// Carries out a command the vehicle owns, or starts it and answers
    /// [`Progress::Waiting`] with what finishes it.
    fn execute(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> Result<Progress, Failure>;

    /// A session's connection ended.
    fn session_closed(&mut self, session: SessionId) {
        let _ = session;
    }

    /// The failsafe that holds now, if any (as
    /// [`lluav_core::Backend::failsafe`]).
    fn failsafe(&self) -> Option<Failsafe> {
        None
    }

    /// The session in control overrides the current failsafe (as
    /// [`lluav_core::Backend::override_failsafe`]).
    fn override_failsafe(&mut self) -> Result<(), Failure> {
        Ok(())
    }

    /// Whether a mission is running (`abort_report` would stop it).
    fn mission_running(&self) -> bool {
        false
    }

    /// How long control lasts without a request from its session, ms.
    fn control_timeout_ms(&self) -> u32 {
        lluav_core::DEFAULT_CONTROL_TIMEOUT_MS
    }

    /// Writes the vehicle's members of the `state` object: at least
    /// `armed`, `fsm` and `lock_mode` (see [`crate::onboard`]).
    fn write_state(&self, ctx: &Context, state: &mut Fields<'_>);

    /// What the companion computer needs to know of the vehicle now.
    fn snapshot(&self) -> Snapshot;

    /// Advances the vehicle by `dt` of wall time.
    fn tick(&mut self, dt: Duration);

    /// How soon the vehicle must be advanced again for what it does to go
    /// on (a climb, a charge, an auto-sleep countdown); `None` while
    /// nothing changes without a command. An idle vehicle costs nothing:
    /// the daemon then advances it only when a request comes.
    fn next_tick(&self) -> Option<Duration> {
        Some(TICK)
    }

    /// What happened since the last call, as events (DESIGN.md,
    /// "Events"), in the order it happened.
    fn drain_events(&mut self, out: &mut Vec<crate::events::Event>) {
        let _ = out;
    }

    /// Persists anything pending.
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }

    /// Whether the link to the autopilot is up at `now_ms`; `None` for a
    /// vehicle without one (the simulator). For systemd's `STATUS=`.
    fn link_up(&self, now_ms: i64) -> Option<bool> {
        let _ = now_ms;
        None
    }

    /// Stops whatever the vehicle runs in the background (a link's tasks);
    /// the daemon calls it once, when it stops serving.
    fn stop(&mut self) {}
}

/// A refusal or failure that knows its `ret` (DESIGN.md, "Errors"); its
/// `Display` is the whole message.
pub(crate) trait Refusal: std::fmt::Display {
    /// The `ret` it is answered with.
    fn ret(&self) -> Ret;

    /// Answers it: the message is written whole into the response.
    fn fail(&self, out: &mut Fields<'_>) -> Failure {
        if self.ret() == Ret::Unhandled {
            tracing::error!(error = %self, "command reached a backend that does not own it");
        }
        out.fail(self.ret(), format_args!("{self}"))
    }
}

impl Refusal for files::Error {
    fn ret(&self) -> Ret {
        files::Error::ret(self)
    }
}
