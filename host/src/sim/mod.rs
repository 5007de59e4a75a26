//! The simulated vehicle: `lluavd`'s default [`Vehicle`].
//!
//! The commands [`crate::onboard`] routes to the vehicle are carried out
//! here against a simulated vehicle: an FSM with timed transitions
//! (`flight`: the modes carry their own data), missions (`mission`),
//! the autopilot's typed parameters (`params`), and simulated peripherals
//! (`devices`, `camera`). `Simulator::run` hands each command to the
//! subsystem that owns its section of the command table.
//!
//! Only `takeoff` leaves the ground: every other command that moves the
//! vehicle (`land`, `tether_land`, `rtl`, `mrtl`, `set_sp_ned`, `zyhk`,
//! `mw_exec`) answers -1 `Vehicle is not flying` on the ground and changes
//! nothing.
//!
//! Time only moves through [`Simulator::tick`], scaled by
//! [`SimConfig::speed`]; a request's time is [`Context::now_ms`]. Nothing
//! here reads a clock.

mod camera;
mod devices;
mod error;
mod flight;
mod mission;
mod params;
mod pilot;
mod reports;

use std::io;
use std::path::PathBuf;
use std::time::Duration;

use lluav_core::{Command, CommandId, Context, Failure, Fields, Section};

use crate::events::Event;
use crate::files::{Files, Saved};
use crate::vehicle::{Progress, Refusal, Snapshot, TICK, Vehicle};
use camera::Camera;
use devices::Devices;
use error::{SimError, SimResult};
use flight::{Flight, Limits};
use mission::Missions;
use params::{Key, PARAMS_FILE, Params};

/// How to start a [`Simulator`].
#[derive(Clone, Debug)]
pub struct SimConfig {
    /// The data directory, where `save_param 1` keeps the parameters.
    pub data_dir: PathBuf,
    /// Simulated seconds per wall-clock second.
    pub speed: f64,
    /// A stable per-machine seed for the simulated autopilot's id
    /// (`show_apguid2`), e.g. the machine id.
    pub seed: String,
}

/// File in the data directory holding what [`Kept`] keeps.
const STATE_FILE: &str = "sim_state.json";

/// What the simulated vehicle keeps across a restart, besides parameters.
#[derive(Clone, Debug, Default, serde::Deserialize, serde::Serialize)]
#[serde(default)]
struct Kept {
    /// Map localisation (`set_maplocate`).
    map_locate: bool,
}

/// Switches the vehicle's commands turn on and off.
#[derive(Clone, Copy, Debug, Default)]
struct Switches {
    tunnelfly: bool,
    autosleep: bool,
    preflight: bool,
    map_locate: bool,
}

/// The simulated vehicle.
#[derive(Debug)]
pub struct Simulator {
    speed: f64,
    seed: String,
    /// Simulated time since start, s.
    sim_s: f64,
    /// Simulated time of the autopilot's last (re)boot, s.
    ap_boot_s: f64,
    params: Params,
    kept: Saved<Kept>,
    flight: Flight,
    missions: Missions,
    switches: Switches,
    devices: Devices,
    camera: Camera,
}

impl Simulator {
    /// Loads the saved parameters.
    pub fn open(cfg: SimConfig) -> io::Result<Simulator> {
        if !(cfg.speed.is_finite() && cfg.speed > 0.0) {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("simulation speed must be a positive number, got {}", cfg.speed),
            ));
        }
        let params = Params::load(cfg.data_dir.join(PARAMS_FILE))?;
        let kept = Saved::<Kept>::load(cfg.data_dir.join(STATE_FILE))?;
        let switches = Switches {
            map_locate: kept.get().map_locate,
            ..Switches::default()
        };
        tracing::info!(speed = cfg.speed, "simulator ready");
        Ok(Simulator {
            speed: cfg.speed,
            seed: cfg.seed,
            sim_s: 0.0,
            ap_boot_s: 0.0,
            params,
            kept,
            flight: Flight::default(),
            missions: Missions::default(),
            switches,
            devices: Devices::default(),
            camera: Camera::default(),
        })
    }

    fn limits(&self) -> Limits {
        let p = &self.params;
        Limits {
            cruise: p.f64(Key::CruiseSpeed),
            climb: p.f64(Key::ClimbSpeed),
            land: p.f64(Key::LandSpeed),
            yaw_rate: p.f64(Key::YawRate),
            accept: p.f64(Key::AcceptRadius),
            rtl_alt: self.envelope().clip(p.f64(Key::RtlAlt)),
            rtl_land: p.flag(Key::RtlLand),
            drain: p.f64(Key::BatteryDrain),
            low_battery: p.f64(Key::LowBattery),
            autosleep_after: self.switches.autosleep.then(|| p.f64(Key::AutosleepAfter)),
            charging: self.devices.charging(),
        }
    }

    /// Carries out one command: each section of the command table has its
    /// owner. The core has already checked the gates and the grammar.
    fn run(&mut self, cmd: &Command<'_>, ctx: &Context, files: &Files, out: &mut Fields<'_>) -> SimResult {
        let air = self.airframe();
        let flag = |on: &mut bool, key: &str, out: &mut Fields<'_>| {
            *on = matches!(cmd.args(), lluav_core::Args::Flag(true));
            out.bool(key, *on);
            Ok(())
        };
        match (cmd.id(), cmd.id().spec().section) {
            (CommandId::Param | CommandId::GetParam, _) | (_, Section::Param) => self.params.run(cmd, out),
            (CommandId::ApronState, _) | (_, Section::Led | Section::Apron | Section::Lidar) => {
                self.devices.run(cmd, air, out)
            }
            (_, Section::State) => self.report(cmd.id(), out),
            (CommandId::Tunnelfly, _) => flag(&mut self.switches.tunnelfly, "tunnelfly", out),
            (CommandId::AutosleepEnable, _) => flag(&mut self.switches.autosleep, "autosleep", out),
            (CommandId::SetMaplocate, _) => {
                let on = matches!(cmd.args(), lluav_core::Args::Flag(true));
                self.kept
                    .update(|k| k.map_locate = on)
                    .map_err(|e| SimError::io("save map localisation", e))?;
                flag(&mut self.switches.map_locate, "map_locate", out)
            }
            (CommandId::PreflightEnable, _) => flag(&mut self.switches.preflight, "preflight_enabled", out),
            (_, Section::Flight) => self.fly(cmd, files, out),
            (_, Section::Mission) => self.mission(cmd, ctx.now_ms, files, out),
            (_, Section::Camera) => self.camera.run(cmd, ctx.now_ms, files, out),
            (CommandId::RebootAp, _) => self.reboot_autopilot(out),
            (CommandId::PreflightCheck, _) => self.write_preflight(files, out),
            (CommandId::TestWp | CommandId::TestListwp, _) => self.test_waypoints(cmd, files, out),
            (_, Section::System | Section::Other) => self.devices.run(cmd, air, out),
            (id, _) => Err(SimError::NotOwned(id.name())),
        }
    }

    fn reboot_autopilot(&mut self, out: &mut Fields<'_>) -> SimResult {
        self.ap_boot_s = self.sim_s;
        tracing::warn!("simulated autopilot reboot");
        out.object("reboot", |o| {
            o.str("target", "autopilot").bool("simulated", true);
        });
        Ok(())
    }
}

impl Vehicle for Simulator {
    fn armed(&self) -> bool {
        self.flight.mode().armed()
    }

    fn execute(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> Result<Progress, Failure> {
        let result = self.run(cmd, ctx, files, out);
        // Commands such as set_sp_ned or land end routes: settle the
        // mission bookkeeping before the next command looks at it.
        self.missions.apply(&self.flight.drain_events());
        match result {
            Ok(()) => Ok(Progress::Done),
            Err(e) => {
                tracing::debug!(cmd = cmd.id().name(), error = %e, "command refused");
                Err(e.fail(out))
            }
        }
    }

    fn write_state(&self, ctx: &Context, state: &mut Fields<'_>) {
        self.write_state_fields(ctx, state);
    }

    fn failsafe(&self) -> Option<lluav_core::Failsafe> {
        let active = self.flight.failsafe()?;
        Some(lluav_core::Failsafe {
            overridden: active.overridden,
            ..lluav_core::Failsafe::new(active.source(), active.action())
        })
    }

    fn next_tick(&self) -> Option<Duration> {
        let charging = self.devices.charging() && self.flight.battery() < 100.0;
        match self.flight.mode() {
            _ if charging => Some(TICK),
            flight::Mode::Sleep => None,
            &flight::Mode::Disarmed { idle_s } => self.switches.autosleep.then(|| {
                let left = (self.params.f64(Key::AutosleepAfter) - idle_s).max(0.0) / self.speed;
                Duration::from_secs_f64(left).max(TICK)
            }),
            _ => Some(TICK),
        }
    }

    fn drain_events(&mut self, out: &mut Vec<Event>) {
        // A run's progress first, then the FSM it moves: `reached` and
        // `completed` before `mission -> hover`, `started` before
        // `hover -> mission`.
        self.missions.drain_news(out);
        self.flight.drain_news(out);
    }

    fn override_failsafe(&mut self) -> Result<(), Failure> {
        // Named as `state.failsafe` names it: the log line is also a `log`
        // event an operator reads.
        let reason = self.failsafe().map(|f| f.reason().to_string());
        tracing::warn!(
            failsafe = reason.as_deref().unwrap_or("none"),
            "failsafe overridden by the session in control"
        );
        self.flight.override_failsafe();
        Ok(())
    }

    fn mission_running(&self) -> bool {
        matches!(self.flight.mode(), flight::Mode::Mission(_)) && self.missions.running().is_some()
    }

    fn control_timeout_ms(&self) -> u32 {
        (self.params.f64(Key::ControlTimeout) * 1000.0) as u32
    }

    fn snapshot(&self) -> Snapshot {
        Snapshot {
            backend: "simulator",
            time_s: self.sim_s,
            position: self.flight.pos(),
            yaw: self.flight.yaw(),
            fsm: self.flight.mode().name(),
            distance_m: self.flight.totals().distance_m,
        }
    }

    /// Advances the simulation by wall time `dt` (simulated: `dt * speed`).
    fn tick(&mut self, dt: Duration) {
        let sim_dt = dt.as_secs_f64() * self.speed;
        let limits = self.limits();
        self.flight.advance(sim_dt, &limits);
        self.sim_s += sim_dt;
        self.missions.apply(&self.flight.drain_events());
    }
}
