//! The Flight Control and Mission Management commands: what the flight
//! model, the parameters and the mission bookkeeping do together.

use lluav_core::{Args, Command, CommandId as C, Fields, LandPoint, Number, Payload};

use super::Simulator;
use super::error::{SimError, SimResult};
use super::flight::{Leg, Mode, Then};
use super::mission::{Mission, Run, Source, Status};
use super::params::Key;
use crate::files::Files;
use crate::vehicle::Ned;
use crate::vehicle::envelope::Envelope;
use crate::vehicle::mission;

/// Largest mission or waypoint file a client may point at, bytes.
pub(super) const MAX_MISSION_FILE: u64 = 1 << 20;

/// A client's point, as the `f64` the model computes with.
fn ned(x: f32, y: f32, z: f32) -> Ned {
    Ned::new(f64::from(x), f64::from(y), f64::from(z))
}

impl Simulator {
    /// Where the vehicle may be sent now (DESIGN.md, "Flight authority").
    pub(super) fn envelope(&self) -> Envelope {
        Envelope {
            home: self.flight.home(),
            min_alt: self.params.f64(Key::MinAlt),
            max_alt: self.params.f64(Key::MaxAlt),
            radius: self.params.f64(Key::GeofenceRadius),
        }
    }

    /// The Flight Control commands (`tunnelfly` and `autosleep_enable` are
    /// switches, set in [`Simulator::run`]).
    pub(super) fn fly(&mut self, cmd: &Command<'_>, files: &Files, out: &mut Fields<'_>) -> SimResult {
        let lim = self.limits();
        match (cmd.id(), cmd.args()) {
            (C::Takeoff, _) => self.takeoff(files, out)?,
            (C::Land | C::TetherLand, _) => {
                self.flight.land(&lim)?;
                out.bool("tethered", cmd.id() == C::TetherLand);
            }
            (C::Rtl | C::Mrtl, _) => {
                let alt = self.flight.rtl(&lim, cmd.id() == C::Mrtl)?;
                out.object("home", |o| self.flight.home().write(o))
                    .f32("return_alt", alt as f32);
            }
            (C::SetSpNed, Args::Setpoint(p)) => {
                self.envelope()
                    .check(ned(p.x, p.y, p.z))
                    .map_err(SimError::outside)?;
                self.flight.track(ned(p.x, p.y, p.z), f64::from(p.yaw))?;
                self.write_setpoint(out);
                out.bool("tracking", true);
            }
            (C::Disarm, _) => {
                self.flight.disarm();
                out.bool("armed", false);
            }
            (C::Sleep, _) => {
                // The armed gate let it through: it is on the ground (or
                // asleep already), unless it falls.
                if *self.flight.mode() == Mode::Falling {
                    return Err(SimError::Falling);
                }
                self.flight.sleep();
            }
            (C::Wakeup, _) => {
                // Scripts send `wakeup; takeoff`: an awake vehicle is fine,
                // and the answer says which it was.
                out.bool("was_asleep", self.flight.wakeup());
            }
            (C::Zyhk, Args::Zyhk { heights, land }) => self.zyhk(heights, land.as_ref(), out)?,
            (C::RelocatePos, Args::Pose(p)) => self.relocate(ned(p.x, p.y, p.z), p.yaw, out)?,
            (id, _) => return Err(SimError::NotOwned(id.name())),
        }
        tracing::info!(
            cmd = cmd.id().name(),
            fsm = self.flight.mode().name(),
            "flight command"
        );
        out.str("fsm", self.flight.mode().name());
        Ok(())
    }

    fn takeoff(&mut self, files: &Files, out: &mut Fields<'_>) -> SimResult {
        self.check_takeoff()?;
        self.check_preflight(files)?;
        // Home is where the vehicle stands: the envelope from there.
        let alt = Envelope {
            home: self.flight.pos(),
            ..self.envelope()
        }
        .clip(self.params.f64(Key::TakeoffAlt));
        self.flight.takeoff(alt);
        out.f32("target_alt", alt as f32);
        Ok(())
    }

    /// Why the vehicle may not take off now, if it may not.
    fn check_takeoff(&self) -> SimResult {
        match self.flight.mode() {
            Mode::Sleep => return Err(SimError::Asleep),
            Mode::Falling => return Err(SimError::Falling),
            _ => {}
        }
        if !self.devices.powered() {
            return Err(SimError::PowerOff);
        }
        let low = self.params.f64(Key::LowBattery);
        if self.flight.battery() <= low {
            return Err(SimError::BatteryLow(self.flight.battery()));
        }
        Ok(())
    }

    /// Refuses takeoff when preflight checks are required and one fails.
    fn check_preflight(&self, files: &Files) -> SimResult {
        if !self.switches.preflight {
            return Ok(());
        }
        match self.preflight_checks(files).into_iter().find(|c| !c.ok) {
            Some(failed) => Err(SimError::Preflight(format!("{}: {}", failed.name, failed.detail))),
            None => Ok(()),
        }
    }

    /// Tells a vehicle on the ground where it is: at `z` 0, inside the
    /// fence.
    fn relocate(&mut self, pos: Ned, yaw: f32, out: &mut Fields<'_>) -> SimResult {
        if !self.switches.map_locate {
            return Err(SimError::MapLocateOff);
        }
        if *self.flight.mode() == Mode::Falling {
            return Err(SimError::Falling);
        }
        if pos.z != 0.0 {
            return Err(SimError::Refused(format!(
                "z {} is not on the ground: relocate_pos places a vehicle on the ground (z 0)",
                pos.z as f32
            )));
        }
        self.envelope().check_horizontal(pos).map_err(SimError::outside)?;
        self.flight.relocate(pos, f64::from(yaw));
        out.object("position", |o| pos.write(o)).f32("yaw", yaw);
        Ok(())
    }

    /// Climbs or descends to each height in turn, holds there, then lands
    /// (at the landing point, if given).
    fn zyhk(&mut self, heights: &[f32], land: Option<&LandPoint>, out: &mut Fields<'_>) -> SimResult {
        let (envelope, here) = (self.envelope(), self.flight.pos());
        let hold_s = self.params.f64(Key::ZyhkHover);
        let mut legs = Vec::with_capacity(heights.len() + 1);
        for &h in heights {
            if h <= 0.0 {
                // As DESIGN.md writes numbers: `-0` is 0.
                let h = Number::from(h);
                return Err(SimError::Refused(format!("zyhk height {h} must be above 0")));
            }
            let target = Ned::new(here.x, here.y, -f64::from(h));
            envelope.check(target).map_err(SimError::outside)?;
            legs.push(Leg {
                hold_s,
                ..Leg::to(target)
            });
        }
        if let (Some(lp), Some(&last)) = (land, heights.last()) {
            let target = ned(lp.x, lp.y, -last);
            envelope.check(target).map_err(SimError::outside)?;
            legs.push(Leg {
                yaw: Some(f64::from(lp.yaw)),
                ..Leg::to(target)
            });
        }
        self.flight.fly_route(legs, Then::Land, false)?;
        out.array("heights", |a| {
            heights.iter().for_each(|&h| {
                a.f32(h);
            })
        })
        .f64("hover_s", hold_s);
        Ok(())
    }

    /// The Mission Management commands.
    pub(super) fn mission(
        &mut self,
        cmd: &Command<'_>,
        now_ms: i64,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> SimResult {
        match cmd.args() {
            Args::Mission { ext_id, payload } => {
                let (text, source) = match payload {
                    Payload::Json(s) => ((*s).to_owned(), Source::Json),
                    Payload::Path(p) => (
                        files.read_mission_file(p, MAX_MISSION_FILE)?,
                        Source::File((*p).to_owned()),
                    ),
                };
                out.u64("ext_id", (*ext_id).into());
                self.submit(*ext_id, source, &text, now_ms, out)
            }
            Args::Ai1Mission { task_id, file } => {
                let text = files.read_mission_file(file, MAX_MISSION_FILE)?;
                out.str("task_id", task_id);
                self.submit(0, Source::Ai1((*task_id).to_owned()), &text, now_ms, out)
            }
            Args::MwExec { ext_id, wp_ids } => self.mw_exec(*ext_id, wp_ids, now_ms, out),
            &Args::OptCount(abort_id) if cmd.id() == C::AbortReport => self.abort(abort_id, now_ms, out),
            _ => self.missions.run(cmd, out),
        }
    }

    fn submit(
        &mut self,
        ext_id: u32,
        source: Source,
        text: &str,
        now_ms: i64,
        out: &mut Fields<'_>,
    ) -> SimResult {
        let waypoints = mission::parse(text, &self.envelope())?;
        out.u64("waypoints", waypoints.len() as u64);
        tracing::info!(source = ?source, ext_id, waypoints = waypoints.len(), "mission received");
        self.missions.submit(Mission {
            ext_id,
            source,
            waypoints,
            received_ms: now_ms,
        })
    }

    fn mw_exec(&mut self, ext_id: u32, wp_ids: &[u32], now_ms: i64, out: &mut Fields<'_>) -> SimResult {
        let waypoints = self.missions.select(ext_id, wp_ids)?;
        // Limits may have changed since the upload.
        let envelope = self.envelope();
        for w in &waypoints {
            envelope
                .check(w.ned())
                .map_err(|why| SimError::Refused(format!("waypoint {}: {why}", w.wp_id())))?;
        }
        let legs = waypoints
            .iter()
            .map(|w| Leg {
                yaw: w.yaw,
                wp: Some(w.wp_id()),
                ..Leg::to(w.ned())
            })
            .collect();
        let route = self.flight.fly_route(legs, Then::Hover, false)?;
        self.missions.apply(&self.flight.drain_events());
        self.missions.start_run(Run {
            ext_id,
            route,
            wp_ids: wp_ids.to_vec(),
            reached: Vec::new(),
            status: Status::Running,
            started_ms: now_ms,
        });
        tracing::info!(ext_id, waypoints = wp_ids.len(), "executing waypoints");
        out.u64("ext_id", ext_id.into())
            .array("wp_ids", |a| {
                wp_ids.iter().for_each(|&i| {
                    a.u64(i.into());
                })
            })
            .str("fsm", self.flight.mode().name());
        Ok(())
    }

    /// Ends the running waypoint run, if any (the vehicle holds where it
    /// is), and records the report.
    fn abort(&mut self, abort_id: Option<u32>, now_ms: i64, out: &mut Fields<'_>) -> SimResult {
        let report = self.missions.abort(abort_id, now_ms)?;
        if report.ext_id.is_some() && matches!(self.flight.mode(), Mode::Mission(_)) {
            // In the air by the check above, so holding cannot be refused.
            let _ = self.flight.track(self.flight.pos(), self.flight.yaw());
        }
        tracing::info!(
            abort_id = report.abort_id,
            aborted = report.ext_id.is_some(),
            "abort report"
        );
        out.object("abort_report", |o| report.write(o));
        Ok(())
    }
}
