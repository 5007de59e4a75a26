//! The simulated vehicle: the default backend of `lluavd`.
//!
//! Every command of `lluav_core::TABLE` that reaches a backend is carried
//! out here against a simulated vehicle — an FSM with timed transitions
//! ([`fsm`]), missions ([`mission`]), typed parameters ([`params`]) and
//! simulated peripherals ([`devices`]) — or against the real machine where
//! the command is about the machine: `sysinfo`, `diskusage`, `machineid`,
//! and maps, images, bags, videos and logs as real files under the data
//! directory ([`files`]). Nothing here ever reboots or powers off the real
//! machine: those commands are simulated and logged.
//!
//! Time only moves through [`Simulator::tick`], scaled by
//! [`SimConfig::speed`], so tests drive it with simulated durations.

pub mod devices;
pub mod error;
pub mod files;
pub mod fsm;
pub mod mission;
pub mod params;
mod routes;
mod storage;
pub mod system;
mod telemetry;

use std::io;
use std::panic::{self, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use lluav_core::{Args, Backend, Command, CommandId, Context, Failure, Fields, Payload, Step};

use crate::recent_log::RecentLog;
use devices::{Devices, Target};
use error::{SimError, SimResult};
use files::{Area, DataDir, atomic_write};
use fsm::{Flight, Limits, Mode, Ned};
use mission::{Fence, Mission, Missions, Source};
use params::{Key, Params};

/// Largest mission or waypoint file a client may point at, bytes.
const MAX_MISSION_FILE: u64 = 1 << 20;
/// `showmsg` without a count shows this many lines.
const DEFAULT_SHOWMSG: usize = 50;
/// Where the machine id is read from.
const MACHINE_ID_FILE: &str = "/etc/machine-id";
/// File in the data directory holding the password `passwd` set.
const PASSWORD_FILE: &str = "password";
/// File in the data directory holding the saved parameters.
const PARAMS_FILE: &str = "params.json";

/// How to start a [`Simulator`].
#[derive(Clone, Debug)]
pub struct SimConfig {
    /// Where maps, images, bags, saved parameters and the password live.
    pub data_dir: PathBuf,
    /// Simulated seconds per wall-clock second.
    pub speed: f64,
    /// The daemon's recent log lines, for `showmsg`/`savemsg`.
    pub log: RecentLog,
}

/// A bag being recorded: poses sampled at every tick, appended to its file
/// when recording stops or the simulator is flushed.
#[derive(Debug)]
struct Bag {
    name: String,
    path: PathBuf,
    samples: Vec<String>,
}

/// Most pose samples a bag buffers before they are written out.
const BAG_BUFFER: usize = 10_000;

/// The simulated vehicle.
#[derive(Debug)]
pub struct Simulator {
    speed: f64,
    log: RecentLog,
    data: DataDir,
    params: Params,
    password: Option<String>,
    flight: Flight,
    missions: Missions,
    dev: Devices,
    sim_s: f64,
    node_boot: Instant,
    ap_boot_s: f64,
    commands: u64,
    bag: Option<Bag>,
    map_path: Option<String>,
    captures: u64,
    /// Makes the next command panic, to prove panics become ret -100.
    #[cfg(test)]
    inject_panic: bool,
}

impl Simulator {
    /// Creates the data directory and its subdirectories and loads the
    /// saved parameters and password.
    pub fn open(cfg: SimConfig) -> io::Result<Simulator> {
        if !(cfg.speed.is_finite() && cfg.speed > 0.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("simulation speed must be a positive number, got {}", cfg.speed),
            ));
        }
        let data = DataDir::open(&cfg.data_dir)?;
        let params = Params::load(data.root().join(PARAMS_FILE))?;
        let password = match std::fs::read_to_string(data.root().join(PASSWORD_FILE)) {
            Ok(p) if !p.is_empty() => Some(p),
            Ok(_) => None,
            Err(e) if e.kind() == io::ErrorKind::NotFound => None,
            Err(e) => return Err(e),
        };
        tracing::info!(data_dir = %data.root().display(), speed = cfg.speed, "simulator ready");
        Ok(Simulator {
            speed: cfg.speed,
            log: cfg.log,
            data,
            params,
            password,
            flight: Flight::default(),
            missions: Missions::default(),
            dev: Devices::default(),
            sim_s: 0.0,
            node_boot: Instant::now(),
            ap_boot_s: 0.0,
            commands: 0,
            bag: None,
            map_path: None,
            captures: 0,
            #[cfg(test)]
            inject_panic: false,
        })
    }

    /// Advances the simulation by wall time `dt` (simulated: `dt * speed`).
    pub fn tick(&mut self, dt: Duration) {
        let sim_dt = dt.as_secs_f64() * self.speed;
        let limits = self.limits();
        self.flight.advance(sim_dt, &limits);
        self.sim_s += sim_dt;
        self.missions.apply(&self.flight.drain_events());
        if let Some(bag) = self.bag.as_mut()
            && bag.samples.len() < BAG_BUFFER
        {
            let (p, yaw) = (self.flight.pos(), self.flight.yaw());
            bag.samples.push(format!(
                "{:.3} {:.3} {:.3} {:.3} {:.3} {}",
                self.sim_s,
                p.x,
                p.y,
                p.z,
                yaw,
                self.flight.mode().name()
            ));
        }
    }

    /// Persists whatever is pending: the recording bag's buffered samples.
    /// Parameters are persisted only by `save_param 1`, by design.
    pub fn flush(&mut self) -> io::Result<()> {
        match self.bag.as_mut() {
            Some(bag) => storage::append_samples(bag),
            None => Ok(()),
        }
    }

    /// The password an earlier `passwd` saved, if any.
    pub fn stored_password(&self) -> Option<String> {
        self.password.clone()
    }

    /// The FSM state.
    pub fn mode(&self) -> Mode {
        self.flight.mode()
    }

    /// Position, NED metres.
    pub fn position(&self) -> Ned {
        self.flight.pos()
    }

    /// The data directory (canonical).
    pub fn data_dir(&self) -> &Path {
        self.data.root()
    }

    fn limits(&self) -> Limits {
        let p = &self.params;
        Limits {
            cruise: p.f64(Key::CruiseSpeed),
            climb: p.f64(Key::ClimbSpeed),
            land: p.f64(Key::LandSpeed),
            yaw_rate: p.f64(Key::YawRate),
            accept: p.f64(Key::AcceptRadius),
            rtl_alt: p.f64(Key::RtlAlt),
            rtl_land: p.flag(Key::RtlLand),
            drain: p.f64(Key::BatteryDrain),
            low_battery: p.f64(Key::LowBattery),
            autosleep_after: self.dev.autosleep.then(|| p.f64(Key::AutosleepAfter)),
            charging: self.dev.bms.charging,
        }
    }

    fn fence(&self) -> Fence {
        Fence {
            home: self.flight.home(),
            radius: self.params.f64(Key::GeofenceRadius),
            max_alt: self.params.f64(Key::MaxAlt),
        }
    }

    /// Carries out one command. Dispatch is on the command id; the core
    /// has already checked the gates and the argument grammar.
    fn run(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> SimResult {
        use CommandId as C;
        self.commands += 1;
        #[cfg(test)]
        if std::mem::take(&mut self.inject_panic) {
            panic!("injected fault");
        }
        match (cmd.id(), cmd.args()) {
            // State & telemetry.
            (C::State, _) => self.write_state(ctx, out),
            (C::Param, _) => {
                out.object("param", |o| self.params.write_all(o));
            }
            (C::GetParam, Args::ParamName(name)) => {
                let (def, value) = self.params.get(name)?;
                out.object("param", |o| value.write(o, def.name));
                out.object("info", |o| {
                    o.str("type", def.default.type_name());
                    def.default.write(o, "default");
                    o.f64("min", def.min)
                        .f64("max", def.max)
                        .bool("unsaved", self.params.unsaved(def))
                        .str("doc", def.doc);
                });
            }
            (C::Ver, _) => self.write_version(out),
            (C::Sysinfo, _) => self.write_sysinfo(out)?,
            (C::Diskusage, _) => {
                let free =
                    system::available_bytes(self.data.root()).map_err(|e| SimError::io("statvfs()", e))?;
                out.u64("available_MB", free >> 20);
            }
            (C::Statics, _) => self.write_statics(out),
            (C::Machineid, _) => {
                let did = system::machine_id(Path::new(MACHINE_ID_FILE))
                    .map_err(|e| SimError::io(format!("read {MACHINE_ID_FILE}"), e))?;
                out.str("did", &did);
            }
            (C::Hud1, _) => self.write_hud1(out),
            (C::Lidarpose, _) => self.write_lidar_pose(out),
            (C::ApronState, _) => {
                let charging = self.dev.bms.charging && !self.flight.mode().armed();
                self.dev.apron.write(out, charging);
                out.bool("apron_comm", true);
            }
            (C::MavlinkMsgs, _) => self.write_mavlink(out),
            (C::GetSubmapInfo, _) => self.write_submap(out),
            (C::ShowSp, _) => self.write_setpoint(out),
            (C::ShowApguid2, _) => {
                out.str("guid2", &telemetry::guid2());
            }
            (C::Showmsg, &Args::OptCount(n)) => {
                let n = n.map_or(DEFAULT_SHOWMSG, |n| usize::try_from(n).unwrap_or(usize::MAX));
                let lines = self.log.recent(n);
                out.array("msgs", |a| {
                    lines.iter().for_each(|l| {
                        a.str(l);
                    })
                });
            }

            // Flight control.
            (C::Takeoff, _) => {
                self.check_takeoff()?;
                let alt = self.params.f64(Key::TakeoffAlt);
                self.flight.takeoff(alt);
                tracing::info!(altitude = alt, "takeoff");
                out.str("fsm", self.flight.mode().name()).f64("target_alt", alt);
            }
            (C::Land | C::TetherLand, _) => {
                self.flight.land();
                tracing::info!(tethered = cmd.id() == C::TetherLand, "land");
                out.str("fsm", self.flight.mode().name())
                    .bool("tethered", cmd.id() == C::TetherLand);
            }
            (C::Rtl | C::Mrtl, _) => {
                if !self.flight.mode().airborne() {
                    return Err(SimError::NotFlying);
                }
                let limits = self.limits();
                self.flight.rtl(&limits, cmd.id() == C::Mrtl);
                tracing::info!(retrace = cmd.id() == C::Mrtl, "return to launch");
                let home = self.flight.home();
                out.str("fsm", self.flight.mode().name()).object("home", |o| {
                    o.f64("x", home.x).f64("y", home.y).f64("z", home.z);
                });
            }
            (C::SetSpNed, Args::Setpoint(p)) => {
                let sp = Ned::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                self.fence().check(sp).map_err(SimError::OutsideFence)?;
                let tracking = self.flight.set_setpoint(sp, f64::from(p.yaw));
                self.write_setpoint(out);
                out.str("fsm", self.flight.mode().name())
                    .bool("tracking", tracking);
            }
            (C::Tunnelfly, &Args::Flag(on)) => {
                self.dev.tunnelfly = on;
                out.bool("tunnelfly", on);
            }
            (C::Disarm, _) => {
                self.flight.disarm();
                tracing::info!("disarmed");
                out.bool("armed", false).str("fsm", self.flight.mode().name());
            }
            (C::Sleep, _) => {
                if self.flight.sleep() {
                    tracing::info!("sleeping");
                }
                out.str("fsm", self.flight.mode().name());
            }
            (C::Wakeup, _) => {
                self.flight.wakeup();
                out.str("fsm", self.flight.mode().name());
            }
            (C::AutosleepEnable, &Args::Flag(on)) => {
                self.dev.autosleep = on;
                out.bool("autosleep", on);
            }
            (C::Zyhk, Args::Zyhk { heights, land }) => self.zyhk(heights, land.as_ref(), out)?,
            (C::RelocatePos, Args::Pose(p)) => {
                if !self.dev.map_locate {
                    return Err(SimError::MapLocateOff);
                }
                let pos = Ned::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                self.flight.relocate(pos, f64::from(p.yaw));
                out.object("position", |o| telemetry::write_ned(o, pos))
                    .f64("yaw", f64::from(p.yaw));
            }

            // Missions.
            (C::Mission, Args::Mission { ext_id, payload }) => {
                let text = self.mission_text(payload)?;
                let waypoints = mission::parse(&text, &self.fence())?;
                let source = match payload {
                    Payload::Json(_) => Source::Json,
                    Payload::Path(p) => Source::File((*p).to_owned()),
                };
                out.u64("ext_id", (*ext_id).into())
                    .u64("waypoints", waypoints.len() as u64);
                tracing::info!(ext_id, waypoints = waypoints.len(), "mission received");
                self.missions.submit(Mission {
                    ext_id: *ext_id,
                    source,
                    waypoints,
                    received_ms: unix_ms(),
                });
            }
            (C::Plan, Args::Text(plan)) => {
                if self.missions.plan_locked {
                    return Err(SimError::PlanLocked);
                }
                self.missions.plan = Some((*plan).to_owned());
                self.missions.plan_locked = true;
                tracing::info!(plan, "plan started");
                out.str("plan", plan).bool("plan_lock", true);
            }
            (C::UnlockPlan, _) => {
                self.missions.plan_locked = false;
                out.bool("plan_lock", false);
            }
            (C::MwList, _) => match self.missions.latest() {
                Some(m) => {
                    out.u64("ext_id", m.ext_id.into());
                    Missions::write_waypoints(m, out);
                }
                None => {
                    out.null("ext_id").array("waypoints", |_| {});
                }
            },
            (C::MwExec, Args::MwExec { ext_id, wp_ids }) => self.mw_exec(*ext_id, wp_ids, out)?,
            (C::Ai1Mission, Args::Ai1Mission { task_id, file }) => {
                let text = self.data.read_client_file(file, MAX_MISSION_FILE)?;
                let waypoints = mission::parse(&text, &self.fence())?;
                out.str("task_id", task_id)
                    .u64("waypoints", waypoints.len() as u64);
                self.missions.submit(Mission {
                    ext_id: 0,
                    source: Source::Ai1((*task_id).to_owned()),
                    waypoints,
                    received_ms: unix_ms(),
                });
            }
            (C::ObsMission, &Args::Flag(on)) => {
                self.missions.obs_live = on;
                out.bool("obs_mission", on);
            }
            (C::DumpMissionresult, &Args::OptCount(ext_id)) => self.missions.write_result(ext_id, out)?,
            (C::DumpMissionlist, _) => self.missions.write_list(out),
            (C::AbortReport, &Args::OptCount(abort_id)) => {
                let report = self.missions.abort(abort_id, unix_ms());
                if report.ext_id.is_some() && self.flight.mode() == Mode::Mission {
                    let pos = self.flight.pos();
                    self.flight.set_setpoint(pos, self.flight.yaw());
                }
                tracing::info!(
                    abort_id = report.abort_id,
                    aborted = report.ext_id.is_some(),
                    "abort report"
                );
                out.object("abort_report", |o| report.write(o));
            }
            (C::SetTaskname, Args::Text(name)) => {
                self.missions.taskname = Some((*name).to_owned());
                out.str("taskname", name);
            }

            // Maps.
            (C::Savemap, Args::Name(name)) => self.save_map(name, out)?,
            (C::SetMaplocate, &Args::Flag(on)) => {
                self.dev.map_locate = on;
                out.bool("map_locate", on);
            }
            (C::SetMappath, Args::Path(path)) => self.set_map_path(path, out)?,
            (C::ListMaps, _) => self.list_maps(out)?,
            (C::RmMap, Args::Name(name)) => self.remove_map(name, out)?,

            // Camera and recording.
            (C::Capture, _) => self.capture(out)?,
            (C::Snapshot, _) => self.snapshot(out)?,
            (C::Record, _) => {
                let stored = self.dev.siyi.toggle_record();
                out.bool("recording", self.dev.siyi.recording);
                if let Some(vid) = stored {
                    out.u64("vid", vid.into());
                }
            }
            (C::Savebag, &Args::Flag(on)) => self.savebag(on, out)?,
            (C::SiyiReboot, _) => {
                self.dev.siyi.reboots += 1;
                self.dev.siyi.recording = false;
                self.dev.siyi.write(out);
            }
            (C::SiyiFormat, _) => {
                let erased = self.dev.siyi.videos.len();
                self.dev.siyi.videos.clear();
                self.dev.siyi.recording = false;
                out.u64("erased", erased as u64);
                self.dev.siyi.write(out);
            }
            (C::SiyiCenter, _) => {
                self.dev.siyi.centered = true;
                self.dev.siyi.write(out);
            }
            (C::SiyiInit, _) => {
                self.dev.siyi.hdmi = false;
                self.dev.siyi.write(out);
            }
            (C::SiyiDownvideo, &Args::OptCount(vid)) => self.download_video(vid, out)?,
            (C::SiyiSync, _) => {
                self.dev.siyi.syncs += 1;
                self.dev.siyi.write(out);
            }

            // LED.
            (C::Ledon, _) => {
                self.dev.led.require_enabled()?;
                self.dev.led.on = true;
                self.dev.led.blink = false;
                self.dev.led.write(out);
            }
            (C::Ledoff, _) => {
                self.dev.led.require_enabled()?;
                self.dev.led.on = false;
                self.dev.led.blink = false;
                self.dev.led.write(out);
            }
            (C::Ledenable | C::Leddisable, _) => {
                let enable = cmd.id() == C::Ledenable;
                self.dev.led.enabled = enable;
                if !enable {
                    self.dev.led.on = false;
                    self.dev.led.blink = false;
                }
                self.dev.led.write(out);
            }
            (C::Ledpwm, &Args::Pwm(pwm)) => {
                self.dev.led.require_enabled()?;
                self.dev.led.pwm = pwm;
                self.dev.led.on = pwm > 0;
                self.dev.led.write(out);
            }
            (C::LedBlink, _) => {
                self.dev.led.require_enabled()?;
                self.dev.led.on = true;
                self.dev.led.blink = true;
                self.dev.led.write(out);
            }

            // Parameters.
            (C::SetParam, Args::SetParam { name, value }) => {
                let v = self.params.set(name, value)?;
                tracing::info!(param = name, value, "parameter set");
                out.object("param", |o| v.write(o, name)).bool("unsaved", true);
            }
            (C::ResetParam, _) => {
                self.params.reset();
                tracing::info!("parameters reset to defaults (unsaved)");
                out.object("param", |o| self.params.write_all(o));
            }
            (C::SaveParam, &Args::Flag(true)) => {
                self.params
                    .save()
                    .map_err(|e| SimError::io("save parameters", e))?;
                tracing::info!("parameters saved");
                out.bool("saved", true).str("file", PARAMS_FILE);
            }
            (C::SaveParam, &Args::Flag(false)) => {
                let n = self
                    .params
                    .discard()
                    .map_err(|e| SimError::io("reload parameters", e))?;
                out.bool("saved", false).u64("discarded", n as u64);
            }

            // Apron.
            (C::ApronVol, &Args::Amount(v)) => {
                self.dev.apron.set_voltage(v)?;
                self.dev.apron.write(out, self.dev.bms.charging);
            }
            (C::ApronAmp, &Args::Amount(a)) => {
                self.dev.apron.set_current(a)?;
                self.dev.apron.write(out, self.dev.bms.charging);
            }

            // System management: all simulated.
            (C::RebootNode, _) => {
                self.node_boot = Instant::now();
                self.dev.restart(Target::Node, out);
            }
            (C::RebootAp, _) => {
                self.ap_boot_s = self.sim_s;
                self.dev.restart(Target::Autopilot, out);
            }
            (C::RebootSystem, _) => {
                self.flush().map_err(|e| SimError::io("flush before reboot", e))?;
                self.node_boot = Instant::now();
                self.ap_boot_s = self.sim_s;
                self.dev.restart(Target::System, out);
            }
            (C::PoweroffSystem, _) => {
                self.flush()
                    .map_err(|e| SimError::io("flush before power-off", e))?;
                self.dev.poweroff_requested = true;
                tracing::warn!("simulated power-off requested (the real machine is untouched)");
                out.object("poweroff", |o| {
                    o.bool("simulated", true);
                });
            }
            (C::PreparePoweroff, _) => {
                self.flush().map_err(|e| SimError::io("flush", e))?;
                let (file, count) = self.save_messages()?;
                out.bool("prepared", true)
                    .str("file", &file)
                    .u64("count", count as u64);
            }
            (C::RebootDlo, _) => self.dev.restart(Target::Dlo, out),
            (C::RestartDlo, _) => self.dev.restart(Target::DloPipeline, out),
            (C::KillLivox, Args::OptName(script)) => {
                self.dev.lidar.driver = false;
                self.dev.lidar.last_kill_script = script.map(str::to_owned);
                tracing::info!(script = script.unwrap_or("-"), "livox driver killed");
                self.dev.lidar.write(out);
            }

            // Lidar and perception.
            (C::Lidaronoff, &Args::Flag(on)) => {
                self.dev.lidar.on = on;
                self.dev.lidar.driver = on;
                self.dev.lidar.write(out);
            }
            (C::Lidarwarn, _) => {
                let altitude = self.flight.pos().up();
                self.dev
                    .lidar
                    .write_warnings(out, altitude, self.flight.mode().airborne());
            }
            (C::UtgGet, _) => {
                self.dev.utg.reads += 1;
                self.dev.utg.write(out);
            }
            (C::UtgSet, &Args::Amount(speed)) => {
                self.dev.utg.set_speed(speed)?;
                self.dev.utg.write(out);
            }

            // Other.
            (C::GrabberCtrl, &Args::Pwm(pwm)) => {
                self.dev.grabber_pwm = pwm;
                self.dev.write_grabber(out);
            }
            (C::Ara8Center, _) => {
                self.dev.ara8.centered = true;
                self.dev.ara8.pitch = 0.0;
                self.dev.ara8.write(out);
            }
            (C::Ara8Pitch, &Args::Angle(pitch)) => {
                self.dev.ara8.centered = false;
                self.dev.ara8.pitch = pitch;
                self.dev.ara8.write(out);
            }
            (C::CvTest, _) => {
                self.dev.cv_tests += 1;
                let frames = self.captures;
                out.object("cv_test", |o| {
                    o.bool("ok", true)
                        .u64("run", self.dev.cv_tests.into())
                        .u64("frames", frames);
                });
            }
            (C::PreflightCheck, _) => self.write_preflight(out),
            (C::PreflightEnable, &Args::Flag(on)) => {
                self.dev.preflight = on;
                out.bool("preflight_enabled", on);
            }
            (C::ClearBags, &Args::OptAmount(min_gb)) => self.clear(Area::Bags, min_gb, out)?,
            (C::ClearImages, &Args::OptAmount(min_gb)) => self.clear(Area::Images, min_gb, out)?,
            (C::ListImagedir, &Args::OptCount(size)) => self.list_imagedirs(size, out)?,
            (C::RmImagedir, Args::Name(name)) => self.remove_imagedir(name, out)?,
            (C::TestWp, Args::Point(p)) => {
                let target = Ned::new(f64::from(p.x), f64::from(p.y), f64::from(p.z));
                let verdict = self.fence().check(target);
                let here = self.flight.pos();
                let dist =
                    ((target.x - here.x).powi(2) + (target.y - here.y).powi(2) + (target.z - here.z).powi(2))
                        .sqrt();
                out.bool("reachable", verdict.is_ok())
                    .f64("distance_m", devices::round1(dist))
                    .f64("eta_s", devices::round1(dist / self.params.f64(Key::CruiseSpeed)));
                if let Err(why) = verdict {
                    out.str("reason", &why);
                }
            }
            (C::TestListwp, Args::Path(path)) => self.test_waypoint_file(path, out)?,
            (C::TestNotif, _) => {
                self.dev.notifications += 1;
                tracing::info!(seq = self.dev.notifications, "test notification");
                out.object("notif", |o| {
                    o.bool("sent", true).u64("seq", self.dev.notifications.into());
                });
            }
            (C::Savemsg, _) => {
                let (file, count) = self.save_messages()?;
                out.str("file", &file).u64("count", count as u64);
            }
            (C::BmsSetpower, &Args::Flag(on)) => {
                self.dev.bms.power = on;
                self.dev.bms.write(out, self.flight.battery());
            }
            (C::BmsSetcharge, &Args::Flag(on)) => {
                self.dev.bms.charging = on;
                self.dev.bms.write(out, self.flight.battery());
            }

            // The core answers these itself (`passwd` reaches
            // `password_changed` instead).
            (id, _) => return Err(SimError::NotBackend(id.name())),
        }
        Ok(())
    }
}

impl Backend for Simulator {
    fn armed(&self) -> bool {
        self.flight.mode().armed()
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let result = panic::catch_unwind(AssertUnwindSafe(|| {
            let r = self.run(cmd, ctx, out);
            // Commands such as set_sp_ned or land end routes: settle the
            // mission bookkeeping before the next command looks at it.
            let events = self.flight.drain_events();
            self.missions.apply(&events);
            r
        }));
        match result {
            Ok(Ok(())) => Ok(Step::Done),
            Ok(Err(e)) => {
                tracing::debug!(cmd = cmd.id().name(), error = %e, "command failed");
                Err(e.to_failure())
            }
            Err(_) => {
                tracing::error!(cmd = cmd.id().name(), "simulator panicked; answered as unhandled");
                Err(Failure::unhandled())
            }
        }
    }

    fn password_changed(&mut self, new: &str) -> Result<(), Failure> {
        let file = self.data.root().join(PASSWORD_FILE);
        atomic_write(&file, new.as_bytes(), 0o600).map_err(|e| {
            tracing::error!(error = %e, "could not save the password");
            SimError::io("save password", e).to_failure()
        })?;
        self.password = Some(new.to_owned());
        tracing::info!("password changed");
        Ok(())
    }
}

/// Now, in milliseconds since the Unix epoch.
fn unix_ms() -> i64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| i64::try_from(d.as_millis()).unwrap_or(i64::MAX))
}

#[cfg(test)]
mod tests {
    use super::*;
    use lluav_core::{Auth, Message, Outcome, Server, Session};

    #[test]
    fn a_panic_in_a_command_is_answered_as_unhandled_and_the_vehicle_carries_on() {
        let dir = tempfile::tempdir().unwrap();
        let sim = Simulator::open(SimConfig {
            data_dir: dir.path().to_path_buf(),
            speed: 1.0,
            log: RecentLog::new(8),
        })
        .unwrap();
        let mut server = Server::new(sim, || 7, Auth::new(None).unwrap());
        let mut session = Session::new();
        let mut out = [0u8; 4096];
        server.backend_mut().inject_panic = true;
        assert_eq!(
            server.handle(&mut session, Message::Text(b"state"), &mut out),
            Outcome::Reply(r#"{"ret":-100,"cmd":2,"ts":7,"msg":"Unhandled exception"}"#)
        );
        let Outcome::Reply(r) = server.handle(&mut session, Message::Text(b"ver"), &mut out) else {
            panic!("no reply");
        };
        assert!(r.starts_with(r#"{"ret":0,"cmd":5,"#), "{r}");
    }

    #[test]
    fn a_speed_that_is_not_a_positive_number_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        for speed in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            let cfg = SimConfig {
                data_dir: dir.path().to_path_buf(),
                speed,
                log: RecentLog::new(8),
            };
            assert!(Simulator::open(cfg).is_err(), "{speed}");
        }
    }
}
