//! What lluavd knows of the autopilot it follows, behind one lock: which
//! autopilot that is (`follow`), the telemetry cache, the setpoint it
//! streams and the sessions that set it, the missions, a takeoff it was
//! told of before the telemetry shows it, the failsafes (`authority`) and
//! the camera's counters.
//! Only methods change it, so every rule about it (what a packet may
//! change, when the stream stops, what a new vehicle forgets) is written
//! here once.

use std::collections::HashSet;
use std::net::SocketAddr;

use ::mavlink::MavHeader;
use ::mavlink::dialects::ardupilotmega::MavMessage;
use lluav_core::{Failsafe, Fields, Pose, SessionId};

use super::answer::{Answer as _, Following, write_pose};
use super::authority::{Asked, Look, Watch};
use super::error::MavError;
use super::follow::{Admit, Follow, Wanted};
use super::mission::{self, Missions};
use super::news::{News, Seen};
use super::protocol::Target;
use super::telemetry::{Status, Telemetry};

/// How long after `takeoff` answered 0 the vehicle counts as taking off
/// without the telemetry showing it: a climb shows within seconds. A
/// disarm shown or commanded, or a landing commanded, ends it sooner.
pub const TAKEOFF_GRACE_MS: i64 = 10_000;

/// The setpoint being streamed and the sessions that set it.
#[derive(Clone, Debug, PartialEq)]
struct Stream {
    pose: Pose,
    /// Every session that set a setpoint since streaming started.
    owners: HashSet<SessionId>,
}

/// What a received packet did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Receipt {
    /// Not the followed autopilot's: dropped, nothing changed.
    Dropped,
    /// The autopilot's: taken in.
    Kept,
    /// The autopilot's heartbeat, and the link is up again.
    LinkUp,
}

/// What lluavd knows of the autopilot.
#[derive(Debug, Default)]
pub struct Known {
    follow: Follow,
    tel: Telemetry,
    stream: Option<Stream>,
    missions: Missions,
    recording: bool,
    images: u32,
    /// When `takeoff` answered 0, until the telemetry shows the climb,
    /// the autopilot's heartbeat shows it disarmed, or a `land` or
    /// `disarm` answers 0.
    took_off_ms: Option<i64>,
    /// Packets dropped as foreign since the last [`Known::take_foreign`].
    foreign: u64,
    /// The failsafes.
    watch: Watch,
    /// What is told as events.
    news: News,
}

impl Known {
    /// Knowing nothing yet, following `wanted`.
    pub fn new(wanted: Wanted) -> Self {
        Known {
            follow: Follow::new(wanted),
            ..Known::default()
        }
    }

    /// Takes in a packet from `from` received at `now_ms`: only the
    /// followed autopilot's change anything.
    pub fn receive(
        &mut self,
        from: Option<SocketAddr>,
        header: &MavHeader,
        msg: &MavMessage,
        now_ms: i64,
    ) -> Receipt {
        let receipt = match self.follow.admit(from, header, msg, now_ms) {
            Admit::Foreign => {
                self.foreign = self.foreign.saturating_add(1);
                return Receipt::Dropped;
            }
            Admit::Accept => Receipt::Kept,
            Admit::Acquired { new_vehicle } => {
                if new_vehicle {
                    self.new_vehicle();
                }
                Receipt::LinkUp
            }
            Admit::Rebooted => {
                self.new_vehicle();
                Receipt::Kept
            }
        };
        self.tel.observe(msg);
        self.missions.observe(msg);
        match msg {
            MavMessage::HEARTBEAT(_) => self.observe_mode(now_ms),
            MavMessage::STATUSTEXT(s) => super::news::statustext(s),
            _ => {}
        }
        // Climbing, or disarmed after `takeoff` answered (the autopilot
        // gave up, or was landed or disarmed by other means): the
        // telemetry tells again, so nothing streams to a vehicle on the
        // ground. A heartbeat the radio held back from before the arming
        // ends it too; the cost is a `-1` until the climb shows, never a
        // setpoint to a disarmed vehicle.
        let disarmed = matches!(msg, MavMessage::HEARTBEAT(_)) && !self.tel.armed();
        if self.tel.airborne() || disarmed {
            self.took_off_ms = None;
        }
        self.judge(now_ms);
        self.notice(now_ms);
        receipt
    }

    /// The heartbeat's mode, for the run's progress: flying the mission,
    /// holding at its end, or doing something else.
    fn observe_mode(&mut self, now_ms: i64) {
        let (Some(flavour), Some(mode)) = (self.tel.flavour(), self.tel.custom_mode()) else {
            return;
        };
        let armed = self.tel.armed();
        self.missions.observe_mode(
            armed && mission::mission_mode(flavour, mode),
            mission::end_of_mission_hold(flavour, mode),
            armed,
            now_ms,
        );
    }

    /// Queues an event for each change since the last look.
    fn notice(&mut self, now_ms: i64) {
        let seen = Seen {
            link_up: self.link_up(now_ms),
            fsm: self.fsm(now_ms),
            armed: self.tel.armed(),
            failsafe: self.failsafe(),
            battery: self.tel.battery_percent().map(f64::from),
        };
        let mut progress = Vec::new();
        self.missions.drain_news(&mut progress);
        self.news.notice(&seen, progress);
    }

    /// Looks again at what time alone changes at `now_ms` (the link lost,
    /// a takeoff's grace over, a run held past its grace) and queues its
    /// events.
    pub fn look(&mut self, now_ms: i64) {
        self.missions.expire(now_ms);
        self.notice(now_ms);
    }

    /// Hands every queued event to `out`, oldest first.
    pub fn drain_events(&mut self, out: &mut Vec<crate::events::Event>) {
        self.news.drain(out);
    }

    /// The autopilot accepted the run's `MISSION_START` at `now_ms`: it is
    /// told started (and whatever progress came before the answer).
    pub fn mission_started(&mut self, now_ms: i64) {
        self.missions.started();
        self.notice(now_ms);
    }

    /// Looks at the autopilot for failsafes. One that takes the vehicle
    /// off lluavd's setpoint stops the stream: nothing streams to a
    /// vehicle that no longer follows it, and a pilot or ground station
    /// switching back to offboard/GUIDED finds no old setpoint to fly to.
    fn judge(&mut self, now_ms: i64) {
        let (Some(flavour), Some(custom_mode), Some(status)) = (
            self.tel.flavour(),
            self.tel.custom_mode(),
            self.tel.system_status(),
        ) else {
            return;
        };
        let look = Look {
            flavour,
            custom_mode,
            status,
            armed: self.tel.armed(),
            airborne: self.airborne(now_ms),
            now_ms,
        };
        if let Some(started) = self.watch.observe(&look)
            && started.left_setpoints
            && self.stream.take().is_some()
        {
            tracing::warn!(
                failsafe = %started.failsafe.reason(),
                "setpoint stream stopped: the vehicle left it"
            );
        }
    }

    /// Another vehicle (or the same one rebooted): nothing lluavd knew of
    /// the old one holds. No setpoint is streamed until a client sends
    /// one, and no mission is on it.
    fn new_vehicle(&mut self) {
        if self.stream.is_some() || self.missions.on_autopilot().is_some() {
            tracing::warn!("a new autopilot: setpoint stream stopped, its missions forgotten");
        }
        self.tel.new_vehicle();
        self.stream = None;
        self.missions.new_vehicle();
        self.recording = false;
        self.took_off_ms = None;
        // What it is doing is seen afresh: a return or landing already
        // active counts as its own.
        self.watch = Watch::default();
    }

    /// How many entries what lluavd knows holds: message kinds counted,
    /// boot times kept, missions kept. Bounded whatever the autopilot
    /// sends.
    #[cfg(feature = "fuzzing")]
    pub fn footprint(&self) -> usize {
        self.tel.kinds() + self.follow.boot_times() + self.missions.kept()
    }

    /// Packets dropped as foreign since the last call.
    pub fn take_foreign(&mut self) -> u64 {
        std::mem::take(&mut self.foreign)
    }

    /// The autopilot followed, once a heartbeat chose it.
    pub fn target(&self) -> Option<Target> {
        self.follow.target()
    }

    /// Where the autopilot's packets come from: where lluavd sends.
    pub fn peer(&self) -> Option<SocketAddr> {
        self.follow.peer()
    }

    /// Whether the autopilot's heartbeat arrived within the link timeout.
    pub fn link_up(&self, now_ms: i64) -> bool {
        self.follow.link_up(now_ms)
    }

    /// Milliseconds since the autopilot's last heartbeat.
    pub fn heartbeat_age_ms(&self, now_ms: i64) -> Option<i64> {
        self.follow.heartbeat_age_ms(now_ms)
    }

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

    /// `takeoff` answered 0 at `now_ms`: the vehicle counts as flying
    /// from now on, before the telemetry shows the climb.
    pub fn took_off(&mut self, now_ms: i64) {
        self.took_off_ms = Some(now_ms);
    }

    /// The vehicle was disarmed on lluavd's command.
    pub fn disarmed(&mut self) {
        self.took_off_ms = None;
        self.stream = None;
    }

    /// `land` answered 0: the vehicle no longer counts as flying on
    /// lluavd's word; the telemetry tells whether it still flies.
    pub fn landing(&mut self) {
        self.took_off_ms = None;
    }

    fn taking_off(&self, now_ms: i64) -> bool {
        self.took_off_ms
            .is_some_and(|t| now_ms.saturating_sub(t) < TAKEOFF_GRACE_MS)
    }

    /// `state.fsm`: the telemetry's, or `takeoff` right after `takeoff`
    /// answered 0.
    pub fn fsm(&self, now_ms: i64) -> &'static str {
        if self.taking_off(now_ms) {
            "takeoff"
        } else {
            self.tel.fsm()
        }
    }

    /// Whether the vehicle flies, for the commands that move a flying
    /// vehicle.
    pub fn airborne(&self, now_ms: i64) -> bool {
        self.taking_off(now_ms) || self.tel.airborne()
    }

    /// The failsafe, if one started and the vehicle has not been disarmed
    /// since (DESIGN.md, "Flight authority").
    pub fn failsafe(&self) -> Option<Failsafe> {
        self.watch.failsafe()
    }

    /// The session in control overrides the failsafe.
    pub fn override_failsafe(&mut self) -> Option<Failsafe> {
        self.watch.override_failsafe()
    }

    /// lluavd is about to ask the autopilot for `asked` at `now_ms`: the
    /// modes that follow are its own.
    pub fn ask(&mut self, asked: Asked, now_ms: i64) {
        self.watch.ask(asked, now_ms);
    }

    /// The command that asked for `asked` failed.
    pub fn unask(&mut self, asked: Asked) {
        self.watch.unask(asked);
    }

    /// Refuses a command that would change the flight (a mode change, a
    /// takeoff, a mission start) while a failsafe holds: the failsafe
    /// gate checked when the request came, this checks again when it is
    /// sent, for one that started meanwhile.
    pub fn check_steering(&self) -> Result<(), MavError> {
        match self.watch.holds() {
            Some(f) => Err(MavError::State(format!(
                "{}{}{}",
                lluav_core::error::messages::FAILSAFE_OPEN,
                f.reason(),
                lluav_core::error::messages::FAILSAFE_MOTION
            ))),
            None => Ok(()),
        }
    }

    /// Whether a mission lluavd started is being flown.
    pub fn mission_running(&self, now_ms: i64) -> bool {
        self.missions.running().is_some() && self.fsm(now_ms) == "mission"
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

    /// The setpoint streamed and the state, as `set_sp_ned` answers them.
    pub fn following(&self, now_ms: i64) -> Following {
        Following {
            setpoint: self.setpoint(),
            fsm: self.fsm(now_ms),
        }
    }

    /// Writes `sp` (the streamed setpoint or null), `active` and `fsm`:
    /// `set_sp_ned`'s and `show_sp`'s answer.
    pub fn write_setpoint(&self, now_ms: i64, out: &mut Fields<'_>) {
        self.following(now_ms).write(out);
    }

    /// Writes the vehicle's members of `state` (see [`super`]).
    pub fn write_state(&self, now_ms: i64, lock_mode: bool, state: &mut Fields<'_>) {
        let status = Status {
            fsm: self.fsm(now_ms),
            airborne: self.airborne(now_ms),
            link_up: self.link_up(now_ms),
            heartbeat_age_ms: self.heartbeat_age_ms(now_ms),
        };
        self.tel.write_state(status, state);
        state.bool("lock_mode", lock_mode);
        write_pose(state, "setpoint", self.setpoint());
        self.missions.write_state(state);
    }
}

#[cfg(test)]
mod tests;
