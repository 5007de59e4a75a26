//! Failsafes over MAVLink (DESIGN.md, "Flight authority"): when the
//! autopilot acts on its own for safety, or a pilot takes it over, read
//! from its heartbeats.
//!
//! A failsafe starts, for a vehicle in the air, when the autopilot is in a
//! return or land mode (`autopilot: <mode>`) or a pilot's mode
//! (`external: <mode>`) that it entered without lluavd asking for it —
//! by a mode change, or because it was in that mode when lluavd first saw
//! it — or when its `system_status` is CRITICAL or EMERGENCY
//! (`autopilot: <status>`) and its mode says nothing of its own.
//!
//! What lluavd asks for is remembered ([`Asked`]), so the modes that
//! follow from its own commands never count: a return or landing mode
//! entered within [`ASKED_WINDOW_MS`] of lluavd's `rtl`, `mrtl` or `land`
//! (the heartbeat showing it may come after lluavd's next command), and
//! the landing a return of lluavd's ends in. A mode lluavd asked to leave
//! (a takeoff from the ground in a pilot's mode, a setpoint from a
//! return) starts nothing while the heartbeat still shows it. Holds are
//! never failsafes: the hold after a takeoff or at a mission's end
//! follows from lluavd's commands.
//!
//! Each reason starts once, on entry, and the latest reason is the
//! failsafe; it ends when a heartbeat says disarmed. `control_take
//! failsafe` overrides the failsafe holding then; a different reason
//! starts a new one, the same reason does not start again until the
//! vehicle is disarmed.

use ::mavlink::dialects::ardupilotmega::MavState;
use lluav_core::{Action, Failsafe};

use super::autopilot::{Flavour, Kind};

/// How long after lluavd asked for a return or a landing the autopilot
/// entering it is lluavd's doing, ms: the command's retries (4.5 s) and a
/// heartbeat period, with room to spare.
pub const ASKED_WINDOW_MS: i64 = 10_000;

/// Most requests for a return or landing remembered at once.
const MAX_ASKED: usize = 4;

/// What lluavd asks the autopilot to do.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Asked {
    /// `takeoff`: the takeoff mode, then the autopilot's hold.
    Takeoff,
    /// `set_sp_ned`: the mode that follows setpoints.
    Setpoints,
    /// `mw_exec`: the mission mode, then the hold at its end.
    Mission,
    /// `land`: a landing mode.
    Land,
    /// `rtl`, `mrtl`: a return mode, and the landing that ends a return.
    Return,
}

impl Asked {
    /// The kind of failsafe-looking mode it leads to, if any.
    fn kind(self) -> Option<Kind> {
        match self {
            Asked::Land => Some(Kind::Land),
            Asked::Return => Some(Kind::Return),
            Asked::Takeoff | Asked::Setpoints | Asked::Mission => None,
        }
    }
}

/// One look at the autopilot: its latest heartbeat, and whether the
/// vehicle is in the air.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Look {
    /// Which autopilot (how its modes are numbered).
    pub flavour: Flavour,
    /// The heartbeat's `custom_mode`.
    pub custom_mode: u32,
    /// The heartbeat's `system_status`.
    pub status: MavState,
    /// The heartbeat's armed flag.
    pub armed: bool,
    /// Whether the vehicle is in the air.
    pub airborne: bool,
    /// When, on the daemon's clock, ms.
    pub now_ms: i64,
}

/// A failsafe that started.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Started {
    /// The failsafe.
    pub failsafe: Failsafe,
    /// Whether it comes from a mode change: the vehicle no longer follows
    /// lluavd's setpoint (a status alone changes nothing of the flight).
    pub left_setpoints: bool,
}

/// The failsafes of the autopilot followed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Watch {
    /// The mode of the latest heartbeat, and its kind.
    mode: Option<(u32, Kind)>,
    /// Whether that mode follows from lluavd's commands.
    own: bool,
    /// Whether lluavd asked for something else since that mode was
    /// entered: it is being left.
    left: bool,
    /// The returns and landings lluavd asked for, and until when
    /// (ms) entering one is its doing.
    asked: Vec<(Kind, i64)>,
    /// The failsafe, until the vehicle is disarmed.
    current: Option<Failsafe>,
    /// The reasons (source, detail) started since the vehicle was last
    /// disarmed: none starts twice. At most one per mode and status.
    started: Vec<(&'static str, &'static str)>,
}

impl Watch {
    /// The failsafe, if one started and the vehicle has not been disarmed
    /// since.
    pub fn failsafe(&self) -> Option<Failsafe> {
        self.current
    }

    /// Whether a failsafe holds (started, not overridden).
    pub fn holds(&self) -> Option<Failsafe> {
        self.current.filter(Failsafe::holds)
    }

    /// lluavd is about to send a command that asks for `asked` at `now_ms`:
    /// the mode it leaves starts nothing any more, and the return or
    /// landing it leads to is lluavd's own. (The failsafe gate lets only
    /// conservative commands through while a failsafe holds.)
    pub fn ask(&mut self, asked: Asked, now_ms: i64) {
        self.left = true;
        if let Some(kind) = asked.kind() {
            self.asked.retain(|&(_, until)| until > now_ms);
            if self.asked.len() == MAX_ASKED {
                self.asked.remove(0);
            }
            self.asked.push((kind, now_ms.saturating_add(ASKED_WINDOW_MS)));
        }
    }

    /// The command that asked for `asked` failed: the autopilot entering
    /// it is its own doing again.
    pub fn unask(&mut self, asked: Asked) {
        if let Some(i) = self.asked.iter().rposition(|&(k, _)| Some(k) == asked.kind()) {
            self.asked.remove(i);
        }
    }

    /// Whether entering a mode of `kind` at `now_ms` follows from lluavd's
    /// commands: it asked for it (each request explains one entry), or it
    /// continues a return or landing of lluavd's.
    fn explained(&mut self, kind: Kind, now_ms: i64) -> bool {
        let continues = self.own
            && matches!(
                (self.mode.map(|(_, k)| k), kind),
                (Some(Kind::Return), Kind::Return | Kind::Land) | (Some(Kind::Land), Kind::Land)
            );
        if continues {
            return true;
        }
        match self
            .asked
            .iter()
            .position(|&(k, until)| k == kind && until > now_ms)
        {
            Some(i) => {
                self.asked.remove(i);
                true
            }
            None => false,
        }
    }

    /// The session in control overrides the failsafe (`control_take
    /// failsafe`); returns it.
    pub fn override_failsafe(&mut self) -> Option<Failsafe> {
        let f = self.current.as_mut()?;
        f.overridden = true;
        Some(*f)
    }

    /// Takes in a look at the autopilot; returns the failsafe it started,
    /// if any.
    pub fn observe(&mut self, look: &Look) -> Option<Started> {
        let kind = look.flavour.kind(look.custom_mode);
        if self.mode.map(|(m, _)| m) != Some(look.custom_mode) {
            self.own = kind != Kind::Other && self.explained(kind, look.now_ms);
            self.left = false;
            self.mode = Some((look.custom_mode, kind));
        }
        if !look.armed {
            if let Some(f) = self.current.take() {
                tracing::info!(failsafe = %f.reason(), "failsafe over: the vehicle is disarmed");
            }
            self.started.clear();
            self.asked.clear();
            return None;
        }
        if !look.airborne {
            return None;
        }
        let action = match kind {
            Kind::Return => Action::Rtl,
            Kind::Land => Action::Land,
            Kind::Manual => Action::Hold,
            Kind::Other => Action::None,
        };
        let status = match look.status {
            MavState::MAV_STATE_CRITICAL => Some("CRITICAL"),
            MavState::MAV_STATE_EMERGENCY => Some("EMERGENCY"),
            _ => None,
        };
        let by_mode = (kind != Kind::Other && !self.own && !self.left).then(|| {
            let source = if kind == Kind::Manual {
                "external"
            } else {
                "autopilot"
            };
            (source, look.flavour.mode_name(look.custom_mode))
        });
        // The mode, when it says something, says more than the status
        // that usually comes with it (PX4 reports CRITICAL in every
        // failsafe mode).
        let (source, detail) = by_mode.or(status.map(|s| ("autopilot", s)))?;
        if self.started.contains(&(source, detail)) {
            return None;
        }
        self.started.push((source, detail));
        if let (Some(_), Some(s)) = (by_mode, status)
            && !self.started.contains(&("autopilot", s))
        {
            self.started.push(("autopilot", s));
        }
        let failsafe = Failsafe {
            source,
            detail,
            action,
            overridden: false,
        };
        tracing::warn!(failsafe = %failsafe.reason(), action = action.name(), "failsafe: the vehicle is no longer lluavd's to steer");
        self.current = Some(failsafe);
        Some(Started {
            failsafe,
            left_setpoints: by_mode.is_some(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const fn px4(main: u32, sub: u32) -> u32 {
        (main << 16) | (sub << 24)
    }
    const PX4_RTL: u32 = px4(4, 5);
    const PX4_LAND: u32 = px4(4, 6);
    const PX4_LOITER: u32 = px4(4, 3);
    const PX4_TAKEOFF: u32 = px4(4, 2);
    const PX4_MISSION: u32 = px4(4, 4);
    const PX4_OFFBOARD: u32 = px4(6, 0);
    const PX4_POSCTL: u32 = px4(3, 0);
    const COPTER_GUIDED: u32 = 4;
    const COPTER_LOITER: u32 = 5;
    const COPTER_RTL: u32 = 6;
    const COPTER_LAND: u32 = 9;

    fn look(flavour: Flavour, custom_mode: u32) -> Look {
        Look {
            flavour,
            custom_mode,
            status: MavState::MAV_STATE_ACTIVE,
            armed: true,
            airborne: true,
            now_ms: 0,
        }
    }

    fn reason(w: &Watch) -> Option<String> {
        w.failsafe().map(|f| {
            let r = f.reason().to_string();
            if f.overridden {
                format!("{r} (overridden)")
            } else {
                r
            }
        })
    }

    /// Flying a PX4 on lluavd's setpoints.
    fn following() -> Watch {
        let mut w = Watch::default();
        w.observe(&look(Flavour::Px4, PX4_LOITER));
        w.ask(Asked::Setpoints, 0);
        assert_eq!(w.observe(&look(Flavour::Px4, PX4_OFFBOARD)), None);
        w
    }

    #[test]
    fn a_return_or_landing_nobody_asked_for_is_the_autopilots_failsafe() {
        let mut w = following();
        let started = w.observe(&look(Flavour::Px4, PX4_RTL)).expect("a failsafe");
        assert!(started.left_setpoints);
        assert_eq!(started.failsafe.action, Action::Rtl);
        assert_eq!(reason(&w).as_deref(), Some("autopilot: AUTO.RTL"));
        assert!(w.holds().is_some());
        // Starts once: the next heartbeats change nothing.
        assert_eq!(w.observe(&look(Flavour::Px4, PX4_RTL)), None);
        // A landing the autopilot chose next is a new, graver reason.
        let land = w.observe(&look(Flavour::Px4, PX4_LAND)).expect("a new reason");
        assert_eq!(land.failsafe.action, Action::Land);
        assert!(land.failsafe.landing());
        assert_eq!(reason(&w).as_deref(), Some("autopilot: AUTO.LAND"));

        let mut w = Watch::default();
        w.observe(&look(Flavour::ArduPilot, COPTER_GUIDED));
        w.observe(&look(Flavour::ArduPilot, COPTER_LAND));
        assert_eq!(reason(&w).as_deref(), Some("autopilot: LAND"));
    }

    #[test]
    fn a_pilots_mode_nobody_asked_for_is_external() {
        let mut w = following();
        let started = w.observe(&look(Flavour::Px4, PX4_POSCTL)).expect("a failsafe");
        assert_eq!(started.failsafe.action, Action::Hold);
        assert_eq!(reason(&w).as_deref(), Some("external: POSCTL"));

        let mut w = Watch::default();
        w.observe(&look(Flavour::ArduPilot, COPTER_GUIDED));
        w.observe(&look(Flavour::ArduPilot, COPTER_LOITER));
        assert_eq!(reason(&w).as_deref(), Some("external: LOITER"));
    }

    #[test]
    fn what_lluavd_asked_for_is_never_a_failsafe() {
        // takeoff, the hold after it, a mission and the hold at its end.
        let mut w = Watch::default();
        w.observe(&Look {
            airborne: false,
            ..look(Flavour::Px4, PX4_POSCTL)
        });
        w.ask(Asked::Takeoff, 0);
        for mode in [PX4_POSCTL, PX4_TAKEOFF, PX4_LOITER] {
            assert_eq!(w.observe(&look(Flavour::Px4, mode)), None);
        }
        w.ask(Asked::Mission, 0);
        for mode in [PX4_MISSION, PX4_LOITER] {
            assert_eq!(w.observe(&look(Flavour::Px4, mode)), None);
        }
        // rtl: the return and the landing that ends it.
        w.ask(Asked::Return, 0);
        for mode in [PX4_RTL, PX4_LAND] {
            assert_eq!(w.observe(&look(Flavour::Px4, mode)), None);
        }
        assert_eq!(w.failsafe(), None);
        // land, on ArduPilot.
        let mut w = Watch::default();
        w.observe(&look(Flavour::ArduPilot, COPTER_GUIDED));
        w.ask(Asked::Land, 0);
        assert_eq!(w.observe(&look(Flavour::ArduPilot, COPTER_LAND)), None);
        // ... but a return lluavd did not ask for, after its landing, is.
        assert!(w.observe(&look(Flavour::ArduPilot, COPTER_RTL)).is_some());
    }

    #[test]
    fn a_mode_asked_for_shows_in_time_even_after_lluavds_next_command() {
        // land, then set_sp_ned before a heartbeat showed the landing.
        let mut w = following();
        w.ask(Asked::Land, 1000);
        w.ask(Asked::Setpoints, 1200);
        let late = Look {
            now_ms: 1500,
            ..look(Flavour::Px4, PX4_LAND)
        };
        assert_eq!(w.observe(&late), None);
        // Each request explains one entry, within its window.
        let mut w = following();
        w.ask(Asked::Return, 1000);
        let rtl = |now_ms| Look {
            now_ms,
            ..look(Flavour::Px4, PX4_RTL)
        };
        assert_eq!(
            w.observe(&rtl(1000 + ASKED_WINDOW_MS)).map(|s| s.failsafe.detail),
            Some("AUTO.RTL")
        );
    }

    #[test]
    fn a_pilot_taking_over_lluavds_return_is_external() {
        let mut w = following();
        w.ask(Asked::Return, 0);
        assert_eq!(w.observe(&look(Flavour::Px4, PX4_RTL)), None);
        assert!(w.observe(&look(Flavour::Px4, PX4_POSCTL)).is_some());
        // ... and the landing after it is not lluavd's return's.
        let mut w = following();
        w.ask(Asked::Return, 0);
        w.observe(&look(Flavour::Px4, PX4_RTL));
        w.observe(&look(Flavour::Px4, PX4_LOITER));
        assert!(w.observe(&look(Flavour::Px4, PX4_LAND)).is_some());
    }

    #[test]
    fn a_command_that_failed_explains_nothing() {
        let mut w = following();
        w.ask(Asked::Land, 0);
        w.unask(Asked::Land);
        assert!(w.observe(&look(Flavour::Px4, PX4_LAND)).is_some());
    }

    #[test]
    fn a_return_already_active_at_first_sight_is_a_failsafe_once_in_the_air() {
        let mut w = Watch::default();
        assert!(w.observe(&look(Flavour::Px4, PX4_RTL)).is_some());
        assert_eq!(reason(&w).as_deref(), Some("autopilot: AUTO.RTL"));

        // Seen on the ground first: it counts when the vehicle is in the
        // air in it, still unasked (a pilot's takeoff in a manual mode).
        let mut w = Watch::default();
        let ground = Look {
            airborne: false,
            ..look(Flavour::Px4, PX4_POSCTL)
        };
        assert_eq!(w.observe(&ground), None);
        assert_eq!(
            w.observe(&look(Flavour::Px4, PX4_POSCTL))
                .map(|s| s.failsafe.source),
            Some("external")
        );

        // Nothing starts on the ground, nor disarmed.
        let mut w = Watch::default();
        w.observe(&Look {
            armed: false,
            airborne: false,
            ..look(Flavour::Px4, PX4_RTL)
        });
        assert_eq!(w.failsafe(), None);
    }

    #[test]
    fn a_critical_status_starts_a_failsafe_that_keeps_the_setpoint() {
        let mut w = following();
        let critical = Look {
            status: MavState::MAV_STATE_CRITICAL,
            ..look(Flavour::Px4, PX4_OFFBOARD)
        };
        let started = w.observe(&critical).expect("a failsafe");
        assert!(
            !started.left_setpoints,
            "a status alone changes nothing of the flight"
        );
        assert_eq!(reason(&w).as_deref(), Some("autopilot: CRITICAL"));
        assert_eq!(w.observe(&critical), None);
        let emergency = Look {
            status: MavState::MAV_STATE_EMERGENCY,
            ..critical
        };
        assert_eq!(
            w.observe(&emergency).map(|s| s.failsafe.detail),
            Some("EMERGENCY")
        );
    }

    #[test]
    fn the_status_that_comes_with_a_failsafe_mode_is_part_of_it() {
        let mut w = following();
        let rtl = Look {
            status: MavState::MAV_STATE_CRITICAL,
            ..look(Flavour::Px4, PX4_RTL)
        };
        w.observe(&rtl);
        assert_eq!(reason(&w).as_deref(), Some("autopilot: AUTO.RTL"));
        w.override_failsafe();
        // Overridden, back on lluavd's setpoints, still CRITICAL: no new
        // failsafe for the status that came with the return.
        w.ask(Asked::Setpoints, 0);
        let back = Look {
            status: MavState::MAV_STATE_CRITICAL,
            ..look(Flavour::Px4, PX4_OFFBOARD)
        };
        assert_eq!(w.observe(&back), None);
        assert_eq!(reason(&w).as_deref(), Some("autopilot: AUTO.RTL (overridden)"));
    }

    #[test]
    fn an_override_covers_its_reason_only_until_disarmed() {
        let mut w = following();
        w.observe(&look(Flavour::Px4, PX4_RTL));
        assert_eq!(w.override_failsafe().map(|f| f.overridden), Some(true));
        assert_eq!(w.holds(), None);
        assert_eq!(reason(&w).as_deref(), Some("autopilot: AUTO.RTL (overridden)"));
        // Back on setpoints after the override; the same return again
        // does not start again while the failsafe lasts...
        w.ask(Asked::Setpoints, 0);
        w.observe(&look(Flavour::Px4, PX4_OFFBOARD));
        assert_eq!(w.observe(&look(Flavour::Px4, PX4_RTL)), None);
        // ... a different reason does.
        assert!(w.observe(&look(Flavour::Px4, PX4_POSCTL)).is_some());
        assert_eq!(reason(&w).as_deref(), Some("external: POSCTL"));
        // Disarmed: over, and everything starts afresh.
        w.observe(&Look {
            armed: false,
            airborne: false,
            ..look(Flavour::Px4, PX4_POSCTL)
        });
        assert_eq!(w.failsafe(), None);
        w.ask(Asked::Takeoff, 0);
        w.observe(&look(Flavour::Px4, PX4_LOITER));
        assert!(w.observe(&look(Flavour::Px4, PX4_RTL)).is_some());
    }

    #[test]
    fn nothing_to_override_without_a_failsafe() {
        let mut w = following();
        assert_eq!(w.override_failsafe(), None);
        assert_eq!(w.failsafe(), None);
    }
}
