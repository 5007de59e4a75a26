//! The daemon's backend: the companion computer and a vehicle, composed.
//!
//! lluavd runs on the companion computer, the Linux machine on board. Two
//! things answer the protocol's commands there:
//! - the **vehicle** ([`VehicleBackend`]): what flies — the flight state
//!   machine, setpoints, missions, the autopilot's parameters — and the
//!   peripherals on the airframe (LED, camera and gimbal, apron, BMS,
//!   lidar, UTG, grabber, ARA8). The simulator ([`crate::sim`]) is one;
//!   an autopilot over MAVLink is another.
//! - the **companion computer** ([`Companion`]): the Linux machine itself,
//!   the same whatever flies.
//!
//! [`Onboard`] owns one of each and implements [`lluav_core::Backend`] by
//! routing every command to the side that owns it ([`owner`]):
//!
//! | owner | commands |
//! |---|---|
//! | companion | `ver`, `sysinfo`, `diskusage`, `machineid`, `get_submap_info`, `showmsg`, `savemsg`; maps: `savemap`, `set_mappath`, `list_maps`, `rm_map`; `savebag`, `clear_bags`; images: `list_imagedir`, `rm_imagedir`, `clear_images`; the machine and its nodes: `reboot_node`, `reboot_system`, `poweroff_system`, `prepare_poweroff`, `reboot_dlo`, `restart_dlo`; `test_notif`, `cv_test`; the password file (`passwd`, through [`lluav_core::Backend::password_changed`]) |
//! | both (vehicle first, then companion) | `state` (one `state` object both fill), `statics` (vehicle: `comm`, `stat`; companion: `rosrecord`, `node_boot_sec`), `hud1` (vehicle: `uav_pos_enu`, `extra`; companion: `kfs`) |
//! | vehicle | everything else that reaches a backend: flight, missions, parameters, `set_maplocate`, camera and gimbal (`capture`, `snapshot`, `record`, `siyi_*`), LED, apron, `reboot_ap`, `kill_livox`, lidar, UTG, grabber, ARA8, preflight, `test_wp`, `test_listwp`, BMS, and the telemetry reports `param`, `get_param`, `lidarpose`, `apron_state`, `mavlink_msgs`, `show_sp`, `show_apguid2` |
//!
//! The core answers `login`, `help`, `admin_lock` and `admin_unlock`
//! itself; they never reach a backend.
//!
//! # The `state` object
//! `{"state":{...}}` with, from the vehicle: `armed` (bool), `fsm` (the
//! state machine's state: `disarmed`, `armed`, `takeoff`, `hover`,
//! `mission`, `landing`, `rtl`, `sleep`), `lock_mode` (bool), `airborne`,
//! `position` and `velocity` (`{x,y,z}`, NED metres and m/s), `yaw`
//! (radians), `altitude` (metres above the NED origin), `battery`
//! (percent), `setpoint` (`{x,y,z,yaw}`), `home` (`{x,y,z}`), then
//! backend-specific members (the simulator's `waypoints_left`, `plan_lock`,
//! `sim_time_s`, ...; an autopilot's `link`); from the companion:
//! `recording_bag`. These names are stable: consoles read them.
//!
//! # Time
//! Nothing under the vehicle or the companion reads a clock: a request's
//! time is [`Context::now_ms`], and the daemon's ticks move simulated time.

mod route;

use std::io;
use std::panic::{self, AssertUnwindSafe};
use std::time::Duration;

use lluav_core::{Backend, Command, CommandId, Context, Failure, Fields, Ret, SessionId, Step, Ticket};

use crate::companion::{self, Companion, CompanionConfig};
use crate::daemon::{Ready, Vehicle};
use crate::sim::{SimConfig, Simulator};
pub use route::{Owner, owner};

/// A point or vector in NED metres (x north, y east, z down).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Ned {
    /// North.
    pub x: f64,
    /// East.
    pub y: f64,
    /// Down.
    pub z: f64,
}

impl Ned {
    /// A point.
    pub fn new(x: f64, y: f64, z: f64) -> Ned {
        Ned { x, y, z }
    }

    /// Writes `x`, `y`, `z` members as `f32`: coordinates are `f32` on the
    /// wire (DESIGN.md, "Numbers in responses").
    pub fn write(self, o: &mut Fields<'_>) {
        o.f32("x", self.x as f32)
            .f32("y", self.y as f32)
            .f32("z", self.z as f32);
    }
}

/// What the companion computer needs to know of the vehicle: for bags,
/// maps and version reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Snapshot {
    /// The backend's name in `ver` (`simulator`, `mavlink`).
    pub backend: &'static str,
    /// The vehicle's own clock, seconds (simulated time, autopilot boot
    /// time, ...), for bag samples.
    pub time_s: f64,
    /// Position, NED metres.
    pub position: Ned,
    /// Heading, radians.
    pub yaw: f64,
    /// The state machine's state, as in `state.fsm`.
    pub fsm: &'static str,
    /// Distance flown since start, metres (map keyframes are spaced by it).
    pub distance_m: f64,
}

/// A vehicle backend: the flying half of [`Onboard`].
///
/// It answers the commands [`owner`] gives the vehicle, with the same
/// contract as [`lluav_core::Backend::execute`]; `files` is the companion
/// computer's data directory, for mission files and camera output.
pub trait VehicleBackend: Send + 'static {
    /// Whether the motors are armed right now (the armed gate).
    fn armed(&self) -> bool;

    /// Carries out a command the vehicle owns, or starts it and answers
    /// [`Step::Pending`].
    fn execute(
        &mut self,
        cmd: &Command<'_>,
        ctx: &Context,
        files: &crate::companion::Files,
        out: &mut Fields<'_>,
    ) -> Result<Step, Failure>;

    /// Finishes a command left pending (see [`lluav_core::Backend::finish`]).
    fn finish(&mut self, ticket: Ticket, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let _ = (ticket, ctx, out);
        Err(Failure::unhandled())
    }

    /// Completes when the pending `ticket` can be finished (see
    /// [`Vehicle::ready`]).
    fn ready(&mut self, ticket: Ticket) -> Ready {
        let _ = ticket;
        Box::pin(std::future::ready(()))
    }

    /// A session's connection ended.
    fn session_closed(&mut self, session: SessionId) {
        let _ = session;
    }

    /// Writes the vehicle's members of the `state` object: at least
    /// `armed`, `fsm` and `lock_mode` (see the module doc).
    fn write_state(&self, ctx: &Context, state: &mut Fields<'_>);

    /// What the companion computer needs to know of the vehicle now.
    fn snapshot(&self) -> Snapshot;

    /// Advances the vehicle by `dt` of wall time.
    fn tick(&mut self, dt: Duration);

    /// Persists anything pending.
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// A refusal or failure that knows its `ret` (DESIGN.md, "Errors"); its
/// `Display` is the whole message.
pub(crate) trait Refusal: std::fmt::Display {
    /// The `ret` it is answered with.
    fn ret(&self) -> Ret;

    /// Answers it: the message is written whole into the response.
    fn fail(&self, out: &mut Fields<'_>) -> Failure {
        if self.ret() == Ret::Unhandled {
            tracing::error!(error = %self, "command reached a backend that does not own it");
        }
        out.fail(self.ret(), format_args!("{self}"))
    }
}

/// The daemon's backend: a companion computer and a vehicle.
#[derive(Debug)]
pub struct Onboard<V> {
    companion: Companion,
    vehicle: V,
}

impl<V: VehicleBackend> Onboard<V> {
    /// Composes the two.
    pub fn new(companion: Companion, vehicle: V) -> Self {
        Onboard { companion, vehicle }
    }

    fn route(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        let Onboard { companion, vehicle } = self;
        let for_companion = |companion: &mut Companion, vehicle: &V, out: &mut Fields<'_>| {
            companion
                .execute(cmd, ctx, &vehicle.snapshot(), out)
                .map(|()| Step::Done)
                .map_err(|e| e.fail(out))
        };
        match owner(cmd.id()) {
            Owner::Companion => for_companion(companion, vehicle, out),
            Owner::Vehicle => vehicle.execute(cmd, ctx, companion.files(), out),
            Owner::Both if cmd.id() == CommandId::State => {
                out.object("state", |s| {
                    vehicle.write_state(ctx, s);
                    companion.write_state(s);
                });
                Ok(Step::Done)
            }
            Owner::Both => match vehicle.execute(cmd, ctx, companion.files(), out)? {
                Step::Done => for_companion(companion, vehicle, out),
                pending => Ok(pending),
            },
        }
    }
}

impl Onboard<Simulator> {
    /// `lluavd`'s default backend: the companion computer and the simulated
    /// vehicle, both keeping their files in `companion.data_dir`; the
    /// simulation runs at `speed`.
    pub fn simulator(companion: CompanionConfig, speed: f64) -> io::Result<Self> {
        let data_dir = companion.data_dir.clone();
        let companion = Companion::open(companion)?;
        let seed = companion::machine_id().unwrap_or_else(|_| "lluav-sim".into());
        let sim = Simulator::open(SimConfig {
            data_dir,
            speed,
            seed,
        })?;
        Ok(Onboard::new(companion, sim))
    }
}

impl<V: VehicleBackend> Backend for Onboard<V> {
    fn armed(&self) -> bool {
        self.vehicle.armed()
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        // A bug must not take the daemon down: a panic is answered -100 and
        // the vehicle carries on with the state it had.
        match panic::catch_unwind(AssertUnwindSafe(|| self.route(cmd, ctx, out))) {
            Ok(result) => result,
            Err(_) => {
                tracing::error!(cmd = cmd.id().name(), "backend panicked; answered as unhandled");
                Err(Failure::unhandled())
            }
        }
    }

    fn finish(&mut self, ticket: Ticket, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        self.vehicle.finish(ticket, ctx, out)
    }

    fn password_changed(&mut self, new: &str) -> Result<(), Failure> {
        self.companion.set_password(new).map_err(|e| {
            tracing::warn!(error = %e, "password not changed");
            Failure::fmt(e.ret(), format_args!("{e}"))
        })
    }

    fn session_closed(&mut self, session: SessionId) {
        self.vehicle.session_closed(session);
    }
}

impl<V: VehicleBackend> Vehicle for Onboard<V> {
    fn tick(&mut self, dt: Duration) {
        self.vehicle.tick(dt);
        self.companion.tick(dt, &self.vehicle.snapshot());
    }

    fn flush(&mut self) -> io::Result<()> {
        let vehicle = self.vehicle.flush();
        self.companion.flush()?;
        vehicle
    }

    fn stored_password(&self) -> Option<String> {
        self.companion.stored_password()
    }

    fn ready(&mut self, ticket: Ticket) -> Ready {
        self.vehicle.ready(ticket)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recent_log::RecentLog;
    use lluav_core::{Auth, Message, Outcome, Server};

    /// A vehicle whose commands panic.
    struct Faulty;

    impl VehicleBackend for Faulty {
        fn armed(&self) -> bool {
            false
        }
        fn execute(
            &mut self,
            _: &Command<'_>,
            _: &Context,
            _: &companion::Files,
            _: &mut Fields<'_>,
        ) -> Result<Step, Failure> {
            panic!("injected fault")
        }
        fn write_state(&self, _: &Context, state: &mut Fields<'_>) {
            state.bool("armed", false).str("fsm", "faulty");
        }
        fn snapshot(&self) -> Snapshot {
            Snapshot {
                backend: "faulty",
                time_s: 0.0,
                position: Ned::default(),
                yaw: 0.0,
                fsm: "faulty",
                distance_m: 0.0,
            }
        }
        fn tick(&mut self, _: Duration) {}
    }

    #[test]
    fn a_panic_in_a_command_is_answered_as_unhandled_and_the_backend_carries_on() {
        let dir = tempfile::tempdir().unwrap();
        let companion = Companion::open(CompanionConfig {
            data_dir: dir.path().to_path_buf(),
            log: RecentLog::new(8),
            password_pinned: false,
        })
        .unwrap();
        let mut server = Server::new(Onboard::new(companion, Faulty), || 7, Auth::new(None).unwrap());
        let mut session = server.open(None);
        let mut out = [0u8; 4096];
        assert_eq!(
            server.handle(&mut session, Message::Text(b"takeoff"), &mut out),
            Outcome::Reply(r#"{"ret":-100,"cmd":18,"ts":7,"msg":"Unhandled exception"}"#)
        );
        let Outcome::Reply(r) = server.handle(&mut session, Message::Text(b"ver"), &mut out) else {
            panic!("no reply");
        };
        assert!(r.contains(r#""backend":"faulty""#), "{r}");
    }
}
