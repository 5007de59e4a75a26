//! The daemon's backend: the companion computer and a vehicle, composed.
//!
//! lluavd runs on the companion computer, the Linux machine on board. Two
//! things answer the protocol's commands there:
//! - the **vehicle** ([`Vehicle`]): what flies — the flight state
//!   machine, setpoints, missions, the autopilot's parameters — and the
//!   peripherals on the airframe (LED, camera and gimbal, apron, BMS,
//!   lidar, UTG, grabber, ARA8). The simulator ([`crate::sim`]) is one;
//!   an autopilot over MAVLink is another.
//! - the **companion computer** ([`Companion`]): the Linux machine itself,
//!   the same whatever flies.
//!
//! [`Onboard`] owns one of each and implements [`lluav_core::Backend`] by
//! routing every command to the side that owns it ([`owner`]): by the
//! command table's section (the map and system sections are the
//! companion's, everything else the vehicle's), except for the commands
//! [`route::EXCEPTIONS`] lists. The commands both answer (`state`,
//! `statics`, `hud1`) are the vehicle's first, then the companion adds its
//! members: `state` is one `state` object both fill; `statics` has the
//! vehicle's `comm` and `stat` and the companion's `rosrecord` and
//! `node_boot_sec`; `hud1` the vehicle's `uav_pos_enu` and `extra` and the
//! companion's `kfs`. `passwd` reaches the companion through
//! [`lluav_core::Backend::password_changed`], and `admin_lock` and
//! `admin_unlock` through [`lluav_core::Backend::lock_mode_changed`].
//!
//! The core answers `login`, `help`, `admin_lock`, `admin_unlock`,
//! `control`, `control_take` and `control_release` itself; they never
//! reach a backend. The failsafe, the mission and the control timeout the
//! core's gates ask for are the vehicle's.
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

pub mod route;

use std::io;
use std::panic::{self, AssertUnwindSafe};
use std::time::{Duration, Instant};

use lluav_core::{Backend, Command, CommandId, Context, Failsafe, Failure, Fields, SessionId, Step, Ticket};

use crate::companion::Companion;
use crate::vehicle::{Progress, Refusal, Reply, Vehicle, Wait};
pub use route::{Owner, owner};

/// The daemon's backend: a companion computer and a vehicle.
pub struct Onboard<V> {
    companion: Companion,
    vehicle: V,
    next_ticket: u32,
    /// The wait of the command [`Backend::execute`] just left pending,
    /// until the daemon takes it in the same critical section.
    waiting: Option<(Ticket, Wait)>,
    /// A waited-for command's reply, from the daemon to
    /// [`Backend::finish`] in the same critical section.
    arrived: Option<(Ticket, Reply)>,
    /// Up to when both sides were advanced.
    advanced: Instant,
}

impl<V: std::fmt::Debug> std::fmt::Debug for Onboard<V> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Onboard")
            .field("companion", &self.companion)
            .field("vehicle", &self.vehicle)
            .finish_non_exhaustive()
    }
}

impl<V: Vehicle> Onboard<V> {
    /// Composes the two.
    pub fn new(companion: Companion, vehicle: V) -> Self {
        Onboard {
            companion,
            vehicle,
            next_ticket: 1,
            waiting: None,
            arrived: None,
            advanced: Instant::now(),
        }
    }

    fn route(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Progress, Failure> {
        let Onboard {
            companion, vehicle, ..
        } = self;
        let for_companion = |companion: &mut Companion, vehicle: &V, out: &mut Fields<'_>| {
            companion
                .execute(cmd, ctx, &vehicle.snapshot(), out)
                .map(|()| Progress::Done)
                .map_err(|e| e.fail(out))
        };
        match owner(cmd.id()) {
            Owner::Companion => for_companion(companion, vehicle, out),
            Owner::Vehicle => vehicle.execute(cmd, ctx, companion.files(), out),
            Owner::Both if cmd.id() == CommandId::State => {
                out.object("state", |s| {
                    vehicle.write_state(ctx, s);
                    ctx.write_authority(s);
                    companion.write_state(s);
                });
                Ok(Progress::Done)
            }
            Owner::Both => match vehicle.execute(cmd, ctx, companion.files(), out)? {
                Progress::Done => for_companion(companion, vehicle, out),
                waiting => Ok(waiting),
            },
        }
    }

    /// Keeps a command's wait for the daemon, under a new ticket.
    fn wait(&mut self, wait: Wait) -> Step {
        let ticket = Ticket(self.next_ticket);
        self.next_ticket = self.next_ticket.wrapping_add(1).max(1);
        if self.waiting.replace((ticket, wait)).is_some() {
            tracing::error!("a pending command's wait was never taken");
        }
        Step::Pending(ticket)
    }

    /// The wait of the command left pending with `ticket`: the daemon
    /// takes it right after [`lluav_core::Server::handle`] or
    /// [`lluav_core::Server::resume`] answered pending, awaits it unlocked,
    /// then hands its reply to [`Onboard::arrive`].
    pub fn take_wait(&mut self, ticket: Ticket) -> Option<Wait> {
        match self.waiting.take() {
            Some((t, wait)) if t == ticket => Some(wait),
            _ => None,
        }
    }

    /// The reply of the command pending with `ticket`, for the
    /// [`lluav_core::Server::resume`] that follows at once.
    pub fn arrive(&mut self, ticket: Ticket, reply: Reply) {
        self.arrived = Some((ticket, reply));
    }
}

impl<V: Vehicle> Backend for Onboard<V> {
    fn armed(&self) -> bool {
        self.vehicle.armed()
    }

    fn execute(&mut self, cmd: &Command<'_>, ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        // A bug must not take the daemon down: a panic is answered -100 and
        // the vehicle carries on with the state it had.
        match panic::catch_unwind(AssertUnwindSafe(|| self.route(cmd, ctx, out))) {
            Ok(Ok(Progress::Done)) => Ok(Step::Done),
            Ok(Ok(Progress::Waiting(wait))) => Ok(self.wait(wait)),
            Ok(Err(failure)) => Err(failure),
            Err(_) => {
                tracing::error!(cmd = cmd.id().name(), "backend panicked; answered as unhandled");
                Err(Failure::unhandled())
            }
        }
    }

    fn finish(&mut self, ticket: Ticket, _ctx: &Context, out: &mut Fields<'_>) -> Result<Step, Failure> {
        match self.arrived.take() {
            Some((t, reply)) if t == ticket => reply(out).map(|()| Step::Done),
            _ => {
                tracing::error!(ticket = ticket.0, "finish without the command's reply");
                Err(Failure::unhandled())
            }
        }
    }

    fn password_changed(&mut self, new: &str) -> Result<(), Failure> {
        self.companion.set_password(new).map_err(|e| {
            tracing::warn!(error = %e, "password not changed");
            Failure::fmt(e.ret(), format_args!("{e}"))
        })
    }

    fn lock_mode_changed(&mut self, on: bool) -> Result<(), Failure> {
        self.companion.set_lock_mode(on).map_err(|e| {
            tracing::warn!(error = %e, "lock mode not changed");
            Failure::fmt(e.ret(), format_args!("{e}"))
        })
    }

    fn session_closed(&mut self, session: SessionId) {
        self.vehicle.session_closed(session);
    }

    fn failsafe(&self) -> Option<Failsafe> {
        self.vehicle.failsafe()
    }

    fn override_failsafe(&mut self) -> Result<(), Failure> {
        self.vehicle.override_failsafe()
    }

    fn mission_running(&self) -> bool {
        self.vehicle.mission_running()
    }

    fn control_timeout_ms(&self) -> u32 {
        self.vehicle.control_timeout_ms()
    }
}

impl<V: Vehicle> Onboard<V> {
    /// Advances the vehicle by `dt` of wall time, then the companion
    /// (which samples the vehicle for a recording bag).
    pub fn tick(&mut self, dt: Duration) {
        self.vehicle.tick(dt);
        self.companion.tick(dt, &self.vehicle.snapshot());
    }

    /// Advances both by the wall time since they were last advanced, up
    /// to `now`: before every request (so that a vehicle left alone while
    /// idle is current when asked) and on the daemon's timer while it
    /// does something.
    pub fn advance_to(&mut self, now: Instant) {
        let dt = now.saturating_duration_since(self.advanced);
        self.advanced = self.advanced.max(now);
        if !dt.is_zero() {
            self.tick(dt);
        }
    }

    /// How soon [`Onboard::advance_to`] must run again for what goes on to
    /// go on; `None` when nothing changes without a request.
    pub fn next_tick(&self) -> Option<Duration> {
        let recording = self.companion.recording().then_some(crate::vehicle::TICK);
        match (self.vehicle.next_tick(), recording) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    /// What the vehicle told since the last call, in order.
    pub fn drain_events(&mut self, out: &mut Vec<crate::events::Event>) {
        self.vehicle.drain_events(out);
    }

    /// Persists what both sides hold pending.
    pub fn flush(&mut self) -> io::Result<()> {
        let vehicle = self.vehicle.flush();
        self.companion.flush()?;
        vehicle
    }

    /// Stops the vehicle's background work.
    pub fn stop(&mut self) {
        self.vehicle.stop();
    }

    /// A password saved by an earlier `passwd`, used when none is
    /// configured.
    pub fn stored_password(&self) -> Option<String> {
        self.companion.stored_password()
    }

    /// Lock mode as `admin_lock`/`admin_unlock` last saved it, restored at
    /// start.
    pub fn stored_lock_mode(&self) -> bool {
        self.companion.stored_lock_mode()
    }

    /// Whether the link to the autopilot is up (see [`Vehicle::link_up`]).
    pub fn link_up(&self, now_ms: i64) -> Option<bool> {
        self.vehicle.link_up(now_ms)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::companion::CompanionConfig;
    use crate::files::Files;
    use crate::recent_log::RecentLog;
    use crate::vehicle::{Ned, Snapshot};
    use lluav_core::{Auth, Message, Outcome, Server};

    /// A vehicle whose commands panic.
    struct Faulty;

    impl Vehicle for Faulty {
        fn armed(&self) -> bool {
            false
        }
        fn execute(
            &mut self,
            _: &Command<'_>,
            _: &Context,
            _: &Files,
            _: &mut Fields<'_>,
        ) -> Result<Progress, Failure> {
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
            uplink: None,
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
