//! Flight commands that need more than one FSM call: the takeoff checks,
//! `zyhk`'s hover-then-land route, `mw_exec`'s waypoint runs, and reading
//! mission payloads.

use lluav_core::{Fields, LandPoint, Payload};

use super::error::{SimError, SimResult};
use super::fsm::{Leg, Mode, Ned, Then};
use super::mission::{Run, Status};
use super::params::Key;
use super::{MAX_MISSION_FILE, Simulator, unix_ms};

impl Simulator {
    /// Why the vehicle may not take off now, if it may not.
    pub(super) fn check_takeoff(&self) -> SimResult {
        if self.flight.mode() == Mode::Sleep {
            return Err(SimError::Asleep);
        }
        let low = self.params.f64(Key::LowBattery);
        if self.flight.battery() <= low {
            return Err(SimError::BatteryLow(self.flight.battery()));
        }
        if self.dev.preflight
            && let Some(failed) = self.preflight_checks().into_iter().find(|c| !c.ok)
        {
            return Err(SimError::Preflight(format!("{}: {}", failed.name, failed.detail)));
        }
        Ok(())
    }

    pub(super) fn mission_text(&self, payload: &Payload<'_>) -> SimResult<String> {
        match payload {
            Payload::Json(s) => Ok((*s).to_owned()),
            Payload::Path(p) => self.data.read_client_file(p, MAX_MISSION_FILE),
        }
    }

    pub(super) fn zyhk(
        &mut self,
        heights: &[f32],
        land: Option<&LandPoint>,
        out: &mut Fields<'_>,
    ) -> SimResult {
        let fence = self.fence();
        let here = self.flight.pos();
        for &h in heights {
            if h <= 0.0 {
                return Err(SimError::OutsideFence(format!("zyhk height {h} must be above 0")));
            }
            fence
                .check(Ned::new(here.x, here.y, -f64::from(h)))
                .map_err(SimError::OutsideFence)?;
        }
        if !self.flight.mode().airborne() {
            self.check_takeoff()?;
            let first = heights.first().copied().map_or(1.0, f64::from);
            self.flight.takeoff(first);
        }
        let hold = self.params.f64(Key::ZyhkHover);
        let (x, y) = (here.x, here.y);
        let mut legs: Vec<Leg> = heights
            .iter()
            .map(|&h| Leg {
                target: Ned::new(x, y, -f64::from(h)),
                yaw: None,
                hold_s: hold,
                wp: None,
            })
            .collect();
        if let Some(lp) = land {
            let last = heights.last().copied().map_or(1.0, f64::from);
            let target = Ned::new(f64::from(lp.x), f64::from(lp.y), -last);
            fence.check(target).map_err(SimError::OutsideFence)?;
            legs.push(Leg {
                target,
                yaw: Some(f64::from(lp.yaw)),
                hold_s: 0.0,
                wp: None,
            });
        }
        self.flight.fly_route(legs, Then::Land, Mode::Mission);
        tracing::info!(
            heights = heights.len(),
            "zyhk: hovering at each height, then landing"
        );
        out.str("fsm", self.flight.mode().name())
            .array("heights", |a| {
                heights.iter().for_each(|&h| {
                    a.f32(h);
                })
            })
            .f64("hover_s", hold);
        Ok(())
    }

    pub(super) fn mw_exec(&mut self, ext_id: u32, wp_ids: &[u32], out: &mut Fields<'_>) -> SimResult {
        let waypoints = self.missions.select(ext_id, wp_ids)?;
        if !self.flight.mode().airborne() {
            return Err(SimError::NotFlying);
        }
        let legs = waypoints
            .iter()
            .map(|w| Leg {
                target: w.ned(),
                yaw: w.yaw,
                hold_s: 0.0,
                wp: Some(w.wp_id()),
            })
            .collect();
        let route = self.flight.fly_route(legs, Then::Hover, Mode::Mission);
        self.missions.apply(&self.flight.drain_events());
        self.missions.start_run(Run {
            ext_id,
            route,
            wp_ids: wp_ids.to_vec(),
            reached: Vec::new(),
            status: Status::Running,
            started_ms: unix_ms(),
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
}
