//! Missions on the MAVLink vehicle: the submitted missions (DESIGN.md's
//! mission JSON, NED), the mission items they become (global, from the
//! vehicle's home), what is on the autopilot now, and the progress of
//! the run `mw_exec` started, from `MISSION_CURRENT`,
//! `MISSION_ITEM_REACHED` and the heartbeat's mode, told as `mission`
//! events (DESIGN.md, "Events"; `started` is told by `mw_exec` once
//! `MISSION_START` is answered).
//!
//! What autopilots say differs, and the run's progress is read so that
//! each of them tells the same story once:
//! - PX4 repeats its last `MISSION_ITEM_REACHED` (ten more times at its
//!   slow rate), and ArduPilot may send one for any item it completes:
//!   an item is told reached once, only ahead of the last one told.
//! - PX4's repeats outlive a run: a run started soon after another hears
//!   the old run's last item. That item counts in the new run only once
//!   `MISSION_CURRENT` showed the vehicle got that far in it.
//! - A run ends `completed` when its last item is reached, `aborted` when
//!   the vehicle stops flying it before: another mode, disarmed, another
//!   run, another vehicle. PX4 enters its hold at a mission's end; a hold
//!   before the last item was heard counts as the end of the run only
//!   after [`HOLD_GRACE_MS`], time for the last item's `reached` (or one
//!   of its repeats) to come over a lossy radio link.

use std::collections::VecDeque;

use ::mavlink::dialects::ardupilotmega::{MISSION_ITEM_INT_DATA, MavCmd, MavFrame, MavMessage};
use lluav_core::Fields;

use super::autopilot::{Flavour, Phase};
use super::error::MavError;
use super::geo::Global;
use super::protocol::mission_item;
use crate::events::{Event, MissionStatus};
use crate::vehicle::Ned;
pub use crate::vehicle::mission::RunStatus as Status;

/// Most missions kept; the oldest go first, never the one running.
const MAX_KEPT: usize = 64;
/// How long the autopilot may hold before a run's last item was heard
/// reached, ms, before the run counts as aborted: PX4 enters its hold
/// as it reaches the last item, and repeats the `MISSION_ITEM_REACHED`
/// a lost packet took away within a second or two.
pub const HOLD_GRACE_MS: i64 = 3000;

/// A waypoint of a submitted mission.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Waypoint {
    /// Its id.
    pub id: u32,
    /// Position, local NED metres.
    pub ned: Ned,
    /// Heading on arrival, radians.
    pub yaw: Option<f64>,
}

/// A submitted mission.
#[derive(Clone, Debug, PartialEq)]
pub struct Mission {
    /// External id.
    pub ext_id: u32,
    /// Its waypoints, in order.
    pub waypoints: Vec<Waypoint>,
}

/// What the autopilot holds: these waypoints, from item `first_seq` on
/// (ArduPilot keeps home in item 0).
#[derive(Clone, Debug, PartialEq)]
pub struct OnAutopilot {
    /// The mission they come from.
    pub ext_id: u32,
    /// Their ids, in item order.
    pub wp_ids: Vec<u32>,
    /// The item of the first waypoint.
    pub first_seq: u16,
}

/// The run `mw_exec` started.
#[derive(Clone, Debug, PartialEq)]
pub struct Run {
    /// The waypoints it flies.
    pub plan: OnAutopilot,
    /// Waypoints reached so far, in the order told.
    pub reached: Vec<u32>,
    /// The waypoint the autopilot flies to now.
    pub current: Option<u32>,
    /// How it goes.
    pub status: Status,
    /// The 1-based index of the last item told reached; 0 before any.
    told: u32,
    /// Whether the heartbeat showed the vehicle flying it (armed, in the
    /// mission mode): until then the mode it leaves says nothing of it.
    flown: bool,
    /// Since when the autopilot holds before the last item was heard
    /// reached, ms.
    held_ms: Option<i64>,
    /// The item the last `MISSION_ITEM_REACHED` before the run named: a
    /// repeat of it is the last run's until `MISSION_CURRENT` shows this
    /// run got that far.
    stale: Option<u16>,
    /// Whether the autopilot accepted `MISSION_START`: until then its
    /// progress waits here, told after `started` (a run that never
    /// started tells nothing).
    confirmed: bool,
    unconfirmed: Vec<Event>,
}

impl Run {
    fn new(plan: OnAutopilot, stale: Option<u16>) -> Run {
        Run {
            plan,
            reached: Vec::new(),
            current: None,
            status: Status::Running,
            told: 0,
            flown: false,
            held_ms: None,
            stale,
            confirmed: false,
            unconfirmed: Vec::new(),
        }
    }

    /// The 1-based index in the run of mission item `seq`, and its
    /// waypoint's id.
    fn item(&self, seq: u16) -> Option<(u32, u32)> {
        let i = usize::from(seq.checked_sub(self.plan.first_seq)?);
        let id = *self.plan.wp_ids.get(i)?;
        Some((u32::try_from(i + 1).ok()?, id))
    }

    fn count(&self) -> u32 {
        u32::try_from(self.plan.wp_ids.len()).unwrap_or(u32::MAX)
    }
}

/// The missions the vehicle knows of.
#[derive(Debug, Default)]
pub struct Missions {
    submitted: VecDeque<Mission>,
    /// What the autopilot holds, after a successful upload.
    on_autopilot: Option<OnAutopilot>,
    /// The latest run.
    run: Option<Run>,
    /// The item the latest `MISSION_ITEM_REACHED` named, run or not.
    last_reached: Option<u16>,
    /// The runs' progress to be told, in order.
    news: Vec<Event>,
}

impl Missions {
    /// Keeps a mission the autopilot accepted, from item `first_seq` on:
    /// it is what the autopilot holds now.
    pub fn uploaded(&mut self, mission: Mission, first_seq: u16) {
        self.on_autopilot = Some(OnAutopilot {
            ext_id: mission.ext_id,
            wp_ids: mission.waypoints.iter().map(|w| w.id).collect(),
            first_seq,
        });
        self.submitted.retain(|m| m.ext_id != mission.ext_id);
        let running = self.running();
        if self.submitted.len() >= MAX_KEPT
            && let Some(oldest) = self.submitted.iter().position(|m| Some(m.ext_id) != running)
        {
            self.submitted.remove(oldest);
        }
        self.submitted.push_back(mission);
    }

    /// The external id of the mission whose run has not ended, if any (the
    /// caller knows whether the vehicle still flies it).
    pub fn running(&self) -> Option<u32> {
        self.run
            .as_ref()
            .filter(|r| r.status == Status::Running)
            .map(|r| r.plan.ext_id)
    }

    /// `plan` is what the autopilot holds now.
    pub fn holds(&mut self, plan: OnAutopilot) {
        self.on_autopilot = Some(plan);
    }

    /// An upload failed: the autopilot may hold part of it (some store
    /// items as they arrive), so no mission is known to be on it and
    /// `mw_exec` uploads its mission again.
    pub fn upload_failed(&mut self) {
        self.on_autopilot = None;
    }

    /// What the autopilot holds, as far as lluavd knows.
    pub fn on_autopilot(&self) -> Option<&OnAutopilot> {
        self.on_autopilot.as_ref()
    }

    /// A run of `plan` starts: the run it replaces, if it still ran, is
    /// aborted.
    pub fn start_run(&mut self, plan: OnAutopilot) {
        self.abort();
        self.run = Some(Run::new(plan, self.last_reached));
    }

    /// Another vehicle: it holds none of lluavd's missions and flies no
    /// run (the one running is aborted). The submitted missions stay, to
    /// be uploaded again.
    pub fn new_vehicle(&mut self) {
        self.abort();
        self.on_autopilot = None;
        self.run = None;
        self.last_reached = None;
    }

    /// The run did not start after all (its `started` was never told).
    pub fn drop_run(&mut self) {
        self.run = None;
    }

    /// Ends the run, if it still runs, before its last waypoint.
    fn abort(&mut self) {
        if let Some(run) = self.run.as_mut().filter(|r| r.status == Status::Running) {
            run.status = Status::Interrupted;
            let ext_id = run.plan.ext_id;
            tracing::info!(ext_id, reached = run.reached.len(), "mission run aborted");
            self.tell(ext_id, MissionStatus::Aborted);
        }
    }

    fn tell(&mut self, ext_id: u32, status: MissionStatus) {
        let event = Event::Mission { ext_id, status };
        match self.run.as_mut() {
            Some(run) if !run.confirmed => run.unconfirmed.push(event),
            _ => self.news.push(event),
        }
    }

    /// The autopilot accepted the run's `MISSION_START`: it is told
    /// `started`, then whatever progress came before the answer did.
    pub fn started(&mut self) {
        if let Some(run) = self.run.as_mut().filter(|r| !r.confirmed) {
            run.confirmed = true;
            self.news.push(Event::Mission {
                ext_id: run.plan.ext_id,
                status: MissionStatus::Started,
            });
            self.news.append(&mut run.unconfirmed);
        }
    }

    /// The runs' progress since the last call, in order.
    pub fn drain_news(&mut self, out: &mut Vec<Event>) {
        out.append(&mut self.news);
    }

    /// Takes in the heartbeat's mode at `now_ms`: whether the vehicle
    /// flies a mission (armed, in the mission mode) or holds in the mode
    /// PX4 enters at a mission's end. A run the vehicle flew, then left
    /// before its last waypoint, is aborted (after [`HOLD_GRACE_MS`] in
    /// that hold); a disarmed vehicle flies no run.
    pub fn observe_mode(&mut self, flying_mission: bool, holding: bool, armed: bool, now_ms: i64) {
        let Some(run) = self.run.as_mut().filter(|r| r.status == Status::Running) else {
            return;
        };
        if flying_mission {
            run.flown = true;
            run.held_ms = None;
        } else if !armed || (run.flown && !holding) {
            self.abort();
        } else if run.flown {
            run.held_ms.get_or_insert(now_ms);
        }
    }

    /// Aborts a run held at `now_ms` for [`HOLD_GRACE_MS`] before its
    /// last waypoint was heard reached.
    pub fn expire(&mut self, now_ms: i64) {
        if self.hold_ends_ms().is_some_and(|end| end <= now_ms) {
            self.abort();
        }
    }

    /// When a hold before the last waypoint ends the run, ms.
    pub fn hold_ends_ms(&self) -> Option<i64> {
        self.run
            .as_ref()
            .filter(|r| r.status == Status::Running)
            .and_then(|r| r.held_ms)
            .map(|t| t.saturating_add(HOLD_GRACE_MS))
    }

    /// The waypoints `wp_ids` of mission `ext_id`, in that order.
    pub fn select(&self, ext_id: u32, wp_ids: &[u32]) -> Result<Vec<Waypoint>, MavError> {
        let mission = self
            .submitted
            .iter()
            .find(|m| m.ext_id == ext_id)
            .ok_or_else(|| MavError::Invalid(format!("unknown mission {ext_id}")))?;
        let mut missing = Vec::new();
        let picked: Vec<Waypoint> = wp_ids
            .iter()
            .filter_map(|id| {
                let wp = mission.waypoints.iter().find(|w| w.id == *id).copied();
                if wp.is_none() {
                    missing.push(id.to_string());
                }
                wp
            })
            .collect();
        if missing.is_empty() {
            Ok(picked)
        } else {
            Err(MavError::Invalid(format!(
                "mission {ext_id} has no waypoint {}",
                missing.join(",")
            )))
        }
    }

    /// How many missions are kept.
    #[cfg(feature = "fuzzing")]
    pub fn kept(&self) -> usize {
        self.submitted.len()
    }

    /// The latest mission.
    pub fn latest(&self) -> Option<&Mission> {
        self.submitted.back()
    }

    /// Takes in mission progress from the autopilot: each item of the
    /// run told reached once, in order, and the run completed with its
    /// last.
    pub fn observe(&mut self, msg: &MavMessage) {
        let seq = match msg {
            MavMessage::MISSION_ITEM_REACHED(r) => {
                self.last_reached = Some(r.seq);
                r.seq
            }
            MavMessage::MISSION_CURRENT(c) => {
                if let Some(run) = self.run.as_mut() {
                    run.current = run.item(c.seq).map(|(_, id)| id);
                    if run.stale.is_some_and(|s| c.seq >= s) {
                        run.stale = None;
                    }
                }
                return;
            }
            _ => return,
        };
        let Some(run) = self.run.as_mut().filter(|r| r.status == Status::Running) else {
            return;
        };
        if run.stale == Some(seq) {
            return;
        }
        let Some((index, wp)) = run.item(seq).filter(|&(index, _)| index > run.told) else {
            return;
        };
        run.told = index;
        run.reached.push(wp);
        let (ext_id, count) = (run.plan.ext_id, run.count());
        let last = index == count;
        if last {
            run.status = Status::Completed;
        }
        self.tell(ext_id, MissionStatus::Reached { wp, index, count });
        if last {
            self.tell(ext_id, MissionStatus::Completed);
        }
    }

    /// Writes `mission` in `state`: the run's progress, or null.
    pub fn write_state(&self, s: &mut Fields<'_>) {
        match &self.run {
            Some(run) => s.object("mission", |o| write_run(run, o)),
            None => s.null("mission"),
        };
    }

    /// Writes `dump_missionresult`'s `result`.
    pub fn write_result(&self, ext_id: Option<u32>, out: &mut Fields<'_>) -> Result<(), MavError> {
        match &self.run {
            Some(run) if ext_id.is_none_or(|id| id == run.plan.ext_id) => {
                out.object("result", |o| write_run(run, o));
                Ok(())
            }
            _ => Err(match ext_id {
                Some(id) => MavError::Invalid(format!("no run of mission {id}")),
                None => MavError::State("No mission has run".into()),
            }),
        }
    }

    /// Writes `mw_list`: the latest mission's waypoints.
    pub fn write_list(&self, out: &mut Fields<'_>) {
        match self.latest() {
            Some(m) => {
                out.u64("ext_id", m.ext_id.into()).array("waypoints", |a| {
                    for w in &m.waypoints {
                        a.object(|o| {
                            o.u64("id", w.id.into());
                            w.ned.write(o);
                            match w.yaw {
                                Some(y) => o.f32("yaw", y as f32),
                                None => o.null("yaw"),
                            };
                        });
                    }
                });
            }
            None => {
                out.null("ext_id").array("waypoints", |_| {});
            }
        }
    }
}

fn write_run(run: &Run, o: &mut Fields<'_>) {
    let ids = |o: &mut Fields<'_>, key: &str, ids: &[u32]| {
        o.array(key, |a| {
            for id in ids {
                a.u64((*id).into());
            }
        });
    };
    o.u64("ext_id", run.plan.ext_id.into());
    ids(o, "wp_ids", &run.plan.wp_ids);
    ids(o, "reached", &run.reached);
    match run.current {
        Some(c) => o.u64("current", c.into()),
        None => o.null("current"),
    };
    o.str("status", run.status.name());
}

/// Whether the heartbeat's `custom_mode` is the mode an autopilot of
/// `flavour` enters at a mission's end on its own: PX4's hold. (ArduCopter
/// stays in AUTO at the end; any other mode is a change of plan.)
pub fn end_of_mission_hold(flavour: Flavour, custom_mode: u32) -> bool {
    flavour != Flavour::ArduPilot && flavour.mode_name(custom_mode) == "AUTO.LOITER"
}

/// Whether the heartbeat's `custom_mode` flies a mission.
pub fn mission_mode(flavour: Flavour, custom_mode: u32) -> bool {
    flavour.phase(custom_mode) == Phase::Mission
}

/// The mission items for `waypoints`: `MAV_CMD_NAV_WAYPOINT`s at the
/// global position of each, relative to home's altitude, preceded on
/// ArduPilot by the home item it keeps at 0. Returns the items and the
/// item of the first waypoint.
// MAV_FRAME_GLOBAL_INT and _RELATIVE_ALT_INT are deprecated for the
// plain frames since 2024, but autopilots older than that know only these.
#[allow(deprecated)]
pub fn items(
    flavour: Flavour,
    home: Global,
    home_local: Ned,
    waypoints: &[Waypoint],
) -> (Vec<MISSION_ITEM_INT_DATA>, u16) {
    let mut items = Vec::with_capacity(waypoints.len() + 1);
    if flavour == Flavour::ArduPilot {
        let (lat, lon) = home.e7();
        items.push(mission_item(
            MavCmd::MAV_CMD_NAV_WAYPOINT,
            MavFrame::MAV_FRAME_GLOBAL_INT,
            [0.0; 4],
            (lat, lon, home.alt as f32),
        ));
    }
    let first_seq = u16::try_from(items.len()).unwrap_or(0);
    for w in waypoints {
        let p = home.offset(w.ned.x - home_local.x, w.ned.y - home_local.y, 0.0);
        let (lat, lon) = p.e7();
        let above_home = -(w.ned.z - home_local.z);
        let yaw_deg = w.yaw.map_or(f32::NAN, |y| y.to_degrees() as f32);
        items.push(mission_item(
            MavCmd::MAV_CMD_NAV_WAYPOINT,
            MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            [0.0, 0.0, 0.0, yaw_deg],
            (lat, lon, above_home as f32),
        ));
    }
    (items, first_seq)
}

#[cfg(test)]
#[allow(deprecated)]
mod tests {
    use super::*;

    const HOME: Global = Global {
        lat: 47.397_742,
        lon: 8.545_594,
        alt: 488.0,
    };

    fn wp(id: u32, x: f64, y: f64, z: f64) -> Waypoint {
        Waypoint {
            id,
            ned: Ned::new(x, y, z),
            yaw: Some(std::f64::consts::FRAC_PI_2),
        }
    }

    #[test]
    fn ned_waypoints_become_global_items_relative_to_home() {
        let home_local = Ned::new(1.0, 2.0, -0.5);
        let (items, first) = items(Flavour::Px4, HOME, home_local, &[wp(1, 11.0, 2.0, -10.5)]);
        assert_eq!((items.len(), first), (1, 0));
        let i = &items[0];
        // 10 m north of home, same longitude, 10 m above home.
        let (n, e, _) = HOME.ned_to(Global::from_e7(i.x, i.y, 0));
        assert!((n - 10.0).abs() < 0.02 && e.abs() < 0.02, "{n} {e}");
        assert_eq!(i.y, 85_455_940);
        assert_eq!(i.z, 10.0);
        assert_eq!(i.param4, 90.0);
        assert_eq!(i.frame, MavFrame::MAV_FRAME_GLOBAL_RELATIVE_ALT_INT);
        assert_eq!(i.command, MavCmd::MAV_CMD_NAV_WAYPOINT);
    }

    #[test]
    fn ardupilot_missions_start_with_home_in_item_zero() {
        let (items, first) = items(Flavour::ArduPilot, HOME, Ned::default(), &[wp(1, 0.0, 5.0, -3.0)]);
        assert_eq!((items.len(), first), (2, 1));
        assert_eq!((items[0].x, items[0].y), HOME.e7());
        assert_eq!(items[0].frame, MavFrame::MAV_FRAME_GLOBAL_INT);
    }

    use ::mavlink::dialects::ardupilotmega::{MISSION_CURRENT_DATA, MISSION_ITEM_REACHED_DATA};

    fn reached(seq: u16) -> MavMessage {
        MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA { seq })
    }

    fn current(seq: u16) -> MavMessage {
        MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA { seq })
    }

    /// Mission 7's run of waypoints 4 and 9 at items 1 and 2, started.
    fn running() -> Missions {
        let mut m = Missions::default();
        m.start_run(OnAutopilot {
            ext_id: 7,
            wp_ids: vec![4, 9],
            first_seq: 1,
        });
        m.started();
        m
    }

    fn told(m: &mut Missions) -> Vec<MissionStatus> {
        let mut out = Vec::new();
        m.drain_news(&mut out);
        out.into_iter()
            .map(|e| match e {
                Event::Mission { ext_id: 7, status } => status,
                other => panic!("not mission 7's: {other:?}"),
            })
            .collect()
    }

    const fn at(wp: u32, index: u32) -> MissionStatus {
        MissionStatus::Reached { wp, index, count: 2 }
    }

    #[test]
    fn progress_maps_mission_items_back_to_waypoint_ids() {
        let mut m = running();
        m.observe(&current(2));
        m.observe(&reached(1));
        let run = m.run.as_ref().unwrap();
        assert_eq!(
            (run.current, run.reached.as_slice(), run.status),
            (Some(9), &[4][..], Status::Running)
        );
        m.observe(&reached(2));
        assert_eq!(m.run.as_ref().unwrap().status, Status::Completed);
        assert_eq!(
            told(&mut m),
            [
                MissionStatus::Started,
                at(4, 1),
                at(9, 2),
                MissionStatus::Completed
            ]
        );
    }

    #[test]
    fn repeated_and_older_items_are_told_once() {
        let mut m = running();
        told(&mut m);
        // PX4 repeats its last MISSION_ITEM_REACHED; an item behind the
        // last one told (ArduPilot's for a completed one) says nothing new.
        for msg in [reached(1), reached(1), reached(0), reached(1)] {
            m.observe(&msg);
        }
        assert_eq!(told(&mut m), [at(4, 1)]);
    }

    #[test]
    fn the_last_runs_repeats_count_only_once_this_run_got_that_far() {
        let mut m = running();
        m.observe(&reached(1));
        m.observe(&reached(2));
        told(&mut m);
        // Run again at once: PX4 still repeats item 2.
        m.start_run(OnAutopilot {
            ext_id: 7,
            wp_ids: vec![4, 9],
            first_seq: 1,
        });
        m.started();
        m.observe(&reached(2));
        assert_eq!(told(&mut m), [MissionStatus::Started]);
        m.observe(&current(1));
        m.observe(&reached(1));
        m.observe(&current(2));
        m.observe(&reached(2));
        assert_eq!(told(&mut m), [at(4, 1), at(9, 2), MissionStatus::Completed]);
    }

    #[test]
    fn a_run_left_before_its_end_is_aborted() {
        // Another mode (a pilot, a return) after flying it.
        let mut m = running();
        m.observe_mode(true, false, true, 0);
        m.observe(&reached(1));
        m.observe_mode(false, false, true, 100);
        assert_eq!(
            told(&mut m),
            [MissionStatus::Started, at(4, 1), MissionStatus::Aborted]
        );
        // Not before it was flown: the mode it starts from says nothing.
        let mut m = running();
        m.observe_mode(false, false, true, 0);
        assert_eq!(told(&mut m), [MissionStatus::Started]);
        // Disarmed.
        m.observe_mode(false, false, false, 10);
        assert_eq!(told(&mut m), [MissionStatus::Aborted]);
        // Another run replaces it.
        let mut m = running();
        m.start_run(OnAutopilot {
            ext_id: 7,
            wp_ids: vec![4],
            first_seq: 1,
        });
        assert_eq!(told(&mut m), [MissionStatus::Started, MissionStatus::Aborted]);
    }

    #[test]
    fn a_hold_before_the_last_item_ends_the_run_only_after_its_grace() {
        let mut m = running();
        m.observe_mode(true, false, true, 0);
        m.observe(&reached(1));
        m.observe_mode(false, true, true, 1000);
        m.expire(1000 + HOLD_GRACE_MS - 1);
        assert_eq!(told(&mut m), [MissionStatus::Started, at(4, 1)]);
        // The last item's reached, late over a lossy link: completed.
        let mut late = running();
        late.observe_mode(true, false, true, 0);
        late.observe_mode(false, true, true, 1000);
        late.observe(&reached(2));
        late.expire(1000 + HOLD_GRACE_MS);
        assert_eq!(
            told(&mut late),
            [MissionStatus::Started, at(9, 2), MissionStatus::Completed]
        );
        // Nothing came: aborted.
        m.expire(1000 + HOLD_GRACE_MS);
        assert_eq!(told(&mut m), [MissionStatus::Aborted]);
    }

    #[test]
    fn a_run_whose_start_was_refused_tells_nothing_and_one_accepted_late_tells_in_order() {
        let mut m = Missions::default();
        let plan = OnAutopilot {
            ext_id: 7,
            wp_ids: vec![4, 9],
            first_seq: 1,
        };
        m.start_run(plan.clone());
        m.observe(&reached(1));
        m.drop_run();
        assert_eq!(told(&mut m), []);
        // Progress that came before MISSION_START's answer follows `started`
        // (item 1 counts once MISSION_CURRENT shows this run got there).
        m.start_run(plan);
        m.observe(&current(1));
        m.observe(&reached(1));
        assert_eq!(told(&mut m), []);
        m.started();
        assert_eq!(told(&mut m), [MissionStatus::Started, at(4, 1)]);
    }

    #[test]
    fn a_full_store_keeps_the_mission_that_runs() {
        let mut m = Missions::default();
        let mission = |ext_id| Mission {
            ext_id,
            waypoints: vec![wp(1, 0.0, 0.0, -1.0)],
        };
        m.uploaded(mission(7000), 0);
        m.start_run(OnAutopilot {
            ext_id: 7000,
            wp_ids: vec![1],
            first_seq: 0,
        });
        assert_eq!(m.running(), Some(7000));
        for ext_id in 1..=u32::try_from(MAX_KEPT).unwrap() {
            m.uploaded(mission(ext_id), 0);
        }
        assert_eq!(m.submitted.len(), MAX_KEPT);
        assert!(m.select(7000, &[1]).is_ok(), "the running mission stays");
        assert!(m.select(1, &[1]).is_err(), "the oldest other went");
        m.drop_run();
        assert_eq!(m.running(), None);
    }

    #[test]
    fn waypoints_are_selected_by_id_in_the_order_asked() {
        let mut m = Missions::default();
        m.uploaded(
            Mission {
                ext_id: 3,
                waypoints: vec![wp(1, 0.0, 0.0, -1.0), wp(2, 1.0, 0.0, -1.0)],
            },
            0,
        );
        let picked = m.select(3, &[2, 1]).unwrap();
        assert_eq!(picked.iter().map(|w| w.id).collect::<Vec<_>>(), [2, 1]);
        assert_eq!(
            m.select(3, &[5]).unwrap_err().to_string(),
            "Invalid arguments: mission 3 has no waypoint 5"
        );
        assert_eq!(
            m.select(4, &[1]).unwrap_err().to_string(),
            "Invalid arguments: unknown mission 4"
        );
    }

    #[test]
    fn after_a_failed_upload_no_mission_is_on_the_autopilot_but_all_are_kept() {
        let mut m = Missions::default();
        let waypoints = vec![wp(1, 0.0, 0.0, -1.0)];
        m.uploaded(Mission { ext_id: 3, waypoints }, 0);
        assert!(m.on_autopilot().is_some());
        m.upload_failed();
        assert_eq!(m.on_autopilot(), None);
        // Still known, so `mw_exec 3` uploads it again.
        assert_eq!(m.select(3, &[1]).unwrap().len(), 1);
    }
}
