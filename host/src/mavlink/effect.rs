//! What a command does that the autopilot's telemetry shows: how lluavd
//! tells whether a command whose `COMMAND_ACK` was lost happened anyway
//! (DESIGN.md "Backends": a lost acknowledgement is not a failure until
//! telemetry says so). Each effect is read from one message of the
//! autopilot: the heartbeat's armed flag and mode, the extended state's
//! landed state.

use ::mavlink::dialects::ardupilotmega::{HEARTBEAT_DATA, MavLandedState, MavMessage, MavModeFlag};

use super::autopilot::{Flavour, Mode, Phase};

/// What a command changes, as telemetry shows it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Effect {
    /// The heartbeat's armed flag is this.
    Armed(bool),
    /// The heartbeat's mode is this one.
    Mode(Flavour, Mode),
    /// The mode means this phase of flight (`NAV_RETURN_TO_LAUNCH`,
    /// `MISSION_START`).
    Phase(Flavour, Phase),
    /// Landing or landed (`NAV_LAND`): the landed state, the landing mode,
    /// or a vehicle that landed and disarmed.
    Landing(Flavour),
    /// Taking off or in the air: the landed state, or PX4's takeoff mode.
    Airborne(Flavour),
}

impl Effect {
    /// Whether `msg`, from the autopilot, shows the effect: `None` when it
    /// says nothing about it. The latest message that says something is
    /// what the telemetry shows.
    pub fn shows(self, msg: &MavMessage) -> Option<bool> {
        let armed = |hb: &HEARTBEAT_DATA| hb.base_mode.contains(MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED);
        match (self, msg) {
            (Effect::Armed(want), MavMessage::HEARTBEAT(hb)) => Some(armed(hb) == want),
            (Effect::Mode(flavour, mode), MavMessage::HEARTBEAT(hb)) => {
                Some(flavour.is_mode(hb.custom_mode, mode))
            }
            (Effect::Phase(flavour, phase), MavMessage::HEARTBEAT(hb)) => {
                Some(flavour.phase(hb.custom_mode) == phase)
            }
            // The landed state says; a heartbeat only when it shows the
            // landing mode, or a vehicle already down and disarmed.
            (Effect::Landing(flavour), MavMessage::HEARTBEAT(hb)) => {
                (!armed(hb) || flavour.phase(hb.custom_mode) == Phase::Landing).then_some(true)
            }
            (Effect::Landing(_), MavMessage::EXTENDED_SYS_STATE(e)) => Some(matches!(
                e.landed_state,
                MavLandedState::MAV_LANDED_STATE_LANDING | MavLandedState::MAV_LANDED_STATE_ON_GROUND
            )),
            // Disarmed is on the ground whatever the mode; armed in PX4's
            // takeoff mode is taking off; any other mode leaves it to the
            // landed state.
            (Effect::Airborne(_), MavMessage::HEARTBEAT(hb)) if !armed(hb) => Some(false),
            (Effect::Airborne(flavour), MavMessage::HEARTBEAT(hb)) => {
                (flavour.phase(hb.custom_mode) == Phase::Takeoff).then_some(true)
            }
            (Effect::Airborne(_), MavMessage::EXTENDED_SYS_STATE(e)) => Some(matches!(
                e.landed_state,
                MavLandedState::MAV_LANDED_STATE_TAKEOFF | MavLandedState::MAV_LANDED_STATE_IN_AIR
            )),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use ::mavlink::dialects::ardupilotmega::{
        EXTENDED_SYS_STATE_DATA, HEARTBEAT_DATA, MavAutopilot, MavState, MavType, MavVtolState,
    };

    use super::*;

    fn heartbeat(armed: bool, custom_mode: u32) -> MavMessage {
        let mut base_mode = MavModeFlag::MAV_MODE_FLAG_CUSTOM_MODE_ENABLED;
        if armed {
            base_mode |= MavModeFlag::MAV_MODE_FLAG_SAFETY_ARMED;
        }
        MavMessage::HEARTBEAT(HEARTBEAT_DATA {
            custom_mode,
            mavtype: MavType::MAV_TYPE_QUADROTOR,
            autopilot: MavAutopilot::MAV_AUTOPILOT_PX4,
            base_mode,
            system_status: MavState::MAV_STATE_ACTIVE,
            mavlink_version: 3,
        })
    }

    fn landed(state: MavLandedState) -> MavMessage {
        MavMessage::EXTENDED_SYS_STATE(EXTENDED_SYS_STATE_DATA {
            vtol_state: MavVtolState::MAV_VTOL_STATE_MC,
            landed_state: state,
        })
    }

    const PX4_TAKEOFF: u32 = (4 << 16) | (2 << 24);
    const PX4_LAND: u32 = (4 << 16) | (6 << 24);
    const PX4_OFFBOARD: u32 = 6 << 16;

    #[test]
    fn arming_shows_in_the_heartbeat() {
        assert_eq!(Effect::Armed(true).shows(&heartbeat(true, 0)), Some(true));
        assert_eq!(Effect::Armed(true).shows(&heartbeat(false, 0)), Some(false));
        assert_eq!(Effect::Armed(false).shows(&heartbeat(false, 0)), Some(true));
        let in_air = landed(MavLandedState::MAV_LANDED_STATE_IN_AIR);
        assert_eq!(Effect::Armed(true).shows(&in_air), None);
    }

    #[test]
    fn a_takeoff_shows_in_the_landed_state_or_the_takeoff_mode() {
        let px4 = Effect::Airborne(Flavour::Px4);
        assert_eq!(
            px4.shows(&landed(MavLandedState::MAV_LANDED_STATE_TAKEOFF)),
            Some(true)
        );
        assert_eq!(
            px4.shows(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR)),
            Some(true)
        );
        assert_eq!(
            px4.shows(&landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND)),
            Some(false)
        );
        assert_eq!(px4.shows(&heartbeat(true, PX4_TAKEOFF)), Some(true));
        assert_eq!(
            px4.shows(&heartbeat(false, PX4_TAKEOFF)),
            Some(false),
            "disarmed is on the ground"
        );
        assert_eq!(
            px4.shows(&heartbeat(true, PX4_OFFBOARD)),
            None,
            "the landed state says"
        );
    }

    #[test]
    fn modes_and_phases_show_in_the_heartbeat() {
        let offboard = Effect::Mode(Flavour::Px4, Mode::Guided);
        assert_eq!(offboard.shows(&heartbeat(true, PX4_OFFBOARD)), Some(true));
        assert_eq!(offboard.shows(&heartbeat(true, PX4_LAND)), Some(false));
        let guided = Effect::Mode(Flavour::ArduPilot, Mode::Guided);
        assert_eq!(guided.shows(&heartbeat(true, 4)), Some(true));
        let landing = Effect::Landing(Flavour::Px4);
        assert_eq!(landing.shows(&heartbeat(true, PX4_LAND)), Some(true));
        assert_eq!(landing.shows(&heartbeat(true, PX4_OFFBOARD)), None);
        assert_eq!(
            landing.shows(&heartbeat(false, PX4_OFFBOARD)),
            Some(true),
            "down and disarmed"
        );
        assert_eq!(
            landing.shows(&landed(MavLandedState::MAV_LANDED_STATE_LANDING)),
            Some(true)
        );
        assert_eq!(
            landing.shows(&landed(MavLandedState::MAV_LANDED_STATE_ON_GROUND)),
            Some(true)
        );
        assert_eq!(
            landing.shows(&landed(MavLandedState::MAV_LANDED_STATE_IN_AIR)),
            Some(false)
        );
        let rtl = Effect::Phase(Flavour::ArduPilot, Phase::Rtl);
        assert_eq!(rtl.shows(&heartbeat(true, 9)), Some(false));
        assert_eq!(rtl.shows(&heartbeat(true, 6)), Some(true));
    }
}
