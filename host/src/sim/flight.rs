//! The flight model: the FSM, a kinematic point vehicle in NED, routes of
//! waypoints, and the battery.
//!
//! Motion is kinematic: every step the vehicle moves straight towards its
//! target at most `cruise_speed` horizontally and `climb_speed` (or the
//! landing rate) vertically, and turns at most `yaw_rate`; it never
//! overshoots. Time arrives in simulated seconds and is cut into steps of
//! at most [`MAX_STEP_S`], so results do not depend on how the caller ticks.
//!
//! Only [`Flight::takeoff`] leaves the ground: every other command that
//! moves the vehicle ([`Flight::land`], [`Flight::track`],
//! [`Flight::fly_route`], [`Flight::rtl`]) refuses a vehicle that is not in
//! the air with [`SimError::NotFlying`] and changes nothing. A vehicle
//! disarmed in the air falls ([`Mode::Falling`]: gravity, no thrust) until
//! it hits the ground; nothing flies it meanwhile.

use std::collections::VecDeque;
use std::f64::consts::PI;

use super::error::{SimError, SimResult};
use crate::events::Event;
use crate::vehicle::Ned;

/// Longest simulated step, s.
const MAX_STEP_S: f64 = 0.05;
/// Most steps one call to [`Flight::advance`] takes.
const MAX_STEPS: f64 = 100_000.0;
/// Time a landed vehicle stays armed before it disarms, s.
const DISARM_DELAY_S: f64 = 1.0;
/// Landing descends at least fast enough to touch down within this, s.
const LAND_BUDGET_S: f64 = 12.0;
/// Battery charge rate on the pad while `bms_setcharge 1`, percent per minute.
const CHARGE_RATE: f64 = 5.0;
/// Gravity, m/s² (a vehicle disarmed in the air falls freely).
const GRAVITY: f64 = 9.81;

/// The FSM states, each with the data only it has.
#[derive(Clone, Debug, PartialEq)]
pub(crate) enum Mode {
    /// On the ground, motors off, for `idle_s` (auto-sleep counts it).
    Disarmed { idle_s: f64 },
    /// Just landed, motors still armed for `on_ground_s` so far.
    Armed { on_ground_s: f64 },
    /// Climbing to the takeoff altitude.
    Takeoff,
    /// Holding or tracking the offboard setpoint.
    Hover,
    /// Flying a route of waypoints (`mw_exec`, `zyhk`).
    Mission(Route),
    /// Descending at `rate` m/s to the ground point `spot` (z 0).
    Landing { rate: f64, spot: Ned },
    /// Returning home along a route.
    Rtl(Route),
    /// Asleep: low power, no takeoff until `wakeup`.
    Sleep,
    /// Disarmed in the air: falling, motors off, until it hits the ground.
    Falling,
}

impl Mode {
    const LANDED: Mode = Mode::Disarmed { idle_s: 0.0 };

    /// The state's name in `state.fsm`.
    pub(crate) fn name(&self) -> &'static str {
        match self {
            Mode::Disarmed { .. } => "disarmed",
            Mode::Armed { .. } => "armed",
            Mode::Takeoff => "takeoff",
            Mode::Hover => "hover",
            Mode::Mission(_) => "mission",
            Mode::Landing { .. } => "landing",
            Mode::Rtl(_) => "rtl",
            Mode::Sleep => "sleep",
            Mode::Falling => "falling",
        }
    }

    /// Whether the motors are armed.
    pub(crate) fn armed(&self) -> bool {
        !matches!(self, Mode::Disarmed { .. } | Mode::Sleep | Mode::Falling)
    }

    /// Whether the vehicle is off the ground (or on its way up or down,
    /// falling included).
    pub(crate) fn airborne(&self) -> bool {
        !matches!(self, Mode::Disarmed { .. } | Mode::Armed { .. } | Mode::Sleep)
    }

    /// Whether it flies: in the air with its motors armed, so that the
    /// commands that move a vehicle can move it.
    pub(crate) fn flying(&self) -> bool {
        self.armed() && self.airborne()
    }

    fn route(&self) -> Option<&Route> {
        match self {
            Mode::Mission(r) | Mode::Rtl(r) => Some(r),
            _ => None,
        }
    }
}

/// One leg of a route.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct Leg {
    /// Where to go.
    pub(crate) target: Ned,
    /// Heading to turn to, if any.
    pub(crate) yaw: Option<f64>,
    /// How long to hold there, s.
    pub(crate) hold_s: f64,
    /// The mission waypoint id this leg flies to, if any.
    pub(crate) wp: Option<u32>,
}

impl Leg {
    /// A leg to `target` that neither turns nor holds.
    pub(crate) fn to(target: Ned) -> Leg {
        Leg {
            target,
            yaw: None,
            hold_s: 0.0,
            wp: None,
        }
    }
}

/// What a route does when its last leg is done.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Then {
    /// Hover where it ended.
    Hover,
    /// Land where it ended.
    Land,
}

/// Legs to fly, in order.
#[derive(Clone, Debug, PartialEq)]
pub(crate) struct Route {
    id: u64,
    legs: VecDeque<Leg>,
    then: Then,
    held_s: f64,
}

/// Something that happened to a route, for mission bookkeeping.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum RouteEvent {
    /// A waypoint leg was completed.
    Reached { route: u64, wp: u32 },
    /// Every leg was flown.
    Finished { route: u64 },
    /// The route was replaced or cancelled before its end.
    Dropped { route: u64 },
}

/// The parameters the flight model reads every step.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Limits {
    /// Horizontal speed, m/s.
    pub(crate) cruise: f64,
    /// Climb speed, m/s.
    pub(crate) climb: f64,
    /// Slowest landing descent, m/s.
    pub(crate) land: f64,
    /// Yaw rate, rad/s.
    pub(crate) yaw_rate: f64,
    /// Waypoint acceptance radius, m.
    pub(crate) accept: f64,
    /// RTL altitude above home (clipped into the envelope), m.
    pub(crate) rtl_alt: f64,
    /// Whether RTL lands at home.
    pub(crate) rtl_land: bool,
    /// Battery drain while armed, %/min.
    pub(crate) drain: f64,
    /// Battery level that triggers RTL, %.
    pub(crate) low_battery: f64,
    /// Disarmed time before auto-sleep, if enabled, s.
    pub(crate) autosleep_after: Option<f64>,
    /// Whether the pad charges the battery.
    pub(crate) charging: bool,
}

/// Why the simulated vehicle acts on its own (DESIGN.md, "Flight
/// authority": failsafes win).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Failsafe {
    /// Below `low_battery` in the air: it returns home.
    BatteryLow,
    /// Empty in the air: it lands where it is.
    BatteryEmpty,
}

/// The failsafe that started, and whether the session in control
/// overrode it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Active {
    pub(crate) reason: Failsafe,
    pub(crate) overridden: bool,
}

impl Active {
    /// The reason as `state.failsafe` and the failsafe event name it.
    pub(crate) fn source(self) -> &'static str {
        match self.reason {
            Failsafe::BatteryLow => "battery_low",
            Failsafe::BatteryEmpty => "battery_empty",
        }
    }

    /// What the vehicle does.
    pub(crate) fn action(self) -> lluav_core::Action {
        match self.reason {
            Failsafe::BatteryLow => lluav_core::Action::Rtl,
            Failsafe::BatteryEmpty => lluav_core::Action::Land,
        }
    }

    fn told(self) -> Event {
        Event::Failsafe {
            reason: Some(self.source().to_owned()),
            action: self.action().name(),
            overridden: self.overridden,
        }
    }
}

/// Totals since start, for `statics`.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct Totals {
    /// Flights started.
    pub(crate) flights: u64,
    /// Time armed, s.
    pub(crate) armed_s: f64,
    /// Distance flown, m.
    pub(crate) distance_m: f64,
}

/// The simulated vehicle's motion and FSM.
#[derive(Clone, Debug)]
pub(crate) struct Flight {
    mode: Mode,
    pos: Ned,
    vel: Ned,
    yaw: f64,
    sp: Ned,
    sp_yaw: f64,
    home: Ned,
    next_route: u64,
    battery: f64,
    /// The failsafe of this flight, until the vehicle is disarmed on the
    /// ground: each reason starts once, on entry.
    failsafe: Option<Active>,
    /// The battery's band: 0 above `low_battery`, then one more for each
    /// 10 % below it, `i32::MAX` empty (a change is told).
    band: i32,
    /// What happened, to be told (DESIGN.md, "Events").
    news: Vec<Event>,
    /// Waypoints reached since takeoff, for `mrtl`.
    trail: Vec<Ned>,
    events: Vec<RouteEvent>,
    totals: Totals,
}

impl Default for Flight {
    fn default() -> Self {
        Flight {
            mode: Mode::LANDED,
            pos: Ned::default(),
            vel: Ned::default(),
            yaw: 0.0,
            sp: Ned::default(),
            sp_yaw: 0.0,
            home: Ned::default(),
            next_route: 1,
            battery: 100.0,
            failsafe: None,
            band: 0,
            news: Vec::new(),
            trail: Vec::new(),
            events: Vec::new(),
            totals: Totals::default(),
        }
    }
}

impl Flight {
    pub(crate) fn mode(&self) -> &Mode {
        &self.mode
    }
    pub(crate) fn pos(&self) -> Ned {
        self.pos
    }
    pub(crate) fn vel(&self) -> Ned {
        self.vel
    }
    pub(crate) fn yaw(&self) -> f64 {
        self.yaw
    }
    /// The target the vehicle tracks: position and heading.
    pub(crate) fn setpoint(&self) -> (Ned, f64) {
        (self.sp, self.sp_yaw)
    }
    /// Where the last takeoff started.
    pub(crate) fn home(&self) -> Ned {
        self.home
    }
    /// Battery, percent.
    pub(crate) fn battery(&self) -> f64 {
        self.battery
    }
    pub(crate) fn totals(&self) -> Totals {
        self.totals
    }
    /// The failsafe of this flight, if one started.
    pub(crate) fn failsafe(&self) -> Option<Active> {
        self.failsafe
    }
    /// The session in control overrides the failsafe: it no longer refuses
    /// motion commands (the vehicle goes on with what it does until told
    /// otherwise); a different reason still starts a new one.
    pub(crate) fn override_failsafe(&mut self) {
        if let Some(f) = self.failsafe.as_mut() {
            f.overridden = true;
            let told = f.told();
            self.news.push(told);
        }
    }

    /// The failsafe is over (disarmed on the ground): told once.
    fn end_failsafe(&mut self) {
        if self.failsafe.take().is_some() {
            self.news.push(Event::Failsafe {
                reason: None,
                action: "none",
                overridden: false,
            });
        }
    }
    /// Waypoint legs left in the active route.
    pub(crate) fn legs_left(&self) -> usize {
        self.mode.route().map_or(0, |r| r.legs.len())
    }

    /// Route events since the last call.
    pub(crate) fn drain_events(&mut self) -> Vec<RouteEvent> {
        std::mem::take(&mut self.events)
    }

    /// Enters `mode`; a route the old mode was flying is dropped.
    fn enter(&mut self, mode: Mode) {
        if let Some(r) = self.switch(mode).route() {
            self.events.push(RouteEvent::Dropped { route: r.id });
        }
    }

    /// Enters `mode` and tells the change of state (and of arming);
    /// returns the mode left. Every change of mode goes through here.
    fn switch(&mut self, mode: Mode) -> Mode {
        let old = std::mem::replace(&mut self.mode, mode);
        let (from, to) = (old.name(), self.mode.name());
        if from != to {
            self.news.push(Event::Fsm { from, to });
        }
        if old.armed() != self.mode.armed() {
            self.news.push(Event::Armed {
                armed: self.mode.armed(),
            });
        }
        old
    }

    /// What happened since the last call, in order.
    pub(crate) fn drain_news(&mut self, out: &mut Vec<Event>) {
        out.append(&mut self.news);
    }

    fn require_airborne(&self) -> SimResult {
        match self.mode {
            _ if self.mode.flying() => Ok(()),
            Mode::Falling => Err(SimError::Falling),
            _ => Err(SimError::NotFlying),
        }
    }

    /// Arms and starts climbing to `alt` metres above the current position.
    /// The caller has checked that the vehicle may take off.
    pub(crate) fn takeoff(&mut self, alt: f64) {
        self.enter(Mode::Takeoff);
        self.home = Ned::new(self.pos.x, self.pos.y, 0.0);
        self.sp = Ned::new(self.pos.x, self.pos.y, self.pos.z.min(0.0) - alt);
        self.sp_yaw = self.yaw;
        self.totals.flights += 1;
        self.failsafe = None;
        self.trail.clear();
    }

    /// Descends where it is and disarms on the ground; already landing is
    /// fine.
    pub(crate) fn land(&mut self, lim: &Limits) -> SimResult {
        self.land_on(lim, self.pos)
    }

    /// Descends to the ground below `over` (a route's end: the vehicle
    /// was accepted within `accept_radius` of it, and lands on it, as an
    /// autopilot's RTL lands at home rather than where it got close).
    fn land_on(&mut self, lim: &Limits, over: Ned) -> SimResult {
        self.require_airborne()?;
        if !matches!(self.mode, Mode::Landing { .. }) {
            let rate = lim.land.max(self.pos.up() / LAND_BUDGET_S);
            let spot = Ned::new(over.x, over.y, 0.0);
            self.enter(Mode::Landing { rate, spot });
        }
        Ok(())
    }

    /// Disarms at once; a vehicle in the air falls from where it is, with
    /// the velocity it had, until it hits the ground.
    pub(crate) fn disarm(&mut self) {
        if self.mode.airborne() {
            if self.mode != Mode::Falling {
                tracing::warn!(
                    altitude = format!("{:.2}", self.pos.up()),
                    "forced disarm in flight: the vehicle falls"
                );
            }
            self.enter(Mode::Falling);
        } else if !matches!(self.mode, Mode::Sleep | Mode::Disarmed { .. }) {
            self.enter(Mode::LANDED);
            self.vel = Ned::default();
        }
        self.sp = Ned::new(self.pos.x, self.pos.y, 0.0);
    }

    /// Goes to sleep (only from the ground, disarmed); whether it did.
    pub(crate) fn sleep(&mut self) -> bool {
        let disarmed = matches!(self.mode, Mode::Disarmed { .. });
        if disarmed {
            self.switch(Mode::Sleep);
        }
        disarmed
    }

    /// Wakes up from sleep; otherwise nothing changes. Whether it slept.
    pub(crate) fn wakeup(&mut self) -> bool {
        let asleep = self.mode == Mode::Sleep;
        if asleep {
            self.switch(Mode::LANDED);
        }
        asleep
    }

    /// Tracks a new setpoint (offboard): hover towards it, ending any route
    /// or landing.
    pub(crate) fn track(&mut self, sp: Ned, yaw: f64) -> SimResult {
        self.require_airborne()?;
        self.sp = sp;
        self.sp_yaw = yaw;
        self.enter(Mode::Hover);
        Ok(())
    }

    /// Flies `legs` in order, then hovers or lands; returns the route id.
    /// With `rtl`, the FSM shows it as a return home.
    pub(crate) fn fly_route(&mut self, legs: Vec<Leg>, then: Then, rtl: bool) -> SimResult<u64> {
        self.require_airborne()?;
        let id = self.next_route;
        self.next_route += 1;
        let route = Route {
            id,
            legs: legs.into(),
            then,
            held_s: 0.0,
        };
        self.enter(if rtl {
            Mode::Rtl(route)
        } else {
            Mode::Mission(route)
        });
        Ok(id)
    }

    /// Returns home: climbs to `rtl_alt` (already clipped into the
    /// envelope) if lower, flies home, then lands or hovers; returns the
    /// altitude it returns at. With `retrace`, first flies back through the
    /// waypoints reached since takeoff, in reverse (mission RTL).
    pub(crate) fn rtl(&mut self, lim: &Limits, retrace: bool) -> SimResult<f64> {
        let alt = self.pos.up().max(lim.rtl_alt);
        let at_alt = |p: Ned| Leg::to(Ned::new(p.x, p.y, -alt));
        let mut legs = vec![at_alt(self.pos)];
        if retrace {
            legs.extend(self.trail.iter().rev().copied().map(at_alt));
        }
        legs.push(at_alt(self.home));
        let then = if lim.rtl_land { Then::Land } else { Then::Hover };
        self.fly_route(legs, then, true).map(|_| alt)
    }

    /// Moves the position estimate (map relocalisation on the ground).
    pub(crate) fn relocate(&mut self, pos: Ned, yaw: f64) {
        self.pos = pos;
        self.yaw = yaw;
        self.sp = pos;
        self.sp_yaw = yaw;
    }

    /// Advances the simulation by `dt` simulated seconds.
    pub(crate) fn advance(&mut self, dt: f64, lim: &Limits) {
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
        match &mut self.mode {
            Mode::Disarmed { idle_s } => {
                *idle_s += dt;
                let idle = *idle_s;
                self.rest(dt, lim, idle);
            }
            Mode::Sleep => self.vel = Ned::default(),
            Mode::Armed { on_ground_s } => {
                *on_ground_s += dt;
                self.vel = Ned::default();
                if *on_ground_s >= DISARM_DELAY_S {
                    tracing::info!("landed: disarmed");
                    self.switch(Mode::LANDED);
                }
            }
            Mode::Takeoff => self.climb(dt, lim),
            Mode::Hover => self.move_towards(dt, lim, lim.climb),
            Mode::Mission(_) | Mode::Rtl(_) => self.follow_route(dt, lim),
            &mut Mode::Landing { rate, spot } => self.descend(dt, lim, rate, spot),
            Mode::Falling => self.fall(dt),
        }
        if self.mode.armed() {
            self.totals.armed_s += dt;
            self.battery = (self.battery - lim.drain * dt / 60.0).max(0.0);
            self.check_battery(lim);
        } else if !self.mode.airborne() {
            // Disarmed on the ground: whatever failsafe there was is over
            // (a vehicle disarmed in the air is still falling).
            self.end_failsafe();
        }
        let band = crate::events::battery_band(self.battery, lim.low_battery);
        if band != self.band {
            self.band = band;
            self.news.push(Event::Battery {
                percent: self.battery,
            });
        }
    }

    /// On the ground, disarmed for `idle_s`: charging, auto-sleep.
    fn rest(&mut self, dt: f64, lim: &Limits, idle_s: f64) {
        self.vel = Ned::default();
        if lim.charging {
            self.battery = (self.battery + CHARGE_RATE * dt / 60.0).min(100.0);
        }
        if lim.autosleep_after.is_some_and(|t| idle_s >= t) {
            tracing::info!("auto-sleep after {idle_s:.0} s disarmed");
            self.switch(Mode::Sleep);
        }
    }

    fn climb(&mut self, dt: f64, lim: &Limits) {
        self.move_towards(dt, lim, lim.climb);
        if (self.pos.z - self.sp.z).abs() < 0.05 {
            tracing::info!(
                altitude = format!("{:.2}", self.pos.up()),
                "takeoff complete: hovering"
            );
            self.switch(Mode::Hover);
        }
    }

    fn descend(&mut self, dt: f64, lim: &Limits, rate: f64, spot: Ned) {
        self.sp = spot;
        self.move_towards(dt, lim, rate);
        if self.pos.z >= -1e-6 {
            self.pos.z = 0.0;
            self.vel = Ned::default();
            self.switch(Mode::Armed { on_ground_s: 0.0 });
        }
    }

    /// Free fall: gravity alone, until the ground stops it.
    fn fall(&mut self, dt: f64) {
        self.vel.z += GRAVITY * dt;
        self.pos = Ned::new(
            self.pos.x + self.vel.x * dt,
            self.pos.y + self.vel.y * dt,
            self.pos.z + self.vel.z * dt,
        );
        self.sp = Ned::new(self.pos.x, self.pos.y, 0.0);
        if self.pos.z >= 0.0 {
            tracing::warn!(
                speed = format!("{:.1}", self.vel.norm()),
                "the falling vehicle hit the ground"
            );
            self.pos.z = 0.0;
            self.vel = Ned::default();
            self.sp = self.pos;
            self.switch(Mode::LANDED);
        }
    }

    fn check_battery(&mut self, lim: &Limits) {
        if !matches!(
            self.mode,
            Mode::Takeoff | Mode::Hover | Mode::Mission(_) | Mode::Rtl(_)
        ) {
            return;
        }
        if self.battery <= 0.0 {
            if self.start(Failsafe::BatteryEmpty) {
                tracing::warn!("battery empty: landing");
                // Airborne by the check above, so landing cannot be refused.
                let _ = self.land(lim);
            }
        } else if self.battery < lim.low_battery && self.start(Failsafe::BatteryLow) {
            tracing::warn!(battery = self.battery, "battery low: returning home");
            if !matches!(self.mode, Mode::Rtl(_)) {
                let _ = self.rtl(lim, false);
            }
        }
    }

    /// Starts a failsafe for `reason`, unless it holds already (overridden
    /// or not: a reason starts once) or a graver one does; whether it did.
    fn start(&mut self, reason: Failsafe) -> bool {
        let graver = |f: Active| f.reason == reason || f.reason == Failsafe::BatteryEmpty;
        if self.failsafe.is_some_and(graver) {
            return false;
        }
        let active = Active {
            reason,
            overridden: false,
        };
        self.failsafe = Some(active);
        self.news.push(active.told());
        true
    }

    fn follow_route(&mut self, dt: f64, lim: &Limits) {
        let Some(leg) = self.mode.route().map(|r| r.legs.front().copied()) else {
            return;
        };
        let Some(leg) = leg else {
            self.finish_route(lim, self.pos);
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
        let (Mode::Mission(route) | Mode::Rtl(route)) = &mut self.mode else {
            return;
        };
        route.held_s += dt;
        if route.held_s < leg.hold_s {
            return;
        }
        route.held_s = 0.0;
        route.legs.pop_front();
        let last = route.legs.is_empty();
        if let Some(wp) = leg.wp {
            self.events.push(RouteEvent::Reached { route: route.id, wp });
            self.trail.push(leg.target);
        }
        if last {
            self.finish_route(lim, leg.target);
        }
    }

    /// Ends the route whose last target was `end`: hovers where it is, or
    /// lands on `end`.
    fn finish_route(&mut self, lim: &Limits, end: Ned) {
        let Some(route) = self.mode.route().cloned() else {
            return;
        };
        // Finished, not dropped: no `Dropped` for it.
        self.switch(Mode::Hover);
        self.events.push(RouteEvent::Finished { route: route.id });
        self.sp = self.pos;
        if route.then == Then::Land {
            // Hovering now, so landing cannot be refused.
            let _ = self.land_on(lim, end);
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
        self.totals.distance_m += delta.norm();
        let turn = wrap(self.sp_yaw - self.yaw);
        self.yaw = wrap(self.yaw + turn.clamp(-lim.yaw_rate * dt, lim.yaw_rate * dt));
    }
}

/// Vector arithmetic the model needs.
trait NedExt {
    fn sub(self, o: Ned) -> Ned;
    fn norm(self) -> f64;
    fn up(self) -> f64;
}

impl NedExt for Ned {
    fn sub(self, o: Ned) -> Ned {
        Ned::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
    fn norm(self) -> f64 {
        (self.x * self.x + self.y * self.y + self.z * self.z).sqrt()
    }
    /// Height above the NED origin's level (`-z`, never `-0.0`).
    fn up(self) -> f64 {
        0.0 - self.z
    }
}

/// Height above the NED origin's level of `p`.
pub(crate) fn altitude(p: Ned) -> f64 {
    p.up()
}

/// Distance between two points, m.
pub(crate) fn distance(a: Ned, b: Ned) -> f64 {
    a.sub(b).norm()
}

/// An angle in (-π, π].
pub(crate) fn wrap(a: f64) -> f64 {
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
        assert_eq!(f.mode(), &Mode::Takeoff);
        assert!((f.pos().z + 1.0).abs() < 1e-9);
        f.advance(1.0, &limits());
        assert_eq!(f.mode(), &Mode::Hover);
    }

    #[test]
    fn landing_from_any_altitude_disarms_within_fifteen_seconds() {
        for alt in [2.0, 30.0, 120.0] {
            let mut f = Flight::default();
            f.takeoff(alt);
            f.advance(200.0, &limits());
            assert_eq!(f.mode(), &Mode::Hover, "alt {alt}");
            f.land(&limits()).unwrap();
            f.advance(14.9, &limits());
            assert_eq!(f.mode().name(), "disarmed", "alt {alt}");
            assert_eq!(f.pos().z, 0.0);
        }
    }

    #[test]
    fn commands_that_move_the_vehicle_refuse_it_on_the_ground() {
        let mut f = Flight::default();
        let lim = limits();
        assert!(matches!(f.land(&lim), Err(SimError::NotFlying)));
        assert!(matches!(f.rtl(&lim, false), Err(SimError::NotFlying)));
        assert!(matches!(
            f.track(Ned::new(1.0, 0.0, -1.0), 0.0),
            Err(SimError::NotFlying)
        ));
        assert!(matches!(
            f.fly_route(vec![], Then::Hover, false),
            Err(SimError::NotFlying)
        ));
        assert_eq!((f.mode().name(), f.setpoint().0), ("disarmed", Ned::default()));
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
        let id = f
            .fly_route(vec![wp(1, 2.0), wp(2, 4.0)], Then::Hover, false)
            .unwrap();
        f.advance(10.0, &limits());
        assert_eq!(f.mode(), &Mode::Hover);
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
    fn a_replaced_route_is_reported_dropped() {
        let mut f = Flight::default();
        f.takeoff(2.0);
        let id = f
            .fly_route(vec![Leg::to(Ned::new(50.0, 0.0, -2.0))], Then::Hover, false)
            .unwrap();
        f.track(Ned::new(0.0, 0.0, -2.0), 0.0).unwrap();
        assert_eq!(f.drain_events(), [RouteEvent::Dropped { route: id }]);
    }

    #[test]
    fn a_huge_tick_still_ends_where_small_ticks_do() {
        let mut f = Flight::default();
        f.takeoff(2.0);
        f.advance(3.0, &limits());
        f.track(Ned::new(100.0, 0.0, -2.0), 0.0).unwrap();
        // No drain: an empty battery would land it.
        let lim = Limits {
            drain: 0.0,
            ..limits()
        };
        f.advance(1e7, &lim);
        assert_eq!(f.mode(), &Mode::Hover);
        assert!((f.pos().x - 100.0).abs() < 1e-9);
    }

    #[test]
    fn yaw_wraps_the_short_way_round() {
        assert!((wrap(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        let mut f = Flight::default();
        f.takeoff(1.0);
        f.track(Ned::new(0.0, 0.0, -1.0), 3.0).unwrap();
        f.advance(0.5, &limits());
        assert!((f.yaw() - 0.5).abs() < 1e-9);
    }
}
