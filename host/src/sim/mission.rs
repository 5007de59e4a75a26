//! Missions: the submitted missions (read by [`crate::vehicle::mission`]),
//! waypoint runs and their results, abort reports, plans and task names.
//!
//! What a client stores here has a maximum chosen so that every answer
//! that reports it fits lluavd's 64 KiB response buffer: a mission holds
//! at most [`crate::vehicle::mission::MAX_WAYPOINTS`] waypoints (`mw_list`
//! lists one whole), at most [`MAX_MISSIONS`] missions are kept
//! (`dump_missionlist` lists them all, paths included), and the core's
//! grammar keeps a plan within [`lluav_core::parse::MAX_TEXT_LEN`] bytes
//! and a task name within [`lluav_core::parse::MAX_TASK_NAME_LEN`]
//! (`state` reports both).

use lluav_core::{Args, Command, CommandId, Fields};

use super::error::{SimError, SimResult};
use super::flight::RouteEvent;
use crate::events::{Event, MissionStatus};
pub(crate) use crate::vehicle::mission::RunStatus as Status;
use crate::vehicle::mission::Waypoint;

/// Most missions kept (the oldest go first, never the one running):
/// `dump_missionlist` of that many, each with a path of the longest, is
/// under 36 KB.
pub(crate) const MAX_MISSIONS: usize = 16;
/// Most runs and abort reports kept; the oldest go first.
const MAX_KEPT: usize = 64;

/// Where a mission came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) enum Source {
    /// Inline JSON.
    Json,
    /// A file under the data directory.
    File(String),
    /// `ai1_mission` with this task id.
    Ai1(String),
}

/// A submitted mission.
#[derive(Clone, Debug)]
pub(crate) struct Mission {
    /// External id (`mission`); an AI1 task has none (0 here, never shown:
    /// its task id is in [`Source::Ai1`]).
    pub(crate) ext_id: u32,
    /// Where it came from.
    pub(crate) source: Source,
    /// Its waypoints.
    pub(crate) waypoints: Vec<Waypoint>,
    /// When it was received, ms since the Unix epoch.
    pub(crate) received_ms: i64,
}

/// One `mw_exec`.
#[derive(Clone, Debug)]
pub(crate) struct Run {
    /// The mission.
    pub(crate) ext_id: u32,
    /// The flight model's route id.
    pub(crate) route: u64,
    /// Waypoints asked for, in order.
    pub(crate) wp_ids: Vec<u32>,
    /// Waypoints reached so far.
    pub(crate) reached: Vec<u32>,
    /// How it went.
    pub(crate) status: Status,
    /// When it started, ms since the Unix epoch.
    pub(crate) started_ms: i64,
}

impl Run {
    fn write(&self, out: &mut Fields<'_>) {
        out.u64("ext_id", self.ext_id.into())
            .str("status", self.status.name())
            .array("wp_ids", |a| {
                self.wp_ids.iter().for_each(|&i| {
                    a.u64(i.into());
                })
            })
            .array("reached", |a| {
                self.reached.iter().for_each(|&i| {
                    a.u64(i.into());
                })
            })
            .i64("started_ms", self.started_ms);
    }
}

/// An `abort_report`.
#[derive(Clone, Debug)]
pub(crate) struct AbortReport {
    /// The id the client gave, or the one after the highest given so far.
    pub(crate) abort_id: u32,
    /// The run it ended, if one was running.
    pub(crate) ext_id: Option<u32>,
    /// Waypoints reached before the abort.
    pub(crate) reached: usize,
    /// Waypoints the run had.
    pub(crate) total: usize,
    /// When, ms since the Unix epoch.
    pub(crate) at_ms: i64,
}

/// All mission bookkeeping.
#[derive(Debug, Default)]
pub(crate) struct Missions {
    missions: Vec<Mission>,
    runs: Vec<Run>,
    reports: Vec<AbortReport>,
    /// The highest abort id ever given out: ids only grow, so none is
    /// given twice, even after its report was dropped.
    last_abort_id: Option<u32>,
    /// The current task name.
    taskname: Option<String>,
    /// Obstacle mission live mode.
    obs_live: bool,
    /// The plan last started.
    plan: Option<String>,
    /// Whether the plan lock is held.
    plan_locked: bool,
    /// Runs' progress, to be told (DESIGN.md, "Events").
    news: Vec<Event>,
}

/// Whether `b` replaces `a`: same external id, or same AI1 task id.
fn same_slot(a: &Mission, b: &Mission) -> bool {
    match (&a.source, &b.source) {
        (Source::Ai1(x), Source::Ai1(y)) => x == y,
        (Source::Ai1(_), _) | (_, Source::Ai1(_)) => false,
        _ => a.ext_id == b.ext_id,
    }
}

/// The `ext_id` a mission is run by: `None` for an AI1 task, which has its
/// own task id instead.
fn ext_id_of(m: &Mission) -> Option<u32> {
    match m.source {
        Source::Ai1(_) => None,
        Source::Json | Source::File(_) => Some(m.ext_id),
    }
}

fn push_bounded<T>(v: &mut Vec<T>, item: T, most: usize) {
    if v.len() >= most {
        v.remove(0);
    }
    v.push(item);
}

impl Missions {
    /// The commands that only keep books: `plan`, `unlock_plan`,
    /// `mw_list`, `obs_mission`, `dump_missionresult`, `dump_missionlist`,
    /// `set_taskname`.
    pub(crate) fn run(&mut self, cmd: &Command<'_>, out: &mut Fields<'_>) -> SimResult {
        match (cmd.id(), cmd.args()) {
            (CommandId::Plan, Args::Text(plan)) => {
                if self.plan_locked {
                    return Err(SimError::PlanLocked);
                }
                (self.plan, self.plan_locked) = (Some((*plan).to_owned()), true);
                tracing::info!(plan, "plan started");
                out.str("plan", plan).bool("plan_lock", true);
            }
            (CommandId::UnlockPlan, _) => {
                self.plan_locked = false;
                out.bool("plan_lock", false);
            }
            (CommandId::MwList, _) => self.write_latest(out),
            (CommandId::ObsMission, &Args::Flag(on)) => {
                self.obs_live = on;
                out.bool("obs_mission", on);
            }
            (CommandId::DumpMissionresult, &Args::OptCount(ext_id)) => self.write_result(ext_id, out)?,
            (CommandId::SetTaskname, Args::TaskName(name)) => {
                self.taskname = Some((*name).to_owned());
                out.str("taskname", name);
            }
            _ => self.write_list(out),
        }
        Ok(())
    }

    /// Writes the bookkeeping's members of `state`.
    pub(crate) fn write_state(&self, s: &mut Fields<'_>) {
        s.bool("plan_lock", self.plan_locked)
            .bool("obs_mission", self.obs_live);
        for (key, value) in [("plan", &self.plan), ("taskname", &self.taskname)] {
            match value {
                Some(v) => s.str(key, v),
                None => s.null(key),
            };
        }
    }

    /// The external id of the mission a run is flying now, if any.
    pub(crate) fn running(&self) -> Option<u32> {
        self.runs
            .iter()
            .rev()
            .find(|r| r.status == Status::Running)
            .map(|r| r.ext_id)
    }

    /// Stores a mission, replacing one with the same external id (or the
    /// same AI1 task id): -1 for the mission that is running, whose
    /// waypoints the vehicle is flying. When the store is full the oldest
    /// mission goes, never the one running.
    pub(crate) fn submit(&mut self, mission: Mission) -> SimResult {
        let running = self.running();
        if let Some(ext_id) = ext_id_of(&mission).filter(|&id| running == Some(id)) {
            return Err(SimError::MissionRunning(ext_id));
        }
        self.missions.retain(|m| !same_slot(m, &mission));
        if self.missions.len() >= MAX_MISSIONS
            && let Some(oldest) = self
                .missions
                .iter()
                .position(|m| running.is_none() || ext_id_of(m) != running)
        {
            self.missions.remove(oldest);
        }
        self.missions.push(mission);
        Ok(())
    }

    /// The mission with this external id.
    pub(crate) fn get(&self, ext_id: u32) -> SimResult<&Mission> {
        self.missions
            .iter()
            .rev()
            .find(|m| ext_id_of(m) == Some(ext_id))
            .ok_or(SimError::UnknownMission(ext_id))
    }

    /// Writes the most recently submitted mission's id (`task_id` for an
    /// AI1 task) and waypoints.
    fn write_latest(&self, out: &mut Fields<'_>) {
        match self.missions.last() {
            Some(m) => {
                m.write_id(out);
                out.array("waypoints", |a| {
                    for wp in &m.waypoints {
                        a.object(|o| wp.write(o));
                    }
                });
            }
            None => {
                out.null("ext_id").array("waypoints", |_| {});
            }
        }
    }

    /// The waypoints of `ext_id` with these ids, in the order asked, or the
    /// ids it does not have.
    pub(crate) fn select(&self, ext_id: u32, ids: &[u32]) -> SimResult<Vec<Waypoint>> {
        let mission = self.get(ext_id)?;
        let find = |id: u32| mission.waypoints.iter().find(|w| w.wp_id() == id).copied();
        let missing: Vec<String> = ids
            .iter()
            .filter(|&&id| find(id).is_none())
            .map(u32::to_string)
            .collect();
        if !missing.is_empty() {
            return Err(SimError::UnknownWaypoints {
                ext_id,
                ids: missing.join(","),
            });
        }
        Ok(ids.iter().filter_map(|&id| find(id)).collect())
    }

    /// Records a new run.
    pub(crate) fn start_run(&mut self, run: Run) {
        self.tell(run.ext_id, MissionStatus::Started);
        push_bounded(&mut self.runs, run, MAX_KEPT);
    }

    fn tell(&mut self, ext_id: u32, status: MissionStatus) {
        self.news.push(Event::Mission { ext_id, status });
    }

    /// What happened to runs since the last call, in order.
    pub(crate) fn drain_news(&mut self, out: &mut Vec<Event>) {
        out.append(&mut self.news);
    }

    /// Applies the flight model's route events to the runs.
    pub(crate) fn apply(&mut self, events: &[RouteEvent]) {
        for event in events {
            let (RouteEvent::Reached { route, .. }
            | RouteEvent::Finished { route }
            | RouteEvent::Dropped { route }) = *event;
            let Some(run) = self.runs.iter_mut().rev().find(|r| r.route == route) else {
                continue;
            };
            let count = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
            let told = match *event {
                RouteEvent::Reached { wp, .. } => {
                    run.reached.push(wp);
                    Some(MissionStatus::Reached {
                        wp,
                        index: count(run.reached.len()),
                        count: count(run.wp_ids.len()),
                    })
                }
                RouteEvent::Finished { .. } if run.status == Status::Running => {
                    run.status = Status::Completed;
                    Some(MissionStatus::Completed)
                }
                RouteEvent::Dropped { .. } if run.status == Status::Running => {
                    run.status = Status::Interrupted;
                    Some(MissionStatus::Aborted)
                }
                _ => None,
            };
            if let Some(status) = told {
                let ext_id = run.ext_id;
                self.tell(ext_id, status);
            }
        }
    }

    /// Marks the running run aborted and records a report under
    /// `abort_id`, or the next id. An id is never given twice: one at or
    /// below the highest given so far is refused (-2), and nothing is
    /// aborted then.
    pub(crate) fn abort(&mut self, abort_id: Option<u32>, now_ms: i64) -> SimResult<AbortReport> {
        let abort_id = match (abort_id, self.last_abort_id) {
            (Some(id), Some(last)) if id <= last => return Err(SimError::AbortIdUsed { id, last }),
            (Some(id), _) => id,
            (None, None) => 1,
            (None, Some(last)) => last.checked_add(1).ok_or(SimError::AbortIdsSpent)?,
        };
        self.last_abort_id = Some(abort_id);
        let run = self.runs.last_mut().filter(|r| r.status == Status::Running);
        let (ext_id, reached, total) = match run {
            Some(r) => {
                r.status = Status::Aborted;
                self.news.push(Event::Mission {
                    ext_id: r.ext_id,
                    status: MissionStatus::Aborted,
                });
                (Some(r.ext_id), r.reached.len(), r.wp_ids.len())
            }
            None => (None, 0, 0),
        };
        let report = AbortReport {
            abort_id,
            ext_id,
            reached,
            total,
            at_ms: now_ms,
        };
        push_bounded(&mut self.reports, report.clone(), MAX_KEPT);
        Ok(report)
    }

    /// Writes `mission_result` for `ext_id` (or the latest run): `null`
    /// when nothing ran yet and no id was asked for.
    fn write_result(&self, ext_id: Option<u32>, out: &mut Fields<'_>) -> SimResult {
        let run = self
            .runs
            .iter()
            .rev()
            .find(|r| ext_id.is_none_or(|id| r.ext_id == id));
        match (run, ext_id) {
            (Some(run), _) => {
                out.object("mission_result", |o| run.write(o));
            }
            (None, None) => {
                out.null("mission_result");
            }
            (None, Some(id)) => return Err(SimError::NotFound(format!("no run of mission {id}"))),
        }
        Ok(())
    }

    /// Writes `missions`: every stored mission, shortly.
    fn write_list(&self, out: &mut Fields<'_>) {
        out.array("missions", |a| {
            for m in &self.missions {
                a.object(|o| {
                    m.write_id(o);
                    o.u64("waypoints", m.waypoints.len() as u64);
                    match &m.source {
                        Source::Json => o.str("source", "json"),
                        Source::File(p) => o.str("source", "file").str("path", p),
                        Source::Ai1(_) => o.str("source", "ai1"),
                    };
                    o.i64("received_ms", m.received_ms);
                });
            }
        });
    }
}

impl Mission {
    /// Writes what the mission is known by: `ext_id`, or an AI1 task's
    /// own `task_id` (it has no external id: never a second `ext_id` 0).
    fn write_id(&self, out: &mut Fields<'_>) {
        match &self.source {
            Source::Ai1(task) => out.str("task_id", task),
            Source::Json | Source::File(_) => out.u64("ext_id", self.ext_id.into()),
        };
    }
}

impl AbortReport {
    /// Writes the report as members of an object.
    pub(crate) fn write(&self, out: &mut Fields<'_>) {
        out.u64("abort_id", self.abort_id.into());
        match self.ext_id {
            Some(id) => out.u64("ext_id", id.into()),
            None => out.null("ext_id"),
        };
        out.bool("aborted", self.ext_id.is_some())
            .u64("reached", self.reached as u64)
            .u64("total", self.total as u64)
            .i64("at_ms", self.at_ms);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vehicle::Ned;
    use crate::vehicle::envelope::Envelope;
    use crate::vehicle::mission::parse;

    fn fence() -> Envelope {
        Envelope {
            home: Ned::default(),
            min_alt: 0.5,
            max_alt: 50.0,
            radius: 100.0,
        }
    }

    #[test]
    fn unknown_waypoint_ids_are_named() {
        let mut m = Missions::default();
        m.submit(Mission {
            ext_id: 9,
            source: Source::Json,
            waypoints: parse(
                r#"{"waypoints":[{"x":1,"y":0,"z":-1},{"x":2,"y":0,"z":-1}]}"#,
                &fence(),
            )
            .unwrap(),
            received_ms: 0,
        })
        .unwrap();
        assert_eq!(
            m.select(9, &[2, 1])
                .unwrap()
                .iter()
                .map(Waypoint::wp_id)
                .collect::<Vec<_>>(),
            [2, 1]
        );
        assert_eq!(
            m.select(9, &[1, 7, 8]).unwrap_err().to_string(),
            "Invalid arguments: mission 9 has no waypoint 7,8"
        );
        assert_eq!(
            m.select(3, &[1]).unwrap_err().to_string(),
            "Invalid arguments: unknown mission 3"
        );
    }

    fn mission(ext_id: u32, source: Source) -> Mission {
        Mission {
            ext_id,
            source,
            waypoints: parse(r#"[{"x":1,"y":0,"z":-1},{"x":2,"y":0,"z":-1}]"#, &fence()).unwrap(),
            received_ms: 0,
        }
    }

    fn run(ext_id: u32) -> Run {
        Run {
            ext_id,
            route: 1,
            wp_ids: vec![1, 2],
            reached: Vec::new(),
            status: Status::Running,
            started_ms: 0,
        }
    }

    #[test]
    fn a_full_store_drops_the_oldest_mission_but_never_the_running_one() {
        let mut m = Missions::default();
        m.submit(mission(7000, Source::Json)).unwrap();
        m.start_run(run(7000));
        for ext_id in 1..=u32::try_from(MAX_MISSIONS).unwrap() + 1 {
            m.submit(mission(ext_id, Source::Json)).unwrap();
        }
        assert_eq!(m.missions.len(), MAX_MISSIONS);
        assert!(m.get(7000).is_ok(), "the running mission stays");
        assert!(m.get(1).is_err() && m.get(2).is_err(), "the oldest others went");
        assert!(m.get(u32::try_from(MAX_MISSIONS).unwrap() + 1).is_ok());
    }

    #[test]
    fn the_running_missions_ext_id_cannot_be_uploaded_again() {
        let mut m = Missions::default();
        m.submit(mission(7000, Source::Json)).unwrap();
        m.start_run(run(7000));
        let e = m.submit(mission(7000, Source::Json)).unwrap_err();
        assert_eq!(e.to_string(), "Mission 7000 is running");
        assert_eq!(lluav_core::Ret::Failed, crate::vehicle::Refusal::ret(&e));
        m.submit(mission(7001, Source::Json)).unwrap();
        // An AI1 task has no ext_id of its own: it never collides.
        m.submit(mission(0, Source::Ai1("t1".into()))).unwrap();
        m.apply(&[RouteEvent::Finished { route: 1 }]);
        m.submit(mission(7000, Source::Json)).unwrap();
    }
}
