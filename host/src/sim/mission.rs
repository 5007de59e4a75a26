//! Missions: the submitted missions (read by [`crate::vehicle::mission`]),
//! waypoint runs and their results, abort reports, plans and task names.
//!
//! What a client stores here has a maximum chosen so that every answer
//! that reports it fits lluavd's 64 KiB response buffer: a mission holds
//! at most [`crate::vehicle::mission::MAX_WAYPOINTS`] waypoints (`mw_list`
//! lists one whole), at most [`MAX_MISSIONS`] missions are kept
//! (`dump_missionlist` lists them all, paths included), a plan is at most
//! [`MAX_PLAN`] bytes and a task name [`MAX_TASKNAME`] (`state` reports
//! both).

use lluav_core::{Args, Command, CommandId, Fields};

use super::error::{SimError, SimResult};
use super::flight::RouteEvent;
use crate::events::{Event, MissionStatus};
use crate::vehicle::mission::Waypoint;

/// Most missions kept (the oldest go first): `dump_missionlist` of that
/// many, each with a path of the longest, is under 36 KB.
pub(crate) const MAX_MISSIONS: usize = 16;
/// Most runs and abort reports kept; the oldest go first.
const MAX_KEPT: usize = 64;
/// Longest plan, bytes.
pub(crate) const MAX_PLAN: usize = 4096;
/// Longest task name, bytes.
pub(crate) const MAX_TASKNAME: usize = 256;

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
    /// External id (`mission`), or 0 for an AI1 task.
    pub(crate) ext_id: u32,
    /// Where it came from.
    pub(crate) source: Source,
    /// Its waypoints.
    pub(crate) waypoints: Vec<Waypoint>,
    /// When it was received, ms since the Unix epoch.
    pub(crate) received_ms: i64,
}

/// How a waypoint run went.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Status {
    /// Still flying.
    Running,
    /// Every waypoint reached.
    Completed,
    /// Replaced by another command (setpoint, land, RTL, disarm, ...).
    Interrupted,
    /// Ended by `abort_report`.
    Aborted,
}

impl Status {
    fn name(self) -> &'static str {
        match self {
            Status::Running => "running",
            Status::Completed => "completed",
            Status::Interrupted => "interrupted",
            Status::Aborted => "aborted",
        }
    }
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
    /// The id the client gave, or the next free one.
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

/// Refuses `text` longer than `most` bytes (-2).
fn at_most(what: &str, text: &str, most: usize) -> SimResult {
    if text.len() > most {
        return Err(SimError::Refused(format!("{what} longer than {most} bytes")));
    }
    Ok(())
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
                at_most("plan", plan, MAX_PLAN)?;
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
            (CommandId::SetTaskname, Args::Text(name)) => {
                at_most("task name", name, MAX_TASKNAME)?;
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

    /// Stores a mission, replacing one with the same external id (or the
    /// same AI1 task id).
    pub(crate) fn submit(&mut self, mission: Mission) {
        self.missions.retain(|m| !same_slot(m, &mission));
        push_bounded(&mut self.missions, mission, MAX_MISSIONS);
    }

    /// The mission with this external id.
    pub(crate) fn get(&self, ext_id: u32) -> SimResult<&Mission> {
        self.missions
            .iter()
            .rev()
            .find(|m| m.ext_id == ext_id && !matches!(m.source, Source::Ai1(_)))
            .ok_or(SimError::UnknownMission(ext_id))
    }

    /// Writes the most recently submitted mission's id and waypoints.
    fn write_latest(&self, out: &mut Fields<'_>) {
        match self.missions.last() {
            Some(m) => {
                out.u64("ext_id", m.ext_id.into()).array("waypoints", |a| {
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

    /// Whether a waypoint run is under way.
    pub(crate) fn running(&self) -> bool {
        self.runs.last().is_some_and(|r| r.status == Status::Running)
    }

    /// Marks the running run aborted and records a report.
    pub(crate) fn abort(&mut self, abort_id: Option<u32>, now_ms: i64) -> AbortReport {
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
        let next = self.reports.last().map_or(1, |r| r.abort_id.saturating_add(1));
        let report = AbortReport {
            abort_id: abort_id.unwrap_or(next),
            ext_id,
            reached,
            total,
            at_ms: now_ms,
        };
        push_bounded(&mut self.reports, report.clone(), MAX_KEPT);
        report
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
                    o.u64("ext_id", m.ext_id.into())
                        .u64("waypoints", m.waypoints.len() as u64);
                    match &m.source {
                        Source::Json => o.str("source", "json"),
                        Source::File(p) => o.str("source", "file").str("path", p),
                        Source::Ai1(task) => o.str("source", "ai1").str("task_id", task),
                    };
                    o.i64("received_ms", m.received_ms);
                });
            }
        });
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
        });
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
}
