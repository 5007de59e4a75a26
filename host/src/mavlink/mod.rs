//! The MAVLink vehicle: a real autopilot (PX4, ArduPilot) on a serial port
//! or UDP/TCP, the second [`Vehicle`] beside the simulator
//! (`lluavd --mavlink ADDRESS`, DESIGN.md "Backends").
//!
//! A link task (module `link`) reads everything the autopilot sends into a
//! cache (`telemetry`) and a feed; commands that need the autopilot's
//! answer run the MAVLink protocols ([`protocol`]) as async sequences
//! (`ops`) on their own tasks and answer [`Step::Pending`]: the daemon
//! waits for them with the vehicle unlocked, so other sessions are served
//! meanwhile. Timeouts and retries are the link task's (tokio time); the
//! command logic here reads time only from [`Context::now_ms`].
//!
//! # What each command does on this backend
//!
//! | command | MAVLink |
//! |---|---|
//! | `state` | the cache: `armed` (heartbeat), `fsm` (from armed, `EXTENDED_SYS_STATE` and the mode), `position`/`velocity` (`LOCAL_POSITION_NED`), `yaw` (`ATTITUDE`), `altitude` (`GLOBAL_POSITION_INT.relative_alt`), `battery` (`BATTERY_STATUS`/`SYS_STATUS`), `setpoint` (the streamed one or null), `home` (`HOME_POSITION`, local), plus `link` (`up`/`lost`), `heartbeat_age_ms`, `autopilot`, `mode`, `landed`, `global`, `home_global`, `mission` (the run's progress) |
//! | `takeoff` | ArduPilot: `DO_SET_MODE` GUIDED; then `COMPONENT_ARM_DISARM` (arm), `NAV_TAKEOFF` to the configured altitude above home (disarms again if refused) |
//! | `land` | `NAV_LAND` |
//! | `rtl` | `NAV_RETURN_TO_LAUNCH` |
//! | `mrtl` | ArduPilot: `DO_SET_MODE` SMART_RTL; PX4: not supported (-2) |
//! | `disarm` | `COMPONENT_ARM_DISARM` with the force flag (21196): motors stop, in the air too |
//! | `set_sp_ned` | in the air only (-1 `Vehicle is not flying`): `SET_POSITION_TARGET_LOCAL_NED` (`MAV_FRAME_LOCAL_NED`, position + yaw) re-sent at 10 Hz, then `DO_SET_MODE` OFFBOARD (PX4) / GUIDED (ArduPilot) unless already in it; streaming stops when no session that set it is connected, or on `disarm`/`mw_exec` |
//! | `mission` | mission upload (`MISSION_COUNT`, `MISSION_REQUEST_INT`, `MISSION_ITEM_INT`, `MISSION_ACK`) of `NAV_WAYPOINT`s, NED converted to global from `HOME_POSITION` (altitude relative to home; ArduPilot's item 0 is home) |
//! | `mw_exec` | in the air only: uploads the chosen waypoints unless they are what the autopilot holds, `MISSION_SET_CURRENT`, `MISSION_START`; progress from `MISSION_CURRENT`/`MISSION_ITEM_REACHED` |
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
//! A refused `COMMAND_ACK` answers -1 with the `MAV_RESULT` name; no
//! answer after the retries, or a lost link (no heartbeat for 3 s),
//! answers -3. The companion computer's commands (files, logs, the
//! machine) are answered by [`crate::companion`] as with the simulator.
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
//! reconnection.

pub mod autopilot;
mod error;
pub mod geo;
mod link;
mod mission;
mod ops;
pub mod protocol;
mod telemetry;

use std::collections::HashMap;
use std::io;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::Duration;

use ::mavlink::dialects::ardupilotmega::MavCmd;
use lluav_core::{Args, Command, CommandId, Context, Failure, Fields, Payload, SessionId, Step, Ticket};
use tokio::sync::oneshot;

pub use error::MavError;
pub use protocol::Timing;

use crate::files::Files;
use crate::vehicle::Ready;
use crate::vehicle::mission::{self as mission_json, Fence};
use crate::vehicle::{Ned, Refusal, Snapshot, Vehicle};
use autopilot::{Flavour, Mode, ParamValue};
use link::{Link, Stream};
use mission::{Mission, Waypoint};
use ops::Answer;

/// Largest mission file a client may point at, bytes.
const MAX_MISSION_FILE: u64 = 1 << 20;
/// Takeoff altitude above home when none is configured, metres.
pub const DEFAULT_TAKEOFF_ALT: f32 = 2.5;

/// How to reach the autopilot.
#[derive(Clone, Debug, PartialEq)]
pub struct MavlinkConfig {
    /// The `mavlink` crate's address: `udpin:0.0.0.0:14540`,
    /// `udpout:HOST:PORT`, `tcpout:HOST:PORT`, `serial:/dev/ttyACM0:57600`.
    pub address: String,
    /// Timeouts and retries.
    pub timing: Timing,
    /// `takeoff` climbs this high above home, metres.
    pub takeoff_alt: f32,
    /// lluavd's MAVLink system id; `None` takes the autopilot's (the
    /// companion-computer convention).
    pub own_system: Option<u8>,
}

impl MavlinkConfig {
    /// The defaults for `address`.
    pub fn new(address: impl Into<String>) -> Self {
        MavlinkConfig {
            address: address.into(),
            timing: Timing::default(),
            takeoff_alt: DEFAULT_TAKEOFF_ALT,
            own_system: None,
        }
    }
}

type Outcome = Result<Answer, MavError>;

/// A command waiting for the autopilot.
struct Pending {
    cmd: CommandId,
    session: SessionId,
    /// Filled by the future [`Vehicle::ready`] returned.
    slot: Arc<Mutex<Option<Outcome>>>,
    /// The task's answer, until `ready` takes it.
    rx: Option<oneshot::Receiver<Outcome>>,
}

/// An autopilot over MAVLink.
pub struct MavlinkVehicle {
    link: Arc<Link>,
    runtime: tokio::runtime::Handle,
    pending: HashMap<u32, Pending>,
    next_ticket: u32,
    takeoff_alt: f32,
    recording: bool,
    images: u32,
}

impl std::fmt::Debug for MavlinkVehicle {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MavlinkVehicle")
            .field("pending", &self.pending.len())
            .finish_non_exhaustive()
    }
}

impl MavlinkVehicle {
    /// Connects to the autopilot and starts the link's tasks on the
    /// current tokio runtime.
    pub async fn open(cfg: MavlinkConfig) -> io::Result<MavlinkVehicle> {
        let link = Link::open(&cfg.address, cfg.timing, cfg.own_system).await?;
        Ok(MavlinkVehicle {
            link,
            runtime: tokio::runtime::Handle::current(),
            pending: HashMap::new(),
            next_ticket: 1,
            takeoff_alt: cfg.takeoff_alt,
            recording: false,
            images: 0,
        })
    }

    /// Runs `op` on its own task and answers pending on it.
    fn pend(
        &mut self,
        cmd: CommandId,
        ctx: &Context,
        op: impl Future<Output = Outcome> + Send + 'static,
    ) -> Step {
        let ticket = self.next_ticket;
        self.next_ticket = self.next_ticket.wrapping_add(1).max(1);
        let (tx, rx) = oneshot::channel();
        self.runtime.spawn(async move {
            // The session may be gone; what the op changed is recorded.
            let _ = tx.send(op.await);
        });
        self.pending.insert(
            ticket,
            Pending {
                cmd,
                session: ctx.session,
                slot: Arc::new(Mutex::new(None)),
                rx: Some(rx),
            },
        );
        Step::Pending(Ticket(ticket))
    }

    /// The flavour, if the link is up now; else -3.
    fn link_up(&self, ctx: &Context) -> Result<Flavour, MavError> {
        let shared = self.link.shared();
        match (shared.tel.link_up(ctx.now_ms), shared.tel.flavour) {
            (true, Some(f)) => Ok(f),
            _ => Err(MavError::LinkLost(
                match shared.tel.heartbeat_age_ms(ctx.now_ms) {
                    Some(age) => format!("no heartbeat from the autopilot for {:.1} s", age as f64 / 1000.0),
                    None => "no heartbeat from the autopilot yet".into(),
                },
            )),
        }
    }

    /// The flavour, if the link is up and the vehicle flies; else -3/-1.
    fn flying(&self, ctx: &Context) -> Result<Flavour, MavError> {
        let flavour = self.link_up(ctx)?;
        if self.link.shared().tel.airborne() {
            Ok(flavour)
        } else {
            Err(MavError::not_flying())
        }
    }

    fn command(
        &mut self,
        id: CommandId,
        ctx: &Context,
        cmd: MavCmd,
        params: [f32; 7],
    ) -> Result<Step, MavError> {
        self.link_up(ctx)?;
        Ok(self.pend(id, ctx, ops::command(Arc::clone(&self.link), cmd, params)))
    }

    fn run(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> Result<Step, MavError> {
        use CommandId as C;
        let link = Arc::clone(&self.link);
        match (cmd.id(), cmd.args()) {
            (C::Statics | C::Hud1 | C::MavlinkMsgs | C::ShowSp | C::MwList | C::DumpMissionresult, _) => {
                self.report(cmd, ctx, out)?;
                Ok(Step::Done)
            }
            (C::Takeoff, _) => {
                let flavour = self.link_up(ctx)?;
                link.shared().stream = None;
                Ok(self.pend(cmd.id(), ctx, ops::takeoff(link, flavour, self.takeoff_alt)))
            }
            (C::Land, _) => {
                self.flying(ctx)?;
                link.shared().stream = None;
                let nan = f32::NAN;
                let params = [0.0, 0.0, 0.0, nan, nan, nan, nan];
                self.command(cmd.id(), ctx, MavCmd::MAV_CMD_NAV_LAND, params)
            }
            (C::Rtl, _) => {
                self.flying(ctx)?;
                link.shared().stream = None;
                self.command(cmd.id(), ctx, MavCmd::MAV_CMD_NAV_RETURN_TO_LAUNCH, [0.0; 7])
            }
            (C::Mrtl, _) => {
                let flavour = self.flying(ctx)?;
                let [p1, p2, p3] = flavour
                    .set_mode_params(Mode::SmartRtl)
                    .ok_or(MavError::Unsupported)?;
                link.shared().stream = None;
                let params = [p1, p2, p3, 0.0, 0.0, 0.0, 0.0];
                self.command(cmd.id(), ctx, MavCmd::MAV_CMD_DO_SET_MODE, params)
            }
            (C::Disarm, _) => {
                self.link_up(ctx)?;
                Ok(self.pend(cmd.id(), ctx, ops::disarm(link)))
            }
            (C::SetSpNed, Args::Setpoint(p)) => self.set_setpoint(*p, ctx, out),
            (C::Mission, Args::Mission { ext_id, payload }) => self.mission(*ext_id, payload, ctx, files),
            (C::MwExec, Args::MwExec { ext_id, wp_ids }) => self.exec(*ext_id, wp_ids, ctx),
            _ => self.run_device(cmd, ctx),
        }
    }

    /// Parameters, camera, gimbal, the autopilot's reboot; the rest is
    /// not supported.
    fn run_device(&mut self, cmd: &Command<'_>, ctx: &Context) -> Result<Step, MavError> {
        use CommandId as C;
        let link = Arc::clone(&self.link);
        let storage = MavCmd::MAV_CMD_PREFLIGHT_STORAGE;
        let gimbal = MavCmd::MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW;
        let nan = f32::NAN;
        match (cmd.id(), cmd.args()) {
            (C::Param, _) => {
                self.link_up(ctx)?;
                Ok(self.pend(cmd.id(), ctx, ops::all_params(link)))
            }
            (C::GetParam, Args::ParamName(name)) => {
                check_param_name(name)?;
                self.link_up(ctx)?;
                Ok(self.pend(cmd.id(), ctx, ops::get_param(link, (*name).to_owned())))
            }
            (C::SetParam, Args::SetParam { name, value }) => {
                check_param_name(name)?;
                self.link_up(ctx)?;
                let op = ops::set_param(link, (*name).to_owned(), (*value).to_owned());
                Ok(self.pend(cmd.id(), ctx, op))
            }
            (C::SaveParam, &Args::Flag(save)) => {
                let what = if save { 1.0 } else { 0.0 };
                self.command(cmd.id(), ctx, storage, [what, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
            }
            (C::ResetParam, _) => self.command(cmd.id(), ctx, storage, [2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]),
            (C::RebootAp, _) => {
                let params = [1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
                self.command(cmd.id(), ctx, MavCmd::MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, params)
            }
            (C::Capture, _) => {
                let seq = self.images.wrapping_add(1);
                let params = [0.0, 0.0, 1.0, seq as f32, 0.0, 0.0, 0.0];
                self.command(cmd.id(), ctx, MavCmd::MAV_CMD_IMAGE_START_CAPTURE, params)
            }
            (C::Record, _) => {
                let what = if self.recording {
                    MavCmd::MAV_CMD_VIDEO_STOP_CAPTURE
                } else {
                    MavCmd::MAV_CMD_VIDEO_START_CAPTURE
                };
                self.command(cmd.id(), ctx, what, [0.0; 7])
            }
            (C::SiyiCenter | C::Ara8Center, _) => {
                self.command(cmd.id(), ctx, gimbal, [0.0, 0.0, nan, nan, 0.0, 0.0, 0.0])
            }
            (C::Ara8Pitch, &Args::Angle(pitch)) => {
                self.command(cmd.id(), ctx, gimbal, [pitch, nan, nan, nan, 0.0, 0.0, 0.0])
            }
            _ => Err(MavError::Unsupported),
        }
    }

    fn set_setpoint(
        &mut self,
        pose: lluav_core::Pose,
        ctx: &Context,
        out: &mut Fields<'_>,
    ) -> Result<Step, MavError> {
        // As the simulator: setpoints move a flying vehicle (on PX4, OFFBOARD
        // on the ground would take off towards the setpoint when armed).
        let flavour = self.flying(ctx)?;
        let in_mode = {
            let mut shared = self.link.shared();
            let stream = shared.stream.get_or_insert_with(|| Stream {
                pose,
                owners: Default::default(),
            });
            stream.pose = pose;
            stream.owners.insert(ctx.session);
            shared
                .tel
                .custom_mode()
                .is_some_and(|m| flavour.is_mode(m, Mode::Guided))
        };
        if in_mode {
            self.write_setpoint_answer(out);
            Ok(Step::Done)
        } else {
            let op = ops::follow_setpoints(Arc::clone(&self.link), flavour);
            Ok(self.pend(CommandId::SetSpNed, ctx, op))
        }
    }

    fn mission(
        &mut self,
        ext_id: u32,
        payload: &Payload<'_>,
        ctx: &Context,
        files: &Files,
    ) -> Result<Step, MavError> {
        let text = match payload {
            Payload::Json(s) => (*s).to_owned(),
            Payload::Path(p) => files
                .read_mission_file(p, MAX_MISSION_FILE)
                .map_err(|e| MavError::from_refusal(&e))?,
        };
        let parsed = mission_json::parse(&text, &Fence::NONE).map_err(|e| MavError::from_refusal(&e))?;
        let waypoints: Vec<Waypoint> = parsed
            .iter()
            .map(|w| Waypoint {
                id: w.wp_id(),
                ned: w.ned(),
                yaw: w.yaw,
            })
            .collect();
        let flavour = self.link_up(ctx)?;
        let (home, home_local) = self.home()?;
        let (items, first_seq) = mission::items(flavour, home, home_local, &waypoints);
        let op = ops::upload(
            Arc::clone(&self.link),
            Mission { ext_id, waypoints },
            items,
            first_seq,
        );
        Ok(self.pend(CommandId::Mission, ctx, op))
    }

    fn home(&self) -> Result<(geo::Global, Ned), MavError> {
        let shared = self.link.shared();
        match (shared.tel.home_global(), shared.tel.home_local()) {
            (Some(g), Some(l)) => Ok((g, l)),
            _ => Err(MavError::State(
                "Home position unknown: the autopilot has not sent HOME_POSITION yet".into(),
            )),
        }
    }

    fn exec(&mut self, ext_id: u32, wp_ids: &[u32], ctx: &Context) -> Result<Step, MavError> {
        let (selected, on_autopilot) = {
            let shared = self.link.shared();
            (
                shared.missions.select(ext_id, wp_ids)?,
                shared.missions.on_autopilot.clone(),
            )
        };
        let flavour = self.flying(ctx)?;
        let (home, home_local) = self.home()?;
        let (items, first_seq) = mission::items(flavour, home, home_local, &selected);
        let plan = mission::OnAutopilot {
            ext_id,
            wp_ids: wp_ids.to_vec(),
            first_seq,
        };
        let upload = (on_autopilot.as_ref() != Some(&plan)).then_some(items);
        Ok(self.pend(
            CommandId::MwExec,
            ctx,
            ops::exec(Arc::clone(&self.link), plan, upload),
        ))
    }

    fn report(&self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<(), MavError> {
        use CommandId as C;
        let shared = self.link.shared();
        let tel = &shared.tel;
        match (cmd.id(), cmd.args()) {
            (C::MavlinkMsgs, _) => tel.write_counts(out),
            (C::ShowSp, _) => {
                drop(shared);
                self.write_setpoint_answer(out);
            }
            (C::Statics, _) => {
                out.object("comm", |o| {
                    o.bool("mavlink", tel.link_up(ctx.now_ms))
                        .u64("mavlink_msgs", tel.total_messages());
                });
                out.object("stat", |o| {
                    o.f64("distance_m", (tel.distance_m * 10.0).round() / 10.0);
                });
            }
            (C::Hud1, _) => {
                let p = tel.position().unwrap_or_default();
                // ENU: x east, y north, z up.
                out.object("uav_pos_enu", |o| Ned::new(p.y, p.x, -p.z).write(o));
                out.object("extra", |o| {
                    o.str("fsm", tel.fsm());
                    match tel.yaw() {
                        Some(y) => o.f32("yaw", y),
                        None => o.null("yaw"),
                    };
                });
            }
            (C::MwList, _) => shared.missions.write_list(out),
            (C::DumpMissionresult, &Args::OptCount(ext_id)) => shared.missions.write_result(ext_id, out)?,
            _ => return Err(MavError::Unsupported),
        }
        Ok(())
    }

    fn write_setpoint_answer(&self, out: &mut Fields<'_>) {
        let shared = self.link.shared();
        match &shared.stream {
            Some(s) => out.object("sp", |o| {
                o.f32("x", s.pose.x)
                    .f32("y", s.pose.y)
                    .f32("z", s.pose.z)
                    .f32("yaw", s.pose.yaw);
            }),
            None => out.null("sp"),
        };
        out.bool("active", shared.stream.is_some())
            .str("fsm", shared.tel.fsm());
    }

    /// Writes a finished command's response.
    fn write_answer(&mut self, cmd: CommandId, answer: Answer, out: &mut Fields<'_>) {
        use CommandId as C;
        match (cmd, answer) {
            (C::Takeoff, Answer::Takeoff { target_alt }) => {
                out.str("fsm", "takeoff").f32("target_alt", target_alt);
            }
            (C::Disarm, _) => {
                out.bool("armed", false).str("fsm", "disarmed");
            }
            (C::SetSpNed, _) => self.write_setpoint_answer(out),
            (
                C::Mission,
                Answer::Mission {
                    ext_id,
                    waypoints,
                    items,
                },
            ) => {
                out.u64("ext_id", ext_id.into())
                    .u64("waypoints", waypoints as u64)
                    .u64("items", items as u64);
            }
            (C::MwExec, Answer::Exec { ext_id, wp_ids }) => {
                out.u64("ext_id", ext_id.into()).array("wp_ids", |a| {
                    for id in wp_ids {
                        a.u64(id.into());
                    }
                });
                out.str("fsm", "mission");
            }
            (
                C::GetParam | C::SetParam,
                Answer::Param {
                    name,
                    value,
                    ty,
                    index,
                    count,
                },
            ) => {
                out.object("param", |o| write_param(o, &name, value));
                out.object("info", |o| {
                    o.str("type", autopilot::type_name(ty))
                        .u64("index", index.into())
                        .u64("count", count.into());
                });
            }
            (C::Param, Answer::Params(all)) => {
                out.object("param", |o| {
                    for (name, value) in &all {
                        write_param(o, name, *value);
                    }
                });
            }
            (C::SaveParam | C::ResetParam, _) => {
                out.bool("saved", cmd == C::SaveParam);
            }
            (C::RebootAp, _) => {
                out.object("reboot", |o| {
                    o.str("target", "autopilot").bool("simulated", false);
                });
            }
            (C::Capture, _) => {
                self.images = self.images.wrapping_add(1);
                out.object("capture", |o| {
                    o.u64("seq", self.images.into());
                });
            }
            (C::Record, _) => {
                self.recording = !self.recording;
                out.bool("recording", self.recording);
            }
            _ => {
                out.str("fsm", self.link.shared().tel.fsm());
            }
        }
    }
}

fn write_param(o: &mut Fields<'_>, name: &str, value: ParamValue) {
    match value {
        ParamValue::Int(i) => o.i64(name, i),
        ParamValue::Float(f) => o.f32(name, f),
    };
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
        self.link.shared().tel.armed()
    }

    fn execute(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &Files,
        out: &mut Fields<'_>,
    ) -> Result<Step, Failure> {
        self.run(cmd, ctx, files, out).map_err(|e| {
            tracing::debug!(cmd = cmd.id().name(), error = %e, "command refused");
            e.fail(out)
        })
    }

    fn finish(&mut self, ticket: Ticket, _ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let Some(p) = self.pending.remove(&ticket.0) else {
            tracing::error!(ticket = ticket.0, "finish for an unknown ticket");
            return Err(Failure::unhandled());
        };
        let outcome = p.slot.lock().unwrap_or_else(PoisonError::into_inner).take();
        match outcome {
            Some(Ok(answer)) => {
                self.write_answer(p.cmd, answer, out);
                Ok(Step::Done)
            }
            Some(Err(e)) => {
                tracing::info!(cmd = p.cmd.name(), error = %e, "command failed");
                Err(e.fail(out))
            }
            None => {
                tracing::error!(ticket = ticket.0, "finish before the ticket was ready");
                Err(Failure::unhandled())
            }
        }
    }

    fn ready(&mut self, ticket: Ticket) -> Ready {
        let Some(p) = self.pending.get_mut(&ticket.0) else {
            return Box::pin(std::future::ready(()));
        };
        let slot = Arc::clone(&p.slot);
        let rx = p.rx.take();
        Box::pin(async move {
            let outcome = match rx {
                Some(rx) => rx
                    .await
                    .unwrap_or_else(|_| Err(MavError::NoAnswer("the command's task ended".into()))),
                None => Err(MavError::NoAnswer("the command was already waited for".into())),
            };
            *slot.lock().unwrap_or_else(PoisonError::into_inner) = Some(outcome);
        })
    }

    fn session_closed(&mut self, session: SessionId) {
        self.pending.retain(|_, p| p.session != session);
        let mut shared = self.link.shared();
        if let Some(stream) = shared.stream.as_mut() {
            stream.owners.remove(&session);
            if stream.owners.is_empty() {
                shared.stream = None;
                tracing::warn!("setpoint stream stopped: no client that set it is connected");
            }
        }
    }

    fn write_state(&self, ctx: &Context, state: &mut Fields<'_>) {
        let shared = self.link.shared();
        shared.tel.write_state(ctx.now_ms, state);
        state.bool("lock_mode", ctx.lock_mode);
        match &shared.stream {
            Some(s) => state.object("setpoint", |o| {
                o.f32("x", s.pose.x)
                    .f32("y", s.pose.y)
                    .f32("z", s.pose.z)
                    .f32("yaw", s.pose.yaw);
            }),
            None => state.null("setpoint"),
        };
        shared.missions.write_state(state);
    }

    fn snapshot(&self) -> Snapshot {
        let shared = self.link.shared();
        let tel = &shared.tel;
        Snapshot {
            backend: "mavlink",
            time_s: tel.boot_s(),
            position: tel.position().unwrap_or_default(),
            yaw: tel.yaw().map_or(0.0, f64::from),
            fsm: tel.fsm(),
            distance_m: tel.distance_m,
        }
    }

    fn tick(&mut self, _dt: Duration) {}

    fn link_up(&self, now_ms: i64) -> Option<bool> {
        Some(self.link.shared().tel.link_up(now_ms))
    }
}
