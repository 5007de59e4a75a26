//! The MAVLink vehicle: a real autopilot (PX4, ArduPilot) on a serial port
//! or UDP/TCP, the second [`Vehicle`] beside the simulator
//! (`lluavd --mavlink ADDRESS`, DESIGN.md "Backends").
//!
//! A link task (module `link`) reads everything the autopilot sends into
//! what lluavd knows of it (`state`: the telemetry cache, the setpoint
//! stream, the missions) and a feed; commands that need the autopilot's
//! answer run the MAVLink protocols (`protocol`) as async sequences
//! (`ops`) on the link's tasks and answer [`Progress::Waiting`]: the
//! daemon waits for them with the vehicle unlocked, so other sessions are
//! served meanwhile, and each sequence ends with its own answer
//! (`answer`). Timeouts and retries are tokio's timers; wall-clock time
//! is the daemon's clock, the one requests are stamped with
//! ([`Context::now_ms`]). [`Vehicle::stop`] ends the link's tasks.
//!
//! # What each command does on this backend
//!
//! | command | MAVLink |
//! |---|---|
//! | `state` | the cache: `armed` (heartbeat), `fsm` (from armed, `EXTENDED_SYS_STATE` and the mode), `position`/`velocity` (`LOCAL_POSITION_NED`), `yaw` (`ATTITUDE`), `altitude` (`GLOBAL_POSITION_INT.relative_alt`), `battery` (`BATTERY_STATUS`/`SYS_STATUS`), `setpoint` (the streamed one or null), `home` (`HOME_POSITION`, local), plus `link` (`up`/`lost`), `heartbeat_age_ms`, `autopilot`, `mode`, `landed`, `global`, `home_global`, `mission` (the run's progress); `failsafe` (`authority`) and `control` as every backend |
//! | `takeoff` | ArduPilot: `DO_SET_MODE` GUIDED; then `COMPONENT_ARM_DISARM` (arm), `NAV_TAKEOFF` to `takeoff_alt` above home clipped into `min_alt..=max_alt` (answered as `target_alt`; disarms again if the autopilot refuses it; never when its acknowledgement is lost); once it answers 0, `fsm` is `takeoff` and the vehicle counts as flying until the telemetry shows the climb, a heartbeat shows it disarmed or `land`/`disarm` answers 0 (at most 10 s) |
//! | `land` | `NAV_LAND`; the setpoint stream stops |
//! | `rtl` | `NAV_RETURN_TO_LAUNCH`; the setpoint stream stops; answers `home` and `return_alt`, the autopilot's own RTL altitude (PX4 `RTL_RETURN_ALT`, ArduPilot `RTL_ALT`, read at link-up; null if unknown): lluavd cannot clip it, and logs a warning when it is above `max_alt` |
//! | `mrtl` | ArduPilot: `DO_SET_MODE` SMART_RTL (the stream stops; `return_alt` null: it retraces the path flown); PX4: not supported (-2) |
//! | `disarm` | `COMPONENT_ARM_DISARM` with the force flag (21196): motors stop, in the air too |
//! | `set_sp_ned` | in the air only (-1 `Vehicle is not flying`), inside the envelope around `HOME_POSITION` (-2 `Invalid arguments: altitude 4 m above max_alt 3 m`; -1 while home is unknown): `SET_POSITION_TARGET_LOCAL_NED` (`MAV_FRAME_LOCAL_NED`, position + yaw) re-sent at 10 Hz, then `DO_SET_MODE` OFFBOARD (PX4) / GUIDED (ArduPilot) unless already in it, never out of a failsafe that holds; streaming stops when no session that set it is connected, on `land`/`rtl`/`mrtl`/`disarm`/`takeoff`/`mw_exec`, and when the autopilot leaves it for a failsafe mode |
//! | `mission` | every waypoint inside the envelope around `HOME_POSITION` (-2 `Invalid arguments: waypoint 2: ...`); mission upload (`MISSION_COUNT`, `MISSION_REQUEST_INT`, `MISSION_ITEM_INT`, `MISSION_ACK`) of `NAV_WAYPOINT`s, NED converted to global from `HOME_POSITION` (altitude relative to home; ArduPilot's item 0 is home); a lost final `MISSION_ACK` is resolved by reading the mission count back (`MISSION_REQUEST_LIST`); requests past the end are ignored; nothing is ever cancelled |
//! | `mw_exec` | in the air only, the waypoints checked again against the envelope around home now (it may have moved; -2 `Invalid arguments: waypoint 7: ...` by id): uploads the chosen waypoints unless they are what this autopilot holds (a new or rebooted autopilot holds none of them), `MISSION_SET_CURRENT`, `MISSION_START`; progress from `MISSION_CURRENT`/`MISSION_ITEM_REACHED` |
//! | `mw_list`, `dump_missionresult` | the missions lluavd uploaded and the run's progress |
//! | `param` | `PARAM_REQUEST_LIST`, missing indices read one by one |
//! | `get_param`, `set_param` | `PARAM_REQUEST_READ` / `PARAM_SET` / `PARAM_VALUE` (integers bytewise on PX4, cast on ArduPilot, or as `AUTOPILOT_VERSION` announces) |
//! | `save_param 1`, `save_param 0`, `reset_param` | `PREFLIGHT_STORAGE` write, read back, reset to defaults |
//! | `capture` | `IMAGE_START_CAPTURE` (one image) |
//! | `record` | `VIDEO_START_CAPTURE` / `VIDEO_STOP_CAPTURE`, toggled |
//! | `siyi_center`, `ara8_center`, `ara8_pitch` | `DO_GIMBAL_MANAGER_PITCHYAW` |
//! | `reboot_ap` | `PREFLIGHT_REBOOT_SHUTDOWN` (autopilot) |
//! | `mavlink_msgs` | messages received, by type |
//! | `show_sp`, `statics`, `hud1` | the streamed setpoint; link statistics; ENU position |
//! | everything else the vehicle owns (`tether_land`, `sleep`, `wakeup`, `autosleep_enable`, `zyhk`, `relocate_pos`, `tunnelfly`, `plan`, `ai1_mission`, LED, apron, lidar, BMS, UTG, grabber, other SIYI commands, ...) | -2 `Invalid arguments: not supported by this vehicle` |
//!
//! A refused `COMMAND_ACK` answers -1 with the `MAV_RESULT` name. No
//! answer after the retries is resolved from the telemetry when the
//! command shows in it (`effect`: armed flag, mode, landed state): 0 if
//! it happened, -3 if not or nothing says; a lost link (no heartbeat for
//! 3 s) answers -3. lluavd never sends a command no client asked for to
//! clean up after a timeout. The companion computer's commands (files,
//! logs, the machine) are answered by [`crate::companion`] as with the
//! simulator.
//!
//! # Flight authority
//!
//! The core's gates (DESIGN.md, "Flight authority") need the failsafe
//! from the vehicle; over MAVLink it is read from the heartbeats
//! (`authority`): in the air, a return or land mode, or a pilot's mode,
//! that lluavd did not ask for (or that was active when lluavd first saw
//! the autopilot), or `system_status` CRITICAL/EMERGENCY. lluavd
//! remembers what it asked for, so the modes that follow from its own
//! commands never count; holds never do. While a failsafe holds, nothing
//! lluavd sends for a motion command changes the mode (`DO_SET_MODE`,
//! `NAV_TAKEOFF`, the mission start are checked again when sent);
//! `control_take failsafe` overrides it; a heartbeat saying disarmed ends
//! it. The envelope is lluavd's own ([`Limits`]: `min_alt`, `max_alt`,
//! `geofence_radius` around `HOME_POSITION`, config keys and flags); the
//! autopilot's geofence and RTL altitude are the autopilot's, and lluavd
//! cannot clip them.
//!
//! # Events
//!
//! What the autopilot says is told as events (DESIGN.md, "Events"; `news`
//! compares what the vehicle looks like after every packet with what was
//! told last): `link` up and lost, `fsm` and `armed` from the heartbeat
//! (and `state.fsm`'s rules), `failsafe` as `authority` reads it,
//! `battery` crossing 20 %, each 10 % below and 0, `STATUSTEXT`s of
//! severity WARNING or graver as `log` (at most 20 at once and 2 a second
//! more: an autopilot repeats its warnings; lluavd's log keeps every one),
//! and the run's `mission` progress (`mission`: `started` once
//! `MISSION_START` is answered, each waypoint `reached` once and in order
//! from `MISSION_ITEM_REACHED` and `MISSION_CURRENT`, `completed` with the
//! last, `aborted` when the vehicle stops flying it before). The daemon
//! takes them at every tick (50 ms).
//!
//! # The radio link
//!
//! lluavd follows one autopilot (`follow`): the system of
//! `--mavlink-system` (default 1, or `any`), component 1, from the
//! address its heartbeat came from; every other packet is dropped before
//! any cache, and lluavd sends only to that address (`transport`: its own
//! UDP, each datagram parsed with its sender). After a loss it acquires
//! again by the same rule; the same autopilot back is the same vehicle, a
//! different or rebooted one (its boot time went back) is a new vehicle
//! and what lluavd knew of the old one is forgotten (`state`): no
//! setpoint streams until a client sends one, no mission is on it.
//! `--mavlink-signing-key` signs everything sent with MAVLink 2 signing
//! and drops whatever is not signed with the key (`signing`).
//!
//! # What was tested against what
//!
//! `scripts/test-mavlink.sh` flies the C++ MAVSDK library acting as an
//! autopilot (it reports a generic autopilot and speaks PX4's modes and
//! bytewise parameters) and a pymavlink autopilot that reports PX4 or
//! ArduPilot and misbehaves on purpose, over UDP. Neither has a flight
//! controller behind it, so these still need a real PX4 and ArduPilot
//! (SITL at least): PX4's acceptance of OFFBOARD after 300 ms of
//! setpoints, `NAV_TAKEOFF` with an altitude above mean sea level,
//! `MISSION_START` switching PX4 to AUTO.MISSION; ArduCopter's GUIDED
//! takeoff and arming checks, its AUTO mission with the home item,
//! SMART_RTL, and `PREFLIGHT_STORAGE`'s read-back (param 1 = 0) which
//! ArduPilot may refuse; every camera and gimbal command against a real
//! camera or gimbal manager; the serial and TCP transports and their
//! reconnection; the modes a real autopilot enters on its own and the
//! `system_status` it reports with them (PX4's failsafe actions, ArduPilot's
//! failsafe options), and `RTL_RETURN_ALT`/`RTL_ALT` as they read on each
//! release.

mod answer;
mod authority;
pub mod autopilot;
mod effect;
mod error;
mod follow;
pub mod geo;
mod link;
mod mission;
mod news;
mod ops;
mod protocol;
mod signing;
mod state;
mod telemetry;
mod transport;

/// The link's internals, for the fuzz targets only (the `fuzzing`
/// feature, off by default): what lluavd knows of the autopilot and how a
/// packet changes it, the datagram parser, and the command and mission
/// protocols over any [`fuzzing::Port`].
#[cfg(feature = "fuzzing")]
pub mod fuzzing {
    pub use super::authority::Asked;
    pub use super::effect::Effect;
    pub use super::follow::Wanted;
    pub use super::protocol::{Heard, Incoming, Next, Port, Target, Timing, Upload, command, upload_mission};
    pub use super::signing::SigningKey;
    pub use super::state::{Known, Receipt};
    pub use super::transport::parse_datagram;
}

use std::io;
use std::sync::Arc;
use std::time::Duration;

use ::mavlink::dialects::ardupilotmega::MavCmd;
use lluav_core::{Args, Clock, Command, CommandId, Context, Failsafe, Failure, Fields, Payload, SessionId};

pub use error::MavError;
pub use follow::Wanted;
pub use protocol::Timing;
pub use signing::SigningKey;

use crate::files::Files;
use crate::vehicle::envelope::Envelope;
use crate::vehicle::mission::{self as mission_json};
use crate::vehicle::{Ned, Progress, Refusal, Reply, Snapshot, Vehicle};
use answer::{Acknowledged, Answer, Captured, Rebooting, Recording, Returning, Saved};
use authority::Asked;
use autopilot::{Flavour, Mode, Phase};
use effect::Effect;
use link::{Link, LinkConfig};
use mission::{Mission, Waypoint};
use ops::Then;
use state::Known;

/// Largest mission file a client may point at, bytes.
const MAX_MISSION_FILE: u64 = 1 << 20;
/// Takeoff altitude above home when none is configured, metres.
pub const DEFAULT_TAKEOFF_ALT: f64 = 2.5;

/// lluavd's own limits for the MAVLink vehicle (DESIGN.md, "Flight
/// authority"; the simulator's are its parameters of the same names): the
/// envelope around the autopilot's home every target is checked against,
/// the takeoff altitude (clipped into it) and how long control lasts
/// without a request. The autopilot's own limits (its geofence, its RTL
/// altitude) still apply on top, and are the autopilot's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Limits {
    /// Lowest target altitude above home, m.
    pub min_alt: f64,
    /// Highest target altitude above home, m.
    pub max_alt: f64,
    /// Largest horizontal distance of a target from home, m.
    pub geofence_radius: f64,
    /// `takeoff` climbs this high above home (clipped into
    /// `min_alt..=max_alt`), m.
    pub takeoff_alt: f64,
    /// Seconds without a request after which the session in control
    /// loses it.
    pub control_timeout_s: u32,
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            min_alt: 0.5,
            max_alt: 120.0,
            geofence_radius: 500.0,
            takeoff_alt: DEFAULT_TAKEOFF_ALT,
            control_timeout_s: 30,
        }
    }
}

impl Limits {
    /// Each limit within the range the simulator's parameter of the same
    /// name allows, and an envelope that is not empty (`min_alt` below
    /// `max_alt`); the reason names the setting.
    pub fn check(&self) -> Result<(), String> {
        let ranges = [
            ("min_alt", self.min_alt, 0.2, 10.0),
            ("max_alt", self.max_alt, 1.0, 500.0),
            ("geofence_radius", self.geofence_radius, 1.0, 10_000.0),
            ("takeoff_alt", self.takeoff_alt, 0.5, 120.0),
            ("control_timeout", f64::from(self.control_timeout_s), 1.0, 3600.0),
        ];
        for (name, value, min, max) in ranges {
            if !(min..=max).contains(&value) {
                return Err(format!("{name} {value} out of range {min}..{max}"));
            }
        }
        if self.min_alt >= self.max_alt {
            return Err(format!(
                "min_alt {} m not below max_alt {} m: no altitude would be left to fly",
                self.min_alt, self.max_alt
            ));
        }
        Ok(())
    }

    /// The envelope around `home` (local NED).
    fn envelope(&self, home: Ned) -> Envelope {
        Envelope {
            home,
            min_alt: self.min_alt,
            max_alt: self.max_alt,
            radius: self.geofence_radius,
        }
    }
}

/// How to reach the autopilot.
#[derive(Clone, Debug, PartialEq)]
pub struct MavlinkConfig {
    /// The `mavlink` crate's address: `udpin:0.0.0.0:14540`,
    /// `udpout:HOST:PORT`, `tcpout:HOST:PORT`, `serial:/dev/ttyACM0:57600`.
    pub address: String,
    /// Timeouts and retries.
    pub timing: Timing,
    /// lluavd's limits: the envelope, the takeoff altitude, the control
    /// timeout.
    pub limits: Limits,
    /// lluavd's MAVLink system id; `None` takes the autopilot's (the
    /// companion-computer convention).
    pub own_system: Option<u8>,
    /// The autopilot followed (`--mavlink-system`).
    pub wanted: Wanted,
    /// MAVLink 2 signing (`--mavlink-signing-key`).
    pub signing: Option<SigningKey>,
}

impl MavlinkConfig {
    /// The defaults for `address`.
    pub fn new(address: impl Into<String>) -> Self {
        MavlinkConfig {
            address: address.into(),
            timing: Timing::default(),
            limits: Limits::default(),
            own_system: None,
            wanted: Wanted::default(),
            signing: None,
        }
    }
}

/// An autopilot over MAVLink.
pub struct MavlinkVehicle {
    link: Arc<Link>,
    limits: Limits,
}

impl std::fmt::Debug for MavlinkVehicle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MavlinkVehicle").finish_non_exhaustive()
    }
}

impl MavlinkVehicle {
    /// Connects to the autopilot and starts the link's tasks on the
    /// current tokio runtime; `clock` is the daemon's, the one requests
    /// are stamped with.
    pub async fn open(
        cfg: MavlinkConfig,
        clock: impl Clock + Send + Sync + 'static,
    ) -> io::Result<MavlinkVehicle> {
        let link_cfg = LinkConfig {
            address: cfg.address,
            timing: cfg.timing,
            own_system: cfg.own_system,
            wanted: cfg.wanted,
            signing: cfg.signing,
            max_alt: cfg.limits.max_alt,
        };
        let link = Link::open(link_cfg, Arc::new(clock)).await?;
        Ok(MavlinkVehicle {
            link,
            limits: cfg.limits,
        })
    }

    /// Runs `op` on the link's tasks; the command waits for it, and its
    /// answer (or failure) is the reply.
    fn pend<A: Answer>(
        &self,
        cmd: CommandId,
        op: impl Future<Output = Result<A, MavError>> + Send + 'static,
    ) -> Progress {
        // The op runs on its own task: a client that leaves early stops
        // waiting, not the exchange with the autopilot.
        let task = self.link.spawn(op);
        Progress::Waiting(Box::pin(async move {
            let outcome = task
                .await
                .unwrap_or_else(|_| Err(MavError::NoAnswer("lluavd stopped the link".into())));
            let reply: Reply = Box::new(move |out: &mut Fields<'_>| match outcome {
                Ok(answer) => {
                    answer.write(out);
                    Ok(())
                }
                Err(e) => {
                    tracing::info!(cmd = cmd.name(), error = %e, "command failed");
                    Err(e.fail(out))
                }
            });
            reply
        }))
    }

    /// The flavour, if the link is up now; else -3.
    fn link_up(&self, ctx: &Context) -> Result<Flavour, MavError> {
        self.link
            .with(|k| match (k.link_up(ctx.now_ms), k.tel().flavour()) {
                (true, Some(f)) => Ok(f),
                _ => Err(MavError::LinkLost(match k.heartbeat_age_ms(ctx.now_ms) {
                    Some(age) => format!("no heartbeat from the autopilot for {:.1} s", age as f64 / 1000.0),
                    None => "no heartbeat from the autopilot yet".into(),
                })),
            })
    }

    /// The flavour, if the link is up and the vehicle flies; else -3/-1.
    fn flying(&self, ctx: &Context) -> Result<Flavour, MavError> {
        let flavour = self.link_up(ctx)?;
        if self.link.with(|k| k.airborne(ctx.now_ms)) {
            Ok(flavour)
        } else {
            Err(MavError::not_flying())
        }
    }

    /// Sends `cmd` when the link is up; `then` answers it once done.
    /// Nothing the telemetry shows tells whether it happened when its
    /// acknowledgement is lost.
    fn command<A: Answer>(
        &self,
        id: CommandId,
        ctx: &Context,
        cmd: MavCmd,
        params: [f32; 7],
        then: impl Then<A>,
    ) -> Result<Progress, MavError> {
        self.link_up(ctx)?;
        Ok(self.pend(id, ops::command(Arc::clone(&self.link), cmd, params, None, then)))
    }

    /// A conservative flight command (`land`, `rtl`, `mrtl`) for a flying
    /// vehicle whose `effect` the telemetry shows: the setpoint stream
    /// stops (the old pilot's setpoint no longer cancels it), the modes it
    /// leads to are lluavd's own (`asked`) unless it fails; `then` answers
    /// it once done. It runs in a failsafe too (DESIGN.md, "Flight
    /// authority").
    fn redirect<A: Answer>(
        &self,
        id: CommandId,
        ctx: &Context,
        (cmd, params): (MavCmd, [f32; 7]),
        (effect, asked): (impl FnOnce(Flavour) -> Effect, Asked),
        then: impl Then<A>,
    ) -> Result<Progress, MavError> {
        let flavour = self.flying(ctx)?;
        self.link.with(|k| {
            k.stop_stream();
            k.ask(asked, ctx.now_ms);
        });
        let link = Arc::clone(&self.link);
        let effect = effect(flavour);
        let op = async move {
            let done = ops::command(Arc::clone(&link), cmd, params, Some(effect), then).await;
            if done.is_err() {
                link.with(|k| k.unask(asked));
            }
            done
        };
        Ok(self.pend(id, op))
    }

    fn run(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> Result<Progress, MavError> {
        use CommandId as C;
        let link = Arc::clone(&self.link);
        let nan = f32::NAN;
        match (cmd.id(), cmd.args()) {
            (C::Statics | C::Hud1 | C::MavlinkMsgs | C::ShowSp | C::MwList | C::DumpMissionresult, _) => {
                self.link.with(|k| report(k, cmd, ctx, out))?;
                Ok(Progress::Done)
            }
            (C::Takeoff, _) => {
                let flavour = self.link_up(ctx)?;
                // Home is where the vehicle stands; only the altitude is
                // clipped, never refused.
                let alt = self.limits.envelope(Ned::default()).clip(self.limits.takeoff_alt) as f32;
                link.with(|k| {
                    k.stop_stream();
                    k.ask(Asked::Takeoff, ctx.now_ms);
                });
                Ok(self.pend(cmd.id(), ops::takeoff(link, flavour, alt)))
            }
            (C::Land, _) => {
                let land = (MavCmd::MAV_CMD_NAV_LAND, [0.0, 0.0, 0.0, nan, nan, nan, nan]);
                let effect = (Effect::Landing, Asked::Land);
                self.redirect::<Acknowledged>(cmd.id(), ctx, land, effect, ops::landing)
            }
            (C::Rtl, _) => {
                let rtl = (MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH, [0.0; 7]);
                let effect = (|f| Effect::Phase(f, Phase::Rtl), Asked::Return);
                let max_alt = self.limits.max_alt;
                self.redirect(cmd.id(), ctx, rtl, effect, move |k: &mut Known, now| {
                    let answer: Returning = ops::returning(k, now);
                    if let Some(alt) = answer.return_alt.filter(|a| f64::from(*a) > max_alt) {
                        tracing::warn!(
                            return_alt = alt,
                            max_alt,
                            "the autopilot's RTL climbs above max_alt"
                        );
                    }
                    answer
                })
            }
            (C::Mrtl, _) => {
                let flavour = self.flying(ctx)?;
                let [p1, p2, p3] = flavour
                    .set_mode_params(Mode::SmartRtl)
                    .ok_or(MavError::Unsupported)?;
                let smart_rtl = (MavCmd::MAV_CMD_DO_SET_MODE, [p1, p2, p3, 0.0, 0.0, 0.0, 0.0]);
                let effect = (|f| Effect::Mode(f, Mode::SmartRtl), Asked::Return);
                self.redirect(cmd.id(), ctx, smart_rtl, effect, ops::retracing)
            }
            (C::Disarm, _) => {
                self.link_up(ctx)?;
                Ok(self.pend(cmd.id(), ops::disarm(link)))
            }
            (C::SetSpNed, Args::Setpoint(p)) => self.set_setpoint(*p, ctx, out),
            (C::Mission, Args::Mission { ext_id, payload }) => self.mission(*ext_id, payload, ctx, files),
            (C::MwExec, Args::MwExec { ext_id, wp_ids }) => self.exec(*ext_id, wp_ids, ctx),
            _ => self.run_device(cmd, ctx),
        }
    }

    /// Parameters, camera, gimbal, the autopilot's reboot; the rest is
    /// not supported.
    fn run_device(&mut self, cmd: &Command<'_>, ctx: &Context) -> Result<Progress, MavError> {
        use CommandId as C;
        let link = Arc::clone(&self.link);
        let storage = MavCmd::MAV_CMD_PREFLIGHT_STORAGE;
        let gimbal = MavCmd::MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW;
        let nan = f32::NAN;
        let id = cmd.id();
        match (id, cmd.args()) {
            (C::Param, _) => {
                self.link_up(ctx)?;
                Ok(self.pend(id, ops::all_params(link)))
            }
            (C::GetParam, Args::ParamName(name)) => {
                check_param_name(name)?;
                self.link_up(ctx)?;
                Ok(self.pend(id, ops::get_param(link, (*name).to_owned())))
            }
            (C::SetParam, Args::SetParam { name, value }) => {
                check_param_name(name)?;
                self.link_up(ctx)?;
                Ok(self.pend(id, ops::set_param(link, (*name).to_owned(), (*value).to_owned())))
            }
            (C::SaveParam, &Args::Flag(save)) => {
                let what = if save { 1.0 } else { 0.0 };
                let params = [what, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                self.command(id, ctx, storage, params, move |_, _| Saved(save))
            }
            (C::ResetParam, _) => {
                let params = [2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                self.command(id, ctx, storage, params, |_, _| Saved(false))
            }
            (C::RebootAp, _) => {
                let params = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                let reboot = MavCmd::MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN;
                self.command(id, ctx, reboot, params, |_, _| Rebooting)
            }
            (C::Capture, _) => {
                let seq = self.link.with(|k| k.images()).wrapping_add(1);
                let params = [0.0, 0.0, 1.0, seq as f32, 0.0, 0.0, 0.0];
                let capture = MavCmd::MAV_CMD_IMAGE_START_CAPTURE;
                self.command(id, ctx, capture, params, |k, _| Captured(k.count_image()))
            }
            (C::Record, _) => {
                let start = !self.link.with(|k| k.recording());
                let what = if start {
                    MavCmd::MAV_CMD_VIDEO_START_CAPTURE
                } else {
                    MavCmd::MAV_CMD_VIDEO_STOP_CAPTURE
                };
                self.command(id, ctx, what, [0.0; 7], move |k, _| {
                    k.set_recording(start);
                    Recording(start)
                })
            }
            (C::SiyiCenter | C::Ara8Center, _) => {
                let params = [0.0, 0.0, nan, nan, 0.0, 0.0, 0.0];
                self.command(id, ctx, gimbal, params, ops::acknowledged)
            }
            (C::Ara8Pitch, &Args::Angle(pitch)) => {
                let params = [pitch, nan, nan, nan, 0.0, 0.0, 0.0];
                self.command(id, ctx, gimbal, params, ops::acknowledged)
            }
            _ => Err(MavError::Unsupported),
        }
    }

    fn set_setpoint(
        &mut self,
        pose: lluav_core::Pose,
        ctx: &Context,
        out: &mut Fields<'_>,
    ) -> Result<Progress, MavError> {
        // As the simulator: setpoints move a flying vehicle (on PX4, OFFBOARD
        // on the ground would take off towards the setpoint when armed).
        let flavour = self.flying(ctx)?;
        let (_, home) = self.home()?;
        let target = Ned::new(pose.x.into(), pose.y.into(), pose.z.into());
        self.limits
            .envelope(home)
            .check(target)
            .map_err(|why| MavError::Invalid(why.to_string()))?;
        let in_mode = self.link.with(|k| {
            k.ask(Asked::Setpoints, ctx.now_ms);
            k.stream(pose, ctx.session);
            k.tel()
                .custom_mode()
                .is_some_and(|m| flavour.is_mode(m, Mode::Guided))
        });
        if in_mode {
            self.link.with(|k| k.write_setpoint(ctx.now_ms, out));
            Ok(Progress::Done)
        } else {
            let op = ops::follow_setpoints(Arc::clone(&self.link), flavour);
            Ok(self.pend(CommandId::SetSpNed, op))
        }
    }

    fn mission(
        &mut self,
        ext_id: u32,
        payload: &Payload<'_>,
        ctx: &Context,
        files: &Files,
    ) -> Result<Progress, MavError> {
        let text = match payload {
            Payload::Json(s) => (*s).to_owned(),
            Payload::Path(p) => files
                .read_mission_file(p, MAX_MISSION_FILE)
                .map_err(|e| MavError::from_refusal(&e))?,
        };
        let parsed = mission_json::parse(&text, &Envelope::NONE).map_err(|e| MavError::from_refusal(&e))?;
        // The autopilot flies a run's items from what it holds: uploading
        // that mission again would change them under the vehicle.
        let running = self
            .link
            .with(|k| k.missions().running().filter(|_| k.fsm(ctx.now_ms) == "mission"));
        if running == Some(ext_id) {
            return Err(MavError::State(format!("Mission {ext_id} is running")));
        }
        let flavour = self.link_up(ctx)?;
        let (home, home_local) = self.home()?;
        // As the simulator's: waypoints named by their place in the list.
        let envelope = self.limits.envelope(home_local);
        for (n, w) in parsed.iter().enumerate() {
            envelope
                .check(w.ned())
                .map_err(|why| MavError::Invalid(format!("waypoint {}: {why}", n + 1)))?;
        }
        let waypoints: Vec<Waypoint> = parsed
            .iter()
            .map(|w| Waypoint {
                id: w.wp_id(),
                ned: w.ned(),
                yaw: w.yaw,
            })
            .collect();
        let (items, first_seq) = mission::items(flavour, home, home_local, &waypoints);
        let op = ops::upload(
            Arc::clone(&self.link),
            Mission { ext_id, waypoints },
            items,
            first_seq,
        );
        Ok(self.pend(CommandId::Mission, op))
    }

    fn home(&self) -> Result<(geo::Global, Ned), MavError> {
        self.link
            .with(|k| match (k.tel().home_global(), k.tel().home_local()) {
                (Some(g), Some(l)) => Ok((g, l)),
                _ => Err(MavError::State(
                    "Home position unknown: the autopilot has not sent HOME_POSITION yet".into(),
                )),
            })
    }

    fn exec(&mut self, ext_id: u32, wp_ids: &[u32], ctx: &Context) -> Result<Progress, MavError> {
        let (selected, on_autopilot) = self.link.with(|k| {
            let missions = k.missions();
            Ok::<_, MavError>((missions.select(ext_id, wp_ids)?, missions.on_autopilot().cloned()))
        })?;
        let flavour = self.flying(ctx)?;
        let (home, home_local) = self.home()?;
        // Checked again: home may have moved since the upload (PX4 sets it
        // at every arming).
        let envelope = self.limits.envelope(home_local);
        for w in &selected {
            envelope
                .check(w.ned)
                .map_err(|why| MavError::Invalid(format!("waypoint {}: {why}", w.id)))?;
        }
        let (items, first_seq) = mission::items(flavour, home, home_local, &selected);
        let plan = mission::OnAutopilot {
            ext_id,
            wp_ids: wp_ids.to_vec(),
            first_seq,
        };
        let upload = (on_autopilot.as_ref() != Some(&plan)).then_some(items);
        self.link.with(|k| k.ask(Asked::Mission, ctx.now_ms));
        Ok(self.pend(CommandId::MwExec, ops::exec(Arc::clone(&self.link), plan, upload)))
    }
}

/// The reports answered from what the link knows.
fn report(k: &Known, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<(), MavError> {
    use CommandId as C;
    let tel = k.tel();
    match (cmd.id(), cmd.args()) {
        (C::MavlinkMsgs, _) => tel.write_counts(out),
        (C::ShowSp, _) => k.write_setpoint(ctx.now_ms, out),
        (C::Statics, _) => {
            out.object("comm", |o| {
                o.bool("mavlink", k.link_up(ctx.now_ms))
                    .u64("mavlink_msgs", tel.total_messages());
            });
            out.object("stat", |o| {
                o.f64("distance_m", (tel.distance_m() * 10.0).round() / 10.0);
            });
        }
        (C::Hud1, _) => {
            let p = tel.position().unwrap_or_default();
            // ENU: x east, y north, z up.
            out.object("uav_pos_enu", |o| Ned::new(p.y, p.x, -p.z).write(o));
            out.object("extra", |o| {
                o.str("fsm", k.fsm(ctx.now_ms));
                match tel.yaw() {
                    Some(y) => o.f32("yaw", y),
                    None => o.null("yaw"),
                };
            });
        }
        (C::MwList, _) => k.missions().write_list(out),
        (C::DumpMissionresult, &Args::OptCount(ext_id)) => k.missions().write_result(ext_id, out)?,
        _ => return Err(MavError::Unsupported),
    }
    Ok(())
}

/// PARAM_* messages carry at most 16 characters of name.
fn check_param_name(name: &str) -> Result<(), MavError> {
    if name.len() > 16 {
        return Err(MavError::Invalid(format!(
            "{name} is longer than the 16 characters of a MAVLink parameter name"
        )));
    }
    Ok(())
}

impl Vehicle for MavlinkVehicle {
    fn armed(&self) -> bool {
        self.link.with(|k| k.tel().armed())
    }

    fn execute(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> Result<Progress, Failure> {
        self.run(cmd, ctx, files, out).map_err(|e| {
            tracing::debug!(cmd = cmd.id().name(), error = %e, "command refused");
            e.fail(out)
        })
    }

    fn session_closed(&mut self, session: SessionId) {
        self.link.with(|k| k.release(session));
    }

    fn failsafe(&self) -> Option<Failsafe> {
        self.link.with(|k| k.failsafe())
    }

    fn override_failsafe(&mut self) -> Result<(), Failure> {
        // Like a pilot taking the sticks: nothing is sent, lluavd's own
        // commands may change the mode again from now on.
        if let Some(f) = self.link.with(Known::override_failsafe) {
            tracing::warn!(failsafe = %f.reason(), "failsafe overridden by the session in control");
        }
        Ok(())
    }

    fn mission_running(&self) -> bool {
        let now = self.link.now_ms();
        self.link.with(|k| k.mission_running(now))
    }

    fn control_timeout_ms(&self) -> u32 {
        self.limits.control_timeout_s.saturating_mul(1000)
    }

    fn write_state(&self, ctx: &Context, state: &mut Fields<'_>) {
        self.link
            .with(|k| k.write_state(ctx.now_ms, ctx.lock_mode, state));
    }

    fn snapshot(&self) -> Snapshot {
        let now = self.link.now_ms();
        self.link.with(|k| {
            let tel = k.tel();
            Snapshot {
                backend: "mavlink",
                time_s: tel.boot_s(),
                position: tel.position().unwrap_or_default(),
                yaw: tel.yaw().map_or(0.0, f64::from),
                fsm: k.fsm(now),
                distance_m: tel.distance_m(),
            }
        })
    }

    fn tick(&mut self, _dt: Duration) {
        // What time alone changes: the link lost, a takeoff's grace over,
        // a run's hold past its grace.
        let now = self.link.now_ms();
        self.link.with(|k| k.look(now));
    }

    fn drain_events(&mut self, out: &mut Vec<crate::events::Event>) {
        self.link.with(|k| k.drain_events(out));
    }

    fn link_up(&self, now_ms: i64) -> Option<bool> {
        Some(self.link.with(|k| k.link_up(now_ms)))
    }

    fn stop(&mut self) {
        self.link.stop();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn stopping_the_vehicle_ends_every_task_of_the_link_and_nothing_more_is_sent() {
        let autopilot = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let address = format!("udpout:{}", autopilot.local_addr().unwrap());
        let mut vehicle = MavlinkVehicle::open(MavlinkConfig::new(address), || 0i64)
            .await
            .unwrap();
        let mut buf = [0u8; 512];
        let heard = tokio::time::timeout(Duration::from_secs(5), autopilot.recv(&mut buf)).await;
        assert!(heard.is_ok(), "no heartbeat from lluavd");
        vehicle.stop();
        // Only the link's tasks hold it besides the vehicle: once they all
        // ended, the vehicle's is the last reference.
        let ended = tokio::time::timeout(Duration::from_secs(2), async {
            while Arc::strong_count(&vehicle.link) > 1 {
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        })
        .await;
        assert!(
            ended.is_ok(),
            "{} references left",
            Arc::strong_count(&vehicle.link)
        );
        while autopilot.try_recv(&mut buf).is_ok() {}
        let more = tokio::time::timeout(Duration::from_millis(1500), autopilot.recv(&mut buf)).await;
        assert!(more.is_err(), "lluavd still sends after stop");
    }
}
