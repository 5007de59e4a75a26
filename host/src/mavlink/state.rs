//! What lluavd knows of the autopilot it follows, behind one lock: the
//! telemetry cache, the setpoint it streams and the sessions that set it,
//! the missions, and the camera's counters. Only methods change it, so
//! every rule about it (when the stream stops, what an upload records)
//! is written here once.

use std::collections::HashSet;

use ::mavlink::MavHeader;
use ::mavlink::dialects::ardupilotmega::MavMessage;
use lluav_core::{Fields, Pose, SessionId};

use super::answer::{Answer as _, Following, write_pose};
use super::mission::Missions;
use super::telemetry::Telemetry;

/// The setpoint being streamed and the sessions that set it.
#[derive(Clone, Debug, PartialEq)]
struct Stream {
    pose: Pose,
    /// Every session that set a setpoint since streaming started.
    owners: HashSet<SessionId>,
}

/// What lluavd knows of the autopilot.
#[derive(Debug, Default)]
pub struct Known {
    tel: Telemetry,
    stream: Option<Stream>,
    missions: Missions,
    recording: bool,
    images: u32,
}

impl Known {
    /// The telemetry cache.
    pub fn tel(&self) -> &Telemetry {
        &self.tel
    }

    /// The missions.
    pub fn missions(&self) -> &Missions {
        &self.missions
    }

    /// The missions, to record an upload or a run.
    pub fn missions_mut(&mut self) -> &mut Missions {
        &mut self.missions
    }

    /// Takes in one message received at `now_ms`; true when it is a
    /// heartbeat that brings the link up.
    pub fn observe(&mut self, header: &MavHeader, msg: &MavMessage, now_ms: i64) -> bool {
        let came_up = self.tel.observe(header, msg, now_ms);
        if self
            .tel
            .target()
            .is_some_and(|t| u32::from(t.system) == header.system_id)
        {
            self.missions.observe(msg);
        }
        came_up
    }

    /// The setpoint streamed now, if any.
    pub fn setpoint(&self) -> Option<Pose> {
        self.stream.as_ref().map(|s| s.pose)
    }

    /// Streams `pose` from now on; `session` is one of the sessions that
    /// keep the stream going.
    pub fn stream(&mut self, pose: Pose, session: SessionId) {
        let stream = self.stream.get_or_insert_with(|| Stream {
            pose,
            owners: HashSet::new(),
        });
        stream.pose = pose;
        stream.owners.insert(session);
    }

    /// Stops streaming: another command takes the vehicle over.
    pub fn stop_stream(&mut self) {
        self.stream = None;
    }

    /// `session` ended: the stream stops when no session that set it is
    /// left, so the autopilot's own offboard-loss failsafe takes over.
    pub fn release(&mut self, session: SessionId) {
        if let Some(stream) = self.stream.as_mut() {
            stream.owners.remove(&session);
            if stream.owners.is_empty() {
                self.stream = None;
                tracing::warn!("setpoint stream stopped: no client that set it is connected");
            }
        }
    }

    /// Whether the camera records.
    pub fn recording(&self) -> bool {
        self.recording
    }

    /// The camera started or stopped recording.
    pub fn set_recording(&mut self, on: bool) {
        self.recording = on;
    }

    /// Images captured so far.
    pub fn images(&self) -> u32 {
        self.images
    }

    /// One more image was captured; its sequence number.
    pub fn count_image(&mut self) -> u32 {
        self.images = self.images.wrapping_add(1);
        self.images
    }

    /// Writes `sp` (the streamed setpoint or null), `active` and `fsm`:
    /// `set_sp_ned`'s and `show_sp`'s answer.
    pub fn write_setpoint(&self, out: &mut Fields<'_>) {
        self.following().write(out);
    }

    /// The setpoint streamed and the state, as `set_sp_ned` answers them.
    pub fn following(&self) -> Following {
        Following {
            setpoint: self.setpoint(),
            fsm: self.tel.fsm(),
        }
    }

    /// Writes the vehicle's members of `state` (see [`super`]).
    pub fn write_state(&self, now_ms: i64, lock_mode: bool, state: &mut Fields<'_>) {
        self.tel.write_state(now_ms, state);
        state.bool("lock_mode", lock_mode);
        write_pose(state, "setpoint", self.setpoint());
        self.missions.write_state(state);
    }
}
