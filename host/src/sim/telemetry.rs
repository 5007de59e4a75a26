//! The simulator's reports: `state`, `ver`, `sysinfo`, `statics`, `hud1`,
//! `lidarpose`, `mavlink_msgs`, `get_submap_info`, `show_sp`,
//! `show_apguid2` and `preflight_check`.

use std::path::Path;

use lluav_core::{Context, Fields, TABLE};

use super::devices::round1;
use super::error::{SimError, SimResult};
use super::fsm::{Mode, Ned};
use super::params::Key;
use super::{MACHINE_ID_FILE, Simulator, system};

/// Map keyframes are taken every this many metres flown.
const KEYFRAME_SPACING_M: f64 = 2.0;
/// Free space below which the disk preflight check fails, MiB.
const MIN_FREE_MB: u64 = 100;

/// Writes `x`, `y`, `z` members.
pub(super) fn write_ned(o: &mut Fields<'_>, p: Ned) {
    o.f64("x", p.x).f64("y", p.y).f64("z", p.z);
}

/// A simulated autopilot's 18-byte `uid2` as hex, stable per machine: an
/// FNV-1a stream seeded by the machine id.
pub(super) fn guid2() -> String {
    let seed = system::machine_id(Path::new(MACHINE_ID_FILE)).unwrap_or_else(|_| "lluav-sim".into());
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

/// One preflight check's outcome.
pub(super) struct Check {
    pub name: &'static str,
    pub ok: bool,
    pub detail: String,
}

impl Simulator {
    fn keyframes(&self) -> u64 {
        1 + (self.flight.distance_m / KEYFRAME_SPACING_M) as u64
    }

    pub(super) fn write_state(&self, ctx: &Context, out: &mut Fields<'_>) {
        let f = &self.flight;
        let (sp, sp_yaw) = f.setpoint();
        out.object("state", |s| {
            s.bool("armed", f.mode().armed())
                .str("fsm", f.mode().name())
                .bool("lock_mode", ctx.lock_mode)
                .bool("airborne", f.mode().airborne())
                .object("position", |o| write_ned(o, f.pos()))
                .object("velocity", |o| write_ned(o, f.vel()))
                .f64("yaw", f.yaw())
                .f64("altitude", f.pos().up())
                .f64("battery", round1(f.battery()))
                .object("setpoint", |o| {
                    write_ned(o, sp);
                    o.f64("yaw", sp_yaw);
                })
                .object("home", |o| write_ned(o, f.home()))
                .u64("waypoints_left", f.legs_left() as u64)
                .bool("plan_lock", self.missions.plan_locked)
                .bool("obs_mission", self.missions.obs_live)
                .bool("tunnelfly", self.dev.tunnelfly)
                .bool("map_locate", self.dev.map_locate)
                .bool("recording_bag", self.bag.is_some())
                .f64("sim_time_s", (self.sim_s * 1000.0).round() / 1000.0)
                .f64("sim_speed", self.speed);
            match &self.missions.taskname {
                Some(t) => s.str("taskname", t),
                None => s.null("taskname"),
            };
        });
    }

    pub(super) fn write_version(&self, out: &mut Fields<'_>) {
        out.object("version", |o| {
            o.str("lluav", env!("CARGO_PKG_VERSION"))
                .str("backend", "simulator")
                .u64("commands", TABLE.len() as u64)
                .str("os", std::env::consts::OS)
                .str("arch", std::env::consts::ARCH);
        });
    }

    pub(super) fn write_sysinfo(&self, out: &mut Fields<'_>) -> SimResult {
        let info = system::sysinfo().map_err(|e| SimError::io("sysinfo()", e))?;
        out.object("sysinfo", |o| {
            o.i64("uptime", info.uptime_s)
                .u64("ram_total_MB", info.ram_total_mb)
                .u64("ram_free_MB", info.ram_free_mb)
                .array("loads", |a| {
                    info.loads.iter().for_each(|&l| {
                        a.f64((l * 100.0).round() / 100.0);
                    })
                })
                .u64("procs", info.procs.into());
        });
        Ok(())
    }

    pub(super) fn write_statics(&self, out: &mut Fields<'_>) {
        let mav_total: u64 = self.mavlink_counts().iter().map(|(_, n)| n).sum();
        out.object("comm", |o| {
            o.u64("commands", self.commands)
                .bool("mavlink", true)
                .u64("mavlink_msgs", mav_total);
        });
        out.object("rosrecord", |o| {
            o.bool("recording", self.bag.is_some());
            match &self.bag {
                Some(b) => o.str("bag", &b.name).u64("buffered", b.samples.len() as u64),
                None => o.null("bag"),
            };
        });
        out.object("stat", |o| {
            o.u64("flights", self.flight.flights)
                .f64("armed_s", round1(self.flight.armed_s))
                .f64("distance_m", round1(self.flight.distance_m))
                .f64("sim_time_s", round1(self.sim_s));
        });
        out.u64("node_boot_sec", self.node_boot.elapsed().as_secs());
    }

    pub(super) fn write_hud1(&self, out: &mut Fields<'_>) {
        let p = self.flight.pos();
        let v = self.flight.vel();
        out.u64("kfs", self.keyframes());
        // ENU: x east, y north, z up.
        out.object("uav_pos_enu", |o| {
            o.f64("x", p.y).f64("y", p.x).f64("z", p.up());
        });
        out.object("extra", |o| {
            o.str("fsm", self.flight.mode().name())
                .f64("battery", round1(self.flight.battery()))
                .f64("yaw", self.flight.yaw())
                .f64("speed", (v.x * v.x + v.y * v.y + v.z * v.z).sqrt());
        });
    }

    pub(super) fn write_lidar_pose(&self, out: &mut Fields<'_>) {
        let p = self.flight.pos();
        let v = self.flight.vel();
        // A multirotor tilts into its motion: a small pitch/roll from velocity.
        let (pitch, roll) = (-0.02 * v.x, 0.02 * v.y);
        let frame = if self.dev.map_locate { "map" } else { "odom" };
        out.object("lidar_pose", |o| {
            write_ned(o, p);
            o.f64("yaw", self.flight.yaw())
                .f64("roll", roll)
                .f64("pitch", pitch)
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

    pub(super) fn write_mavlink(&self, out: &mut Fields<'_>) {
        let counts = self.mavlink_counts();
        out.object("mav_msgs", |o| {
            for (name, n) in counts {
                o.u64(name, n);
            }
        });
    }

    pub(super) fn write_submap(&self, out: &mut Fields<'_>) {
        let map = self.map_path.as_deref().unwrap_or("live");
        out.object("kfs", |o| {
            o.str("map_id", map).u64("count", self.keyframes());
        });
    }

    pub(super) fn write_setpoint(&self, out: &mut Fields<'_>) {
        let (sp, yaw) = self.flight.setpoint();
        out.object("sp", |o| {
            write_ned(o, sp);
            o.f64("yaw", yaw);
        })
        .bool("active", self.flight.mode().airborne());
    }

    pub(super) fn preflight_checks(&self) -> Vec<Check> {
        let battery = self.flight.battery();
        let low = self.params.f64(Key::LowBattery);
        let free_mb = system::available_bytes(self.data.root()).map(|b| b >> 20);
        vec![
            Check {
                name: "battery",
                ok: battery > low,
                detail: format!("{battery:.0}% (low_battery {low:.0}%)"),
            },
            Check {
                name: "lidar",
                ok: self.dev.lidar.on && self.dev.lidar.driver,
                detail: if self.dev.lidar.on && self.dev.lidar.driver {
                    "running".into()
                } else {
                    "off or driver stopped".into()
                },
            },
            Check {
                name: "awake",
                ok: self.flight.mode() != Mode::Sleep,
                detail: self.flight.mode().name().into(),
            },
            Check {
                name: "disk",
                ok: free_mb.as_ref().is_ok_and(|&mb| mb >= MIN_FREE_MB),
                detail: match free_mb {
                    Ok(mb) => format!("{mb} MB free"),
                    Err(e) => format!("statvfs failed: {e}"),
                },
            },
        ]
    }

    pub(super) fn write_preflight(&self, out: &mut Fields<'_>) {
        let checks = self.preflight_checks();
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
    }
}
