//! Missions on the MAVLink vehicle: the submitted missions (DESIGN.md's
//! mission JSON, NED), the mission items they become (global, from the
//! vehicle's home), what is on the autopilot now, and the progress of
//! the run `mw_exec` started, from `MISSION_CURRENT` and
//! `MISSION_ITEM_REACHED`.

use std::collections::VecDeque;

use ::mavlink::dialects::ardupilotmega::{MISSION_ITEM_INT_DATA, MavCmd, MavFrame, MavMessage};
use lluav_core::Fields;

use super::autopilot::Flavour;
use super::error::MavError;
use super::geo::Global;
use super::protocol::mission_item;
use crate::vehicle::Ned;

/// Most missions kept; the oldest go first, never the one running.
const MAX_KEPT: usize = 64;

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

/// How a run goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Status {
    /// Flying.
    Running,
    /// The last waypoint was reached.
    Completed,
}

/// The run `mw_exec` started.
#[derive(Clone, Debug, PartialEq)]
pub struct Run {
    /// The waypoints it flies.
    pub plan: OnAutopilot,
    /// Waypoints reached so far.
    pub reached: Vec<u32>,
    /// The waypoint the autopilot flies to now.
    pub current: Option<u32>,
    /// How it goes.
    pub status: Status,
}

/// The missions the vehicle knows of.
#[derive(Debug, Default)]
pub struct Missions {
    submitted: VecDeque<Mission>,
    /// What the autopilot holds, after a successful upload.
    on_autopilot: Option<OnAutopilot>,
    /// The latest run.
    run: Option<Run>,
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

    /// A run of `plan` starts.
    pub fn start_run(&mut self, plan: OnAutopilot) {
        self.run = Some(Run {
            plan,
            reached: Vec::new(),
            current: None,
            status: Status::Running,
        });
    }

    /// Another vehicle: it holds none of lluavd's missions and flies no
    /// run. The submitted missions stay, to be uploaded again.
    pub fn new_vehicle(&mut self) {
        self.on_autopilot = None;
        self.run = None;
    }

    /// The run did not start after all.
    pub fn drop_run(&mut self) {
        self.run = None;
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

    /// Takes in mission progress from the autopilot.
    pub fn observe(&mut self, msg: &MavMessage) {
        let Some(run) = self.run.as_mut() else { return };
        let wp_at = |seq: u16| {
            let i = usize::from(seq.checked_sub(run.plan.first_seq)?);
            run.plan.wp_ids.get(i).copied()
        };
        match msg {
            MavMessage::MISSION_CURRENT(c) => run.current = wp_at(c.seq),
            MavMessage::MISSION_ITEM_REACHED(r) => {
                if let Some(id) = wp_at(r.seq)
                    && !run.reached.contains(&id)
                {
                    run.reached.push(id);
                    if run.plan.wp_ids.last() == Some(&id) {
                        run.status = Status::Completed;
                    }
                }
            }
            _ => {}
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
    o.str(
        "status",
        match run.status {
            Status::Running => "running",
            Status::Completed => "completed",
        },
    );
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

    #[test]
    fn progress_maps_mission_items_back_to_waypoint_ids() {
        let mut m = Missions {
            run: Some(Run {
                plan: OnAutopilot {
                    ext_id: 7,
                    wp_ids: vec![4, 9],
                    first_seq: 1,
                },
                reached: vec![],
                current: None,
                status: Status::Running,
            }),
            ..Missions::default()
        };
        use ::mavlink::dialects::ardupilotmega::{MISSION_CURRENT_DATA, MISSION_ITEM_REACHED_DATA};
        m.observe(&MavMessage::MISSION_CURRENT(MISSION_CURRENT_DATA { seq: 2 }));
        m.observe(&MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA {
            seq: 1,
        }));
        let run = m.run.as_ref().unwrap();
        assert_eq!(
            (run.current, run.reached.as_slice(), run.status),
            (Some(9), &[4][..], Status::Running)
        );
        m.observe(&MavMessage::MISSION_ITEM_REACHED(MISSION_ITEM_REACHED_DATA {
            seq: 2,
        }));
        assert_eq!(m.run.as_ref().unwrap().status, Status::Completed);
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
