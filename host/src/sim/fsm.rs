//! The flight model: the FSM, a kinematic point vehicle in NED, routes of
//! waypoints, and the battery.
//!
//! Motion is kinematic: every step the vehicle moves straight towards its
//! target at most `cruise_speed` horizontally and `climb_speed` (or the
//! landing rate) vertically, and turns at most `yaw_rate`; it never
//! overshoots. Time arrives in simulated seconds and is cut into steps of
//! at most [`MAX_STEP_S`], so results do not depend on how the caller ticks.

use std::collections::VecDeque;
use std::f64::consts::PI;

/// Longest simulated step, s.
pub const MAX_STEP_S: f64 = 0.05;
/// Most steps one call to [`Flight::advance`] takes.
pub const MAX_STEPS: f64 = 100_000.0;
/// Time a landed vehicle stays armed before it disarms, s.
pub const DISARM_DELAY_S: f64 = 1.0;
/// Landing descends at least fast enough to touch down within this, s.
pub const LAND_BUDGET_S: f64 = 12.0;
/// Battery charge rate on the pad while `bms_setcharge 1`, percent per minute.
pub const CHARGE_RATE: f64 = 5.0;

/// The FSM states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mode {
    /// On the ground, motors off.
    Disarmed,
    /// On the ground, motors armed (just landed).
    Armed,
    /// Climbing to the takeoff altitude.
    Takeoff,
    /// Holding or tracking the offboard setpoint.
    Hover,
    /// Flying a route of waypoints.
    Mission,
    /// Descending to land.
    Landing,
    /// Returning home.
    Rtl,
    /// Asleep: low power, no takeoff until `wakeup`.
    Sleep,
}

impl Mode {
    /// The state's name in `state.fsm`.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Disarmed => "disarmed",
            Mode::Armed => "armed",
            Mode::Takeoff => "takeoff",
            Mode::Hover => "hover",
            Mode::Mission => "mission",
            Mode::Landing => "landing",
            Mode::Rtl => "rtl",
            Mode::Sleep => "sleep",
        }
    }

    /// Whether the motors are armed.
    pub fn armed(self) -> bool {
        !matches!(self, Mode::Disarmed | Mode::Sleep)
    }

    /// Whether the vehicle is off the ground (or on its way up or down).
    pub fn airborne(self) -> bool {
        matches!(
            self,
            Mode::Takeoff | Mode::Hover | Mode::Mission | Mode::Landing | Mode::Rtl
        )
    }
}

/// A point in NED metres.
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

    fn sub(self, o: Ned) -> Ned {
        Ned::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }

    /// Height above the NED origin's level (`-z`, never `-0.0`).
    pub fn up(self) -> f64 {
        0.0 - self.z
    }

    fn norm(self) -> f64 {
        (self.x * self.x + self.y * self.y + self.z * self.z).sqrt()
    }
}

/// One leg of a route.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Leg {
    /// Where to go.
    pub target: Ned,
    /// Heading to turn to, if any.
    pub yaw: Option<f64>,
    /// How long to hold there, s.
    pub hold_s: f64,
    /// The mission waypoint id this leg flies to, if any.
    pub wp: Option<u32>,
}

/// What a route does when its last leg is done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Then {
    /// Hover where it ended.
    Hover,
    /// Land where it ended.
    Land,
}

#[derive(Clone, Debug)]
struct Route {
    id: u64,
    legs: VecDeque<Leg>,
    then: Then,
    held: f64,
}

/// Something that happened to a route, for mission bookkeeping.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RouteEvent {
    /// A waypoint leg was completed.
    Reached {
        /// The route.
        route: u64,
        /// The waypoint id.
        wp: u32,
    },
    /// Every leg was flown.
    Finished {
        /// The route.
        route: u64,
    },
    /// The route was replaced or cancelled before its end.
    Dropped {
        /// The route.
        route: u64,
    },
}

/// The parameters the flight model reads every step.
#[derive(Clone, Copy, Debug)]
pub struct Limits {
    /// Horizontal speed, m/s.
    pub cruise: f64,
    /// Climb speed, m/s.
    pub climb: f64,
    /// Slowest landing descent, m/s.
    pub land: f64,
    /// Yaw rate, rad/s.
    pub yaw_rate: f64,
    /// Waypoint acceptance radius, m.
    pub accept: f64,
    /// RTL altitude above home, m.
    pub rtl_alt: f64,
    /// Whether RTL lands at home.
    pub rtl_land: bool,
    /// Battery drain while armed, %/min.
    pub drain: f64,
    /// Battery level that triggers RTL, %.
    pub low_battery: f64,
    /// Disarmed time before auto-sleep, if enabled, s.
    pub autosleep_after: Option<f64>,
    /// Whether the pad charges the battery.
    pub charging: bool,
}

/// The simulated vehicle's motion and FSM.
#[derive(Clone, Debug)]
pub struct Flight {
    mode: Mode,
    pos: Ned,
    vel: Ned,
    yaw: f64,
    sp: Ned,
    sp_yaw: f64,
    home: Ned,
    route: Option<Route>,
    next_route: u64,
    land_rate: f64,
    on_ground_s: f64,
    idle_s: f64,
    battery: f64,
    low_battery_handled: bool,
    trail: Vec<Ned>,
    events: Vec<RouteEvent>,
    /// Flights started since boot.
    pub flights: u64,
    /// Total time armed, s.
    pub armed_s: f64,
    /// Total distance flown, m.
    pub distance_m: f64,
}

impl Default for Flight {
    fn default() -> Self {
        Flight {
            mode: Mode::Disarmed,
            pos: Ned::default(),
            vel: Ned::default(),
            yaw: 0.0,
            sp: Ned::default(),
            sp_yaw: 0.0,
            home: Ned::default(),
            route: None,
            next_route: 1,
            land_rate: 0.0,
            on_ground_s: 0.0,
            idle_s: 0.0,
            battery: 100.0,
            low_battery_handled: false,
            trail: Vec::new(),
            events: Vec::new(),
            flights: 0,
            armed_s: 0.0,
            distance_m: 0.0,
        }
    }
}

impl Flight {
    /// The FSM state.
    pub fn mode(&self) -> Mode {
        self.mode
    }
    /// Position, NED m.
    pub fn pos(&self) -> Ned {
        self.pos
    }
    /// Velocity, NED m/s.
    pub fn vel(&self) -> Ned {
        self.vel
    }
    /// Heading, rad.
    pub fn yaw(&self) -> f64 {
        self.yaw
    }
    /// The target the vehicle tracks: position and heading.
    pub fn setpoint(&self) -> (Ned, f64) {
        (self.sp, self.sp_yaw)
    }
    /// Home (where the last takeoff started).
    pub fn home(&self) -> Ned {
        self.home
    }
    /// Battery, percent.
    pub fn battery(&self) -> f64 {
        self.battery
    }
    /// The active route's id, if flying one.
    pub fn route_id(&self) -> Option<u64> {
        self.route.as_ref().map(|r| r.id)
    }
    /// Waypoint legs left in the active route.
    pub fn legs_left(&self) -> usize {
        self.route.as_ref().map_or(0, |r| r.legs.len())
    }

    /// Route events since the last call.
    pub fn drain_events(&mut self) -> Vec<RouteEvent> {
        std::mem::take(&mut self.events)
    }

    /// Arms and starts climbing to `alt` metres above the current position.
    pub fn takeoff(&mut self, alt: f64) {
        self.drop_route();
        self.mode = Mode::Takeoff;
        self.home = Ned::new(self.pos.x, self.pos.y, 0.0);
        self.sp = Ned::new(self.pos.x, self.pos.y, self.pos.z.min(0.0) - alt);
        self.sp_yaw = self.yaw;
        self.flights += 1;
        self.idle_s = 0.0;
        self.low_battery_handled = false;
        self.trail.clear();
    }

    /// Descends where it is and disarms on the ground. A no-op on the
    /// ground.
    pub fn land(&mut self) {
        if !self.mode.airborne() {
            return;
        }
        self.drop_route();
        self.mode = Mode::Landing;
        self.sp = Ned::new(self.pos.x, self.pos.y, 0.0);
        self.sp_yaw = self.yaw;
    }

    /// Disarms at once; a vehicle in the air drops to the ground.
    pub fn disarm(&mut self) {
        if self.mode.airborne() {
            tracing::warn!(
                altitude = format!("{:.2}", self.pos.up()),
                "forced disarm in flight: vehicle dropped"
            );
        }
        self.drop_route();
        if self.mode != Mode::Sleep {
            self.mode = Mode::Disarmed;
        }
        self.pos.z = 0.0;
        self.vel = Ned::default();
        self.sp = self.pos;
        self.idle_s = 0.0;
    }

    /// Goes to sleep (only from the ground, disarmed).
    pub fn sleep(&mut self) -> bool {
        if self.mode != Mode::Disarmed {
            return false;
        }
        self.mode = Mode::Sleep;
        true
    }

    /// Wakes up from sleep; otherwise nothing changes.
    pub fn wakeup(&mut self) {
        if self.mode == Mode::Sleep {
            self.mode = Mode::Disarmed;
            self.idle_s = 0.0;
        }
    }

    /// Tracks a new setpoint. In the air this switches to hover (offboard),
    /// ending any route or landing; on the ground it is only stored.
    /// Returns whether the vehicle now tracks it.
    pub fn set_setpoint(&mut self, sp: Ned, yaw: f64) -> bool {
        self.sp = sp;
        self.sp_yaw = yaw;
        if self.mode.airborne() {
            self.drop_route();
            self.mode = Mode::Hover;
            true
        } else {
            false
        }
    }

    /// Flies `legs` in order, then hovers or lands. Returns the route id.
    pub fn fly_route(&mut self, legs: Vec<Leg>, then: Then, mode: Mode) -> u64 {
        self.drop_route();
        let id = self.next_route;
        self.next_route += 1;
        self.route = Some(Route {
            id,
            legs: legs.into(),
            then,
            held: 0.0,
        });
        self.trail.clear();
        self.mode = mode;
        id
    }

    /// Returns home: climbs to `rtl_alt` if lower, flies home, then lands or
    /// hovers. With `retrace`, first flies back through the waypoints of the
    /// last mission in reverse (mission RTL).
    pub fn rtl(&mut self, lim: &Limits, retrace: bool) {
        if !self.mode.airborne() {
            return;
        }
        let alt = (-self.pos.z).max(lim.rtl_alt);
        let mut legs = vec![leg(Ned::new(self.pos.x, self.pos.y, -alt))];
        if retrace {
            legs.extend(self.trail.iter().rev().map(|p| leg(Ned::new(p.x, p.y, -alt))));
        }
        legs.push(leg(Ned::new(self.home.x, self.home.y, -alt)));
        let then = if lim.rtl_land { Then::Land } else { Then::Hover };
        self.fly_route(legs, then, Mode::Rtl);
    }

    /// Moves the position estimate (map relocalisation on the ground).
    pub fn relocate(&mut self, pos: Ned, yaw: f64) {
        self.pos = pos;
        self.yaw = yaw;
        self.sp = pos;
        self.sp_yaw = yaw;
    }

    /// Sets the battery level (e.g. a new pack).
    pub fn set_battery(&mut self, pct: f64) {
        self.battery = pct.clamp(0.0, 100.0);
    }

    fn drop_route(&mut self) {
        if let Some(r) = self.route.take() {
            self.events.push(RouteEvent::Dropped { route: r.id });
        }
    }

    /// Advances the simulation by `dt` simulated seconds.
    pub fn advance(&mut self, dt: f64, lim: &Limits) {
        let mut left = dt.max(0.0);
        // A tick after a long stall must not hold the vehicle's lock for
        // seconds: past MAX_STEPS the steps grow instead. Motion stays
        // exact (steps never overshoot); only timing resolution coarsens.
        let max_step = MAX_STEP_S.max(left / MAX_STEPS);
        while left > 0.0 {
            let step = left.min(max_step);
            self.step(step, lim);
            left -= step;
        }
    }

    fn step(&mut self, dt: f64, lim: &Limits) {
        match self.mode {
            Mode::Disarmed => {
                self.vel = Ned::default();
                self.idle_s += dt;
                if lim.charging {
                    self.battery = (self.battery + CHARGE_RATE * dt / 60.0).min(100.0);
                }
                if lim.autosleep_after.is_some_and(|t| self.idle_s >= t) {
                    tracing::info!("auto-sleep after {:.0} s disarmed", self.idle_s);
                    self.mode = Mode::Sleep;
                }
            }
            Mode::Sleep => self.vel = Ned::default(),
            Mode::Armed => {
                self.vel = Ned::default();
                self.on_ground_s += dt;
                if self.on_ground_s >= DISARM_DELAY_S {
                    tracing::info!("landed: disarmed");
                    self.mode = Mode::Disarmed;
                    self.idle_s = 0.0;
                }
            }
            Mode::Takeoff => {
                self.move_towards(dt, lim, lim.climb);
                if (self.pos.z - self.sp.z).abs() < 0.05 {
                    tracing::info!(
                        altitude = format!("{:.2}", self.pos.up()),
                        "takeoff complete: hovering"
                    );
                    self.mode = Mode::Hover;
                }
            }
            Mode::Hover => self.move_towards(dt, lim, lim.climb),
            Mode::Mission | Mode::Rtl => self.follow_route(dt, lim),
            Mode::Landing => {
                if self.land_rate <= 0.0 {
                    self.land_rate = lim.land.max(-self.pos.z / LAND_BUDGET_S);
                }
                self.sp = Ned::new(self.pos.x, self.pos.y, 0.0);
                let rate = self.land_rate;
                self.move_towards(dt, lim, rate);
                if self.pos.z >= -1e-6 {
                    self.pos.z = 0.0;
                    self.vel = Ned::default();
                    self.mode = Mode::Armed;
                    self.on_ground_s = 0.0;
                }
            }
        }
        if self.mode != Mode::Landing {
            self.land_rate = 0.0;
        }
        if self.mode.armed() {
            self.armed_s += dt;
            self.battery = (self.battery - lim.drain * dt / 60.0).max(0.0);
            self.check_battery(lim);
        }
    }

    fn check_battery(&mut self, lim: &Limits) {
        if !matches!(self.mode, Mode::Takeoff | Mode::Hover | Mode::Mission | Mode::Rtl) {
            return;
        }
        if self.battery <= 0.0 {
            tracing::warn!("battery empty: landing");
            self.land();
        } else if self.battery < lim.low_battery && !self.low_battery_handled && self.mode != Mode::Rtl {
            self.low_battery_handled = true;
            tracing::warn!(battery = self.battery, "battery low: returning home");
            self.rtl(lim, false);
        }
    }

    fn follow_route(&mut self, dt: f64, lim: &Limits) {
        let Some(route) = self.route.as_mut() else {
            self.mode = Mode::Hover;
            return;
        };
        let Some(leg) = route.legs.front().copied() else {
            let (id, then) = (route.id, route.then);
            self.route = None;
            self.events.push(RouteEvent::Finished { route: id });
            match then {
                Then::Hover => {
                    self.sp = self.pos;
                    self.mode = Mode::Hover;
                }
                Then::Land => {
                    self.mode = Mode::Hover;
                    self.land();
                }
            }
            return;
        };
        self.sp = leg.target;
        if let Some(yaw) = leg.yaw {
            self.sp_yaw = yaw;
        }
        self.move_towards(dt, lim, lim.climb);
        let yaw_ok = leg.yaw.is_none_or(|y| wrap(y - self.yaw).abs() < 0.05);
        if self.pos.sub(leg.target).norm() > lim.accept || !yaw_ok {
            return;
        }
        let Some(route) = self.route.as_mut() else { return };
        route.held += dt;
        if route.held < leg.hold_s {
            return;
        }
        route.held = 0.0;
        route.legs.pop_front();
        if let Some(wp) = leg.wp {
            self.events.push(RouteEvent::Reached { route: route.id, wp });
            self.trail.push(leg.target);
        }
    }

    fn move_towards(&mut self, dt: f64, lim: &Limits, vertical: f64) {
        let d = self.sp.sub(self.pos);
        let horiz = (d.x * d.x + d.y * d.y).sqrt();
        let h_step = horiz.min(lim.cruise * dt);
        let (hx, hy) = if horiz > 0.0 {
            (d.x / horiz * h_step, d.y / horiz * h_step)
        } else {
            (0.0, 0.0)
        };
        let vz = d.z.clamp(-vertical * dt, vertical * dt);
        let delta = Ned::new(hx, hy, vz);
        self.pos = Ned::new(self.pos.x + hx, self.pos.y + hy, self.pos.z + vz);
        self.vel = Ned::new(hx / dt, hy / dt, vz / dt);
        self.distance_m += delta.norm();
        let turn = wrap(self.sp_yaw - self.yaw);
        self.yaw = wrap(self.yaw + turn.clamp(-lim.yaw_rate * dt, lim.yaw_rate * dt));
    }
}

fn leg(target: Ned) -> Leg {
    Leg {
        target,
        yaw: None,
        hold_s: 0.0,
        wp: None,
    }
}

/// An angle in (-π, π].
pub fn wrap(a: f64) -> f64 {
    let r = a.rem_euclid(2.0 * PI);
    if r > PI { r - 2.0 * PI } else { r }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn limits() -> Limits {
        Limits {
            cruise: 2.0,
            climb: 1.0,
            land: 0.7,
            yaw_rate: 1.0,
            accept: 0.3,
            rtl_alt: 10.0,
            rtl_land: true,
            drain: 1.0,
            low_battery: 20.0,
            autosleep_after: None,
            charging: false,
        }
    }

    #[test]
    fn takeoff_climbs_at_climb_speed_then_hovers() {
        let mut f = Flight::default();
        f.takeoff(2.0);
        assert!(f.mode().armed());
        f.advance(1.0, &limits());
        assert_eq!(f.mode(), Mode::Takeoff);
        assert!((f.pos().z + 1.0).abs() < 1e-9);
        f.advance(1.0, &limits());
        assert_eq!(f.mode(), Mode::Hover);
    }

    #[test]
    fn landing_from_any_altitude_disarms_within_fifteen_seconds() {
        for alt in [2.0, 30.0, 120.0] {
            let mut f = Flight::default();
            f.takeoff(alt);
            f.advance(200.0, &limits());
            assert_eq!(f.mode(), Mode::Hover, "alt {alt}");
            f.land();
            f.advance(14.9, &limits());
            assert_eq!(f.mode(), Mode::Disarmed, "alt {alt}");
            assert_eq!(f.pos().z, 0.0);
        }
    }

    #[test]
    fn route_reports_waypoints_then_finishes() {
        let mut f = Flight::default();
        f.takeoff(2.0);
        f.advance(3.0, &limits());
        let wp = |id, x| Leg {
            target: Ned::new(x, 0.0, -2.0),
            yaw: Some(0.5),
            hold_s: 1.0,
            wp: Some(id),
        };
        let id = f.fly_route(vec![wp(1, 2.0), wp(2, 4.0)], Then::Hover, Mode::Mission);
        f.advance(10.0, &limits());
        assert_eq!(f.mode(), Mode::Hover);
        assert_eq!(
            f.drain_events(),
            [
                RouteEvent::Reached { route: id, wp: 1 },
                RouteEvent::Reached { route: id, wp: 2 },
                RouteEvent::Finished { route: id }
            ]
        );
        assert!((f.yaw() - 0.5).abs() < 0.05);
    }

    #[test]
    fn a_huge_tick_still_ends_where_small_ticks_do() {
        let mut f = Flight::default();
        f.takeoff(2.0);
        f.advance(3.0, &limits());
        f.set_setpoint(Ned::new(100.0, 0.0, -2.0), 0.0);
        // No drain: an empty battery would land it.
        f.advance(
            1e7,
            &Limits {
                drain: 0.0,
                ..limits()
            },
        );
        assert_eq!(f.mode(), Mode::Hover);
        assert!((f.pos().x - 100.0).abs() < 1e-9);
    }

    #[test]
    fn yaw_wraps_the_short_way_round() {
        assert!((wrap(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        let mut f = Flight::default();
        f.takeoff(1.0);
        f.set_setpoint(Ned::new(0.0, 0.0, -1.0), 3.0);
        f.advance(0.5, &limits());
        assert!((f.yaw() - 0.5).abs() < 1e-9);
    }
}
