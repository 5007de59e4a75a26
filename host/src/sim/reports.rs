//! The simulated vehicle's reports: its members of `state`, `statics` and
//! `hud1`; `lidarpose`, `mavlink_msgs`, `show_sp`, `show_apguid2`,
//! `preflight_check`, `test_wp` and `test_listwp`. Coordinates and angles
//! are written as `f32` (DESIGN.md, "Numbers in responses").

use lluav_core::{Args, Command, CommandId as C, Context, Fields};

use super::Simulator;
use super::devices::{Airframe, round1};
use super::error::{SimError, SimResult};
use super::flight::{Mode, altitude, distance};
use super::params::Key;
use super::pilot::MAX_MISSION_FILE;
use crate::files::Files;
use crate::vehicle::Ned;
use crate::vehicle::envelope::{Envelope, Outside};
use crate::vehicle::mission;

/// Free space below which the disk preflight check fails, MiB.
const MIN_FREE_MB: u64 = 100;

/// One preflight check's outcome.
pub(super) struct Check {
    pub(super) name: &'static str,
    pub(super) ok: bool,
    pub(super) detail: String,
}

impl Simulator {
    pub(super) fn airframe(&self) -> Airframe {
        Airframe {
            altitude: altitude(self.flight.pos()),
            airborne: self.flight.mode().airborne(),
            armed: self.flight.mode().armed(),
            battery: self.flight.battery(),
        }
    }

    /// The State & Telemetry reports the vehicle owns.
    pub(super) fn report(&self, id: C, out: &mut Fields<'_>) -> SimResult {
        match id {
            C::Statics => self.write_statics(out),
            C::Hud1 => self.write_hud1(out),
            C::Lidarpose => self.write_lidar_pose(out),
            C::MavlinkMsgs => {
                let counts = self.mavlink_counts();
                out.object("mav_msgs", |o| {
                    for (name, n) in counts {
                        o.u64(name, n);
                    }
                });
            }
            C::ShowSp => self.write_setpoint(out),
            C::ShowApguid2 => {
                out.str("guid2", &guid2(&self.seed));
            }
            id => return Err(SimError::NotOwned(id.name())),
        }
        Ok(())
    }

    /// The vehicle's members of `state` (see [`crate::onboard`]).
    pub(super) fn write_state_fields(&self, ctx: &Context, s: &mut Fields<'_>) {
        let f = &self.flight;
        let (sp, sp_yaw) = f.setpoint();
        s.bool("armed", f.mode().armed())
            .str("fsm", f.mode().name())
            .bool("lock_mode", ctx.lock_mode)
            .bool("airborne", f.mode().airborne())
            .object("position", |o| f.pos().write(o))
            .object("velocity", |o| f.vel().write(o))
            .f32("yaw", f.yaw() as f32)
            .f32("altitude", altitude(f.pos()) as f32)
            .f32("battery", battery_level(f.battery()))
            .object("setpoint", |o| {
                sp.write(o);
                o.f32("yaw", sp_yaw as f32);
            })
            .object("home", |o| f.home().write(o))
            .u64("waypoints_left", f.legs_left() as u64)
            .bool("tunnelfly", self.switches.tunnelfly)
            .bool("map_locate", self.switches.map_locate)
            .f64("sim_time_s", (self.sim_s * 1000.0).round() / 1000.0)
            .f64("sim_speed", self.speed);
        self.missions.write_state(s);
    }

    fn write_statics(&self, out: &mut Fields<'_>) {
        let mav_total: u64 = self.mavlink_counts().iter().map(|(_, n)| n).sum();
        let totals = self.flight.totals();
        out.object("comm", |o| {
            o.bool("mavlink", true).u64("mavlink_msgs", mav_total);
        });
        out.object("stat", |o| {
            o.u64("flights", totals.flights)
                .f64("armed_s", round1(totals.armed_s))
                .f64("distance_m", round1(totals.distance_m))
                .f64("sim_time_s", round1(self.sim_s));
        });
    }

    fn write_hud1(&self, out: &mut Fields<'_>) {
        let (p, v) = (self.flight.pos(), self.flight.vel());
        // ENU: x east, y north, z up.
        out.object("uav_pos_enu", |o| {
            Ned::new(p.y, p.x, altitude(p)).write(o);
        });
        out.object("extra", |o| {
            o.str("fsm", self.flight.mode().name())
                .f64("battery", round1(self.flight.battery()))
                .f32("yaw", self.flight.yaw() as f32)
                .f32("speed", distance(v, Ned::default()) as f32);
        });
    }

    fn write_lidar_pose(&self, out: &mut Fields<'_>) {
        let v = self.flight.vel();
        // A multirotor tilts into its motion: a small pitch/roll from velocity.
        let (pitch, roll) = (-0.02 * v.x, 0.02 * v.y);
        let frame = if self.switches.map_locate { "map" } else { "odom" };
        out.object("lidar_pose", |o| {
            self.flight.pos().write(o);
            o.f32("yaw", self.flight.yaw() as f32)
                .f32("roll", roll as f32)
                .f32("pitch", pitch as f32)
                .str("frame", frame)
                .u64("usec", (self.sim_s * 1e6) as u64);
        });
    }

    fn mavlink_counts(&self) -> [(&'static str, u64); 5] {
        let t = (self.sim_s - self.ap_boot_s).max(0.0);
        let at = |hz: f64| (t * hz) as u64;
        [
            ("HEARTBEAT", at(1.0)),
            ("SYS_STATUS", at(2.0)),
            ("ATTITUDE", at(self.params.f64(Key::MavlinkRate))),
            ("LOCAL_POSITION_NED", at(30.0)),
            ("BATTERY_STATUS", at(1.0)),
        ]
    }

    /// Writes `sp` (the setpoint the vehicle tracks) and `active`.
    pub(super) fn write_setpoint(&self, out: &mut Fields<'_>) {
        let (sp, yaw) = self.flight.setpoint();
        out.object("sp", |o| {
            sp.write(o);
            o.f32("yaw", yaw as f32);
        })
        .bool("active", self.flight.mode().flying());
    }

    pub(super) fn preflight_checks(&self, files: &Files) -> Vec<Check> {
        let battery = self.flight.battery();
        let low = self.params.f64(Key::LowBattery);
        let lidar = self.devices.lidar_running();
        let free_mb = files.free_bytes().map(|b| b >> 20);
        let mode = self.flight.mode();
        vec![
            Check {
                name: "battery",
                ok: battery > low,
                detail: format!("{battery:.0}% (low_battery {low:.0}%)"),
            },
            Check {
                name: "lidar",
                ok: lidar,
                detail: if lidar { "running" } else { "off or driver stopped" }.into(),
            },
            Check {
                name: "awake",
                ok: *mode != Mode::Sleep,
                detail: mode.name().into(),
            },
            Check {
                name: "disk",
                ok: free_mb.as_ref().is_ok_and(|&mb| mb >= MIN_FREE_MB),
                detail: match free_mb {
                    Ok(mb) => format!("{mb} MB free"),
                    Err(e) => e.to_string(),
                },
            },
        ]
    }

    pub(super) fn write_preflight(&self, files: &Files, out: &mut Fields<'_>) -> SimResult {
        let checks = self.preflight_checks(files);
        out.object("preflight", |o| {
            o.bool("passed", checks.iter().all(|c| c.ok))
                .array("checks", |a| {
                    for c in &checks {
                        a.object(|o| {
                            o.str("name", c.name).bool("ok", c.ok).str("detail", &c.detail);
                        });
                    }
                });
        });
        Ok(())
    }

    /// `test_wp` (one point) and `test_listwp` (every waypoint of a mission
    /// file) against the fence.
    pub(super) fn test_waypoints(&self, cmd: &Command<'_>, files: &Files, out: &mut Fields<'_>) -> SimResult {
        let envelope = self.envelope();
        match cmd.args() {
            Args::Point(p) => {
                let target = Ned::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                let verdict = envelope.check(target);
                let dist = distance(target, self.flight.pos());
                out.bool("reachable", verdict.is_ok())
                    .f64("distance_m", round1(dist))
                    .f64("eta_s", round1(dist / self.params.f64(Key::CruiseSpeed)));
                if let Err(why) = verdict {
                    out.str("reason", &why.to_string());
                }
            }
            Args::Path(path) => {
                let text = files.read_mission_file(path, MAX_MISSION_FILE)?;
                let verdicts: Vec<_> = mission::parse(&text, &Envelope::NONE)?
                    .iter()
                    .map(|w| (w.wp_id(), envelope.check(w.ned())))
                    .collect();
                write_verdicts(&verdicts, out);
            }
            _ => return Err(SimError::NotOwned(cmd.id().name())),
        }
        Ok(())
    }
}

fn write_verdicts(verdicts: &[(u32, Result<(), Outside>)], out: &mut Fields<'_>) {
    out.bool("reachable", verdicts.iter().all(|(_, v)| v.is_ok()))
        .array("waypoints", |a| {
            for (id, verdict) in verdicts {
                a.object(|o| {
                    o.u64("id", (*id).into()).bool("reachable", verdict.is_ok());
                    if let Err(why) = verdict {
                        o.str("reason", &why.to_string());
                    }
                });
            }
        });
}

/// A simulated autopilot's 18-byte `uid2` as hex, stable per seed: an
/// FNV-1a stream.
fn guid2(seed: &str) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut out = String::with_capacity(36);
    for i in 0..18u8 {
        for b in seed.bytes().chain([i]) {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
        out.push_str(&format!("{:02x}", (h >> 56) as u8));
    }
    out
}

/// The battery level as `state` writes it: one decimal of 0-100 % has at
/// most four significant digits, so its `f32` prints exactly the text its
/// `f64` would (every level, in the test below), and an `f32` costs a
/// fraction of an `f64` to print: `state` is the command clients poll.
fn battery_level(battery: f64) -> f32 {
    round1(battery) as f32
}

#[cfg(test)]
mod tests {
    use lluav_core::{Auth, Backend, Failure, Message, Outcome, Server, Step};

    use super::*;

    /// Writes one level both ways.
    struct Level(f64);

    impl Backend for Level {
        fn armed(&self) -> bool {
            false
        }

        fn execute(&mut self, _: &Command<'_>, _: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
            out.f64("f64", round1(self.0)).f32("f32", battery_level(self.0));
            Ok(Step::Done)
        }
    }

    #[test]
    fn every_battery_level_prints_the_same_as_f32_as_it_did_as_f64() {
        let levels = (0..=1000).map(|tenths| f64::from(tenths) / 10.0);
        for level in levels.chain([-0.0, 0.04, 99.96, 33.333, 66.666]) {
            let mut server = Server::new(Level(level), || 7, Auth::new(None).expect("no password"));
            let mut session = server.open(None);
            let mut out = [0u8; 256];
            let Outcome::Reply(reply) = server.handle(&mut session, Message::Text(b"state"), &mut out) else {
                panic!("no reply for {level}");
            };
            let value = |key: &str| {
                let from = reply.find(key).map(|i| i + key.len()).expect("written");
                let rest = reply.get(from..).unwrap_or_default();
                rest.split([',', '}']).next().unwrap_or_default().to_owned()
            };
            let (as_f64, as_f32) = (value(r#""f64":"#), value(r#""f32":"#));
            assert!(as_f64.parse::<f64>().is_ok(), "{level}: {reply}");
            assert_eq!(as_f32, as_f64, "{level}: {reply}");
        }
    }
}
